"""The web view's twin (issue 47): a physical twin's objects, its arm beside the commanded
one, its camera's picture and its words reach the page over DDS, as a twin publishes
them; a page without a twin shows none of it."""

from __future__ import annotations

import numpy as np
import viser
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from al5d.arm.config import ArmConfig
from al5d.model import JOINTS, urdf
from al5d.ros.dds import start_context
from al5d.ros.names import Names
from al5d.twin.node import QOS_PICTURES, QOS_WORDS
from al5d.web.page import Page
from al5d.web.twin import TwinView
from al5d_rig.rospeer import wait_until


def test_the_page_shows_a_twins_objects_arm_picture_and_words(config: ArmConfig) -> None:
    names = Names()
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    page = Page(server, config, "al5d test")
    context = start_context()
    view = TwinView(page, context, names)
    twin = Node("al5d_test_twin", context=start_context())
    try:
        page.on_description(urdf(config.model, dict.fromkeys(JOINTS, 90.0)))
        assert view.objects == {} and view.picture is None and view.robot is None
        objects = twin.create_publisher(MarkerArray, names.twin_objects, 10)
        joints = twin.create_publisher(JointState, names.twin_joint_states, 10)
        pictures = twin.create_publisher(Image, names.camera_image, QOS_PICTURES)
        words = twin.create_publisher(String, names.twin_held, QOS_WORDS)

        cup = Marker(ns="cup", type=Marker.CYLINDER, text="cup")
        cup.scale.x = cup.scale.y = 0.026
        cup.scale.z = 0.055
        cup.pose.position.x, cup.pose.position.z = 0.2, 0.0275
        cup.color.r, cup.color.a = 0.85, 1.0
        block = Marker(ns="block", type=Marker.CUBE)
        block.scale.x = block.scale.y = block.scale.z = 0.04
        picture = Image(height=24, width=32, encoding="rgb8", step=96)
        picture.data = np.full((24, 32, 3), 200, dtype=np.uint8).tobytes()
        values = config.model.to_urdf(config.presets["ready"])

        def publish() -> bool:
            objects.publish(MarkerArray(markers=[cup, block]))
            joints.publish(JointState(name=list(values), position=list(values.values())))
            pictures.publish(picture)
            words.publish(String(data="shoulder held 12 deg short of its target"))
            return (
                {"cup", "block"} <= set(view.objects)
                and view.robot is not None
                and view.picture is not None
                and bool(view.words)
            )

        wait_until(publish, 30, "the twin's messages on the page")
        assert tuple(view.objects["cup"].position) == (0.2, 0.0, 0.0275)
        assert view.picture.image.shape == (24, 32, 3)
        assert "shoulder held 12 deg short" in view.words_md.content
        assert view.robot.get_actuated_joint_names()  # the twin's arm, from the page's URDF
    finally:
        twin.destroy_node()
        twin.context.try_shutdown()
        view.close()
        context.try_shutdown()
        page.close()
        server.stop()
