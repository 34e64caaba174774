"""The live web view and control panel (`al5d web`): a ROS 2 client that serves one page.

Like RViz, it talks to the server over ROS (the public names of
`al5d.ros.names.Names`), in its own process, so that a browser never slows
the arm; its STOP also goes by the server's local lane where the server is on
this machine (`al5d.owner.quick`). The page is built with viser: the arm in
3D from /robot_description, moving with /joint_states, the target of the
running move as a ghost, sliders, a draggable target for the tool, presets,
STOP, what happened, and teach and replay (named poses, sequences).

    link.py    the ROS side: subscriptions, the instruction and jog publishers, the lease
    stopping.py  the page's STOP and RELEASE: sent by the lane or the topic, answers said
    plan.py    pure: targets of instructions, the outcome log, the joint history
    guard.py   who may open the page's websocket (same origin, known host names)
    loopsafe.py  viser's message buffers woken on their own loop, whichever thread sends
    scene.py   the 3D view: the arm, its ghost, the straight path, the target gizmo
    panel.py   the widgets: STOP in a window of its own, the side panel
    page.py    the page: what it knows of the arm, its decisions, the user's input
    jog.py     the sliders' jog: when a set-point is due, sent again, given up (no viser)
    sliders.py the sliders as the user moves them: read as they arrive, judged, into the jog
    viewhold.py  when the 3D view may change: a state goes to the browsers first
    target.py  the Target tab: the gizmo dragged, the numbers typed, `move_to` sent
    parts.py   what the tabs' input (sliders.py, target.py) uses of the page
    teach.py   the Teach tab: named poses, sequences built, saved, loaded and played
    player.py  a sequence played step by step, each outcome waited for (no viser, no ROS)
    calibrate.py  the Calibrate tab: the guided calibration (`al5d.arm.calibration`)
    twin.py    a physical twin's objects and arm in the 3D view, its camera and words (a tab)
    app.py     `al5d web`: the page on a port, until SIGINT/SIGTERM

Imports al5d.arm, al5d.model, al5d.ros (the public names, QoS, conversions),
rclpy and viser; nothing imports it but al5d.app.
"""
