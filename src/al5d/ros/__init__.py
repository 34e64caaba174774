"""ROS 2: the server's node, the mapping of messages to instructions, and the client.

- `runtime`: the public names (topics, services, the action), QoS profiles,
  starting a ROS context, the executor and its spin thread.
- `workarounds`: what rclpy does not give the server, and how it is had here.
- `convert`: ROS messages <-> instructions and outcomes (pure).
- `node`: `ArmNode` (node `al5d`), `RobotNode` and `ActionsNode` on an `ArmDriver`;
  `RosServer` runs them for `al5d serve`.
- `safety`: the stop, release and shutdown services, and the stop watcher.
- `robot`: the robot's description, joint states and transforms.
- `actions`: the move action; `controllers`: MoveIt's FollowJointTrajectory and
  GripperCommand.
- `client`: `al5d send` and `al5d run`, a ROS client of the server.

This layer imports `al5d.arm` (never the board's emulator) and rclpy.
"""
