"""The public names of one arm's server (its nodes, topics, services and actions, under
its namespace): the one place that spells them, for the server, the clients and the web
view alike; and its node found in a ROS graph by them, whatever its name. No rclpy here."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from al5d.arm.config import namespace_problem
from al5d.arm.instruction import Kind

NODE = "al5d"
SAFETY_NODE = "al5d_safety"
STOP_NODE = "al5d_stop"
ACTIONS_NODE = "al5d_actions"
ROBOT_NODE = "al5d_robot"
#: A recording's node (`al5d record`, `al5d serve --record`): it reads, and commands nothing.
RECORDER_NODE = "al5d_recorder"
#: The physical twin's node, in a process of its own (`al5d.twin`).
TWIN_NODE = "al5d_twin"
#: The node name that discovery lists for an endpoint whose node it has not heard of yet.
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
#: The instruction a client's handshake sends on the instruction topic: the node answers
#: it `done` on the result topic at once, without the arm (nothing written, nothing
#: logged, whatever the arm's state). An answer says both ways of the topics work.
PING = "ping"


@dataclass(frozen=True)
class Names:
    """Every public name of one arm's server, under its namespace (ROS conventions).

    With no namespace the names are the design's (`/al5d/instruction`, `/joint_states`,
    `/arm_controller/follow_joint_trajectory`); with namespace `left` the node-private
    names become `/left/al5d/...`, the robot's and the controllers' `/left/...`, and the
    TF frames `left/base_link`... The one place that spells them, for the server, the
    clients and the web view alike.
    """

    namespace: str = ""

    @classmethod
    def of(cls, namespace: str | None) -> Names:
        """`left`, `/left` or `/lab/left` (None or "" or "/": none); refused with the reason."""
        problem = namespace_problem(namespace or "")
        if problem:
            raise ValueError(problem)
        ns = (namespace or "").strip("/")
        return cls(f"/{ns}" if ns else "")

    @property
    def node_namespace(self) -> str:
        return self.namespace or "/"

    def private(self, name: str, node: str = NODE) -> str:
        """`name` private to the server's node (`node`: its name, if a remap changed it)."""
        return f"{self.namespace}/{node}/{name}"

    def shared(self, name: str) -> str:
        return f"{self.namespace}/{name}"

    @property
    def frame_prefix(self) -> str:
        return f"{self.namespace.lstrip('/')}/" if self.namespace else ""

    @property
    def instruction(self) -> str:
        return self.private("instruction")

    @property
    def result(self) -> str:
        return self.private("result")

    @property
    def clients(self) -> str:
        """Where clients send their leases (`al5d.ros.leases`)."""
        return self.private("clients")

    @property
    def state(self) -> str:
        return self.private("state")

    @property
    def config(self) -> str:
        """The configuration the server judges with, as JSON (latched)."""
        return self.private("config")

    @property
    def move(self) -> str:
        return self.private("move")

    @property
    def trajectory(self) -> str:
        return self.private("joint_trajectory")

    @property
    def tool_pose(self) -> str:
        return self.private("tool_pose")

    def goals(self, action: str) -> str:
        """What each goal of `action` (`move`, `follow_joint_trajectory`, `gripper_cmd`) asked,
        as it came: a service request is no topic, so a recorder could not see it."""
        return self.private(f"goals/{action}")

    @property
    def joint_states(self) -> str:
        return self.shared("joint_states")

    @property
    def joint_commands(self) -> str:
        """Set-points (sensor_msgs/JointState, the URDF's names and values), as ros2_control's
        topic-based hardware (`JointStateTopicSystem`) publishes its commands."""
        return self.shared("joint_commands")

    @property
    def physical_joint_states(self) -> str:
        """Where the joints physically stand, where something knows it (an emulated arm's
        true angles: `al5d.ros.physical`), as /joint_states (the URDF's names and values)."""
        return self.shared("physical_joint_states")

    @property
    def robot_description(self) -> str:
        return self.shared("robot_description")

    @property
    def follow_joint_trajectory(self) -> str:
        return self.shared("arm_controller/follow_joint_trajectory")

    @property
    def gripper_command(self) -> str:
        return self.shared("gripper_controller/gripper_cmd")

    @property
    def twin_joint_states(self) -> str:
        """The physical twin's joints (`al5d emulator --physics`): where the body is, which
        differs from `joint_states` (what the board is told) under a load or a contact."""
        return self.private("twin/joint_states")

    @property
    def twin_objects(self) -> str:
        """The twin's scene objects (visualization_msgs/MarkerArray: shape, size, colour, pose)."""
        return self.private("twin/objects")

    @property
    def twin_held(self) -> str:
        """The twin's word when a joint is held short of its target (std_msgs/String)."""
        return self.private("twin/held")

    @property
    def camera_image(self) -> str:
        """The twin's camera (sensor_msgs/Image, rgb8), as a ROS camera driver names it."""
        return self.shared("camera/image_raw")

    @property
    def camera_info(self) -> str:
        return self.shared("camera/camera_info")

    @property
    def services(self) -> dict[str, Kind]:
        return {self.private(k.value): k for k in (Kind.STOP, Kind.RELEASE, Kind.SHUTDOWN)}


#: The instruction topic with no namespace, as the design gives it.
INSTRUCTION_TOPIC = Names().instruction


def pinned(name: str) -> list[str]:
    """A node's own arguments that keep its name whatever the command line's `-r __node:=`
    (which renames every node of a context; a node's own rules come first): the server's
    nodes but `al5d` keep theirs, so that each has one name, as the design gives them."""
    return ["--ros-args", "-r", f"__node:={name}"]


def server_nodes(node: Any, names: Names) -> set[str]:
    """The names of the server's node at `names` that the ROS graph, as rclpy's `node` sees
    it, lists: the node that both reads the instructions and publishes the results,
    whatever a remap called it (`-r __node:=left_arm`). A name that discovery has not
    heard yet counts for nothing (it may be the stop watcher's reader)."""
    ours = names.node_namespace

    def named(infos: Any) -> set[str]:
        return {i.node_name for i in infos if i.node_namespace == ours} - {UNKNOWN_NODE}

    readers = named(node.get_subscriptions_info_by_topic(names.instruction))
    return readers & named(node.get_publishers_info_by_topic(names.result))


def reaches_server(node: Any, pub: Any, names: Names) -> bool:
    """Whether `pub`, rclpy's writer of `names.instruction` in `node`, has matched every reader
    of instructions that the graph lists, the server's node's among them (`server_nodes`).

    A count of readers alone says nothing of which: the stop watcher's reader is often
    found first, and a node that also reads the topic (the web view's) matches its own
    writer at once. An instruction published before the writer has matched the server
    node's reader never reaches it (the topic is volatile)."""
    readers = node.get_subscriptions_info_by_topic(names.instruction)
    return bool(server_nodes(node, names)) and pub.get_subscription_count() >= len(readers)


def server_namespaces(node: Any) -> set[str]:
    """The namespaces ("/" for none) of the servers that the ROS graph, as rclpy's `node`
    sees it, lists (`server_nodes`)."""
    tail = Names().instruction
    found = set()
    for topic, _ in node.get_topic_names_and_types():
        if topic.endswith(tail) and server_nodes(node, names := Names(topic[: -len(tail)])):
            found.add(names.node_namespace)
    return found
