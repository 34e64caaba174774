"""ROS 2: the server's nodes, the mapping of messages to instructions, and the client.

- `runtime`: the public names (topics, services, the action), QoS profiles,
  starting a ROS context, the executor and its spin thread.
- `workarounds`: what rclpy does not give the server, and how it is had here.
- `convert`: ROS messages <-> instructions and outcomes (pure).
- `node`: the nodes on an `ArmDriver`: `ArmNode` (node `al5d`: the topics, the results,
  the state), `RobotNode` (node `al5d_robot`) and `ActionsNode` (node `al5d_actions`).
- `safety`: node `al5d_safety` (the stop, release and shutdown services) and node
  `al5d_stop_watcher` (a stop on the instruction topic, obeyed at once).
- `params`: `al5d serve`'s settings as ROS parameters of the node `al5d`.
- `server`: `RosStart` and `RosServer`, every node put together for `al5d serve`.
- `robot`: the robot's description, joint states and transforms.
- `actions`: the move action; `controllers`: MoveIt's FollowJointTrajectory and
  GripperCommand.
- `client`: `al5d send`, `al5d run`, `al5d shell` and `Client`, a ROS client of the server.

This layer imports `al5d.arm` (never the board's emulator) and rclpy.
"""
