"""ROS 2: the server's node, the mapping of messages to instructions, and the client.

- `runtime`: the public names (topics, services, the action), QoS profiles,
  starting a ROS context, the executor and its spin thread.
- `convert`: ROS messages <-> instructions and outcomes (pure).
- `node`: `ArmNode`, node `al5d` on an `ArmDriver`; `RosServer` runs it for `al5d serve`.
- `client`: `al5d send` and `al5d run`, a ROS client of the server.

This layer imports `al5d.arm` (never the board's emulator) and rclpy.
"""
