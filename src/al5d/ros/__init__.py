"""ROS 2: the server's bridges to the owner, the mapping of messages to instructions, and the
client.

- `names`: every public name of an arm's server (nodes, topics, services, actions) under
  its namespace; no rclpy.
- `qos`: the QoS profiles of those topics and services, and why.
- `dds`: starting DDS as the project needs it (the Fast DDS profile, the context).
- `executors`: an executor in a thread of its own (`Spinner`), a publishing thread.
- `workarounds`: what rclpy does not give the server, how it is had here, and when each
  can go.
- `convert`: ROS messages <-> instructions and outcomes (pure).
- `params`: the node's ROS parameters, validated by the configuration's own code.
- `processes`: the ROS side's processes as the owner starts them (no rclpy there).
- `bridge`: the bridge: the parameters read (`RosStart`), then the nodes on the owner's
  lane (`Bridge`); its process is `al5d.app.bridgeproc`.
- `node`: the nodes on the owner: `ArmNode` (`al5d`: the instruction topic, results,
  state, parameters), `RobotNode` (`al5d_robot`) and `ActionsNode` (`al5d_actions`).
- `safety`: node `al5d_safety` (the release and shutdown services) and node `al5d_stop`
  (the stop service, and a stop on the instruction topic obeyed at once).
- `stopproc`: the stop's own process: node `al5d_stop`, ahead of the rest.
- `robot`: the robot's description, joint states and transforms (`RobotNode`'s).
- `physical`: where the joints physically stand, where something knows it (an emulated
  arm's true angles): published beside the server, read by the web view and `al5d calibrate`.
- `actions`: the move action; `controllers`: MoveIt's FollowJointTrajectory and
  GripperCommand (both `ActionsNode`'s).
- `client`: `Client`, a client of the server: a local one by its lane (`laneway`:
  `LaneWay`), any other over ROS 2 (`rosway`: `RosWay`; `rosstop`: its stop, copies on the
  topic sent until one is answered); the terminal's commands on it are
  `al5d.app.terminal`'s and `al5d.app.shell`'s. `answers`: what a client raises, and its
  stop's answer.
- `reading`: what a client hears of the arm (its state, joints and tool pose), kept from
  the lane or the ROS topics, with waits and callbacks.
- `leases`: the ROS clients' leases (who is still there, and each one's clock), and
  which requests are stale (pure); `leasing`: a client's side of its lease (its key, the
  lease sent while it hears the server, its goodbye), for the client and the web view.

This layer imports `al5d.owner`, `al5d.arm` (never the board's emulator) and rclpy.
"""
