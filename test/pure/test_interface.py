"""The ROS interface as plain data (curve_formation/interface.py): ROS-free, and the rclpy side
built from it agrees with it.
"""

import subprocess
import sys

from curve_formation import interface


def test_the_interface_the_analysis_and_measure_link_import_no_rclpy():
    code = ('import sys; import curve_formation.interface, curve_formation.bags.analysis, '
            'curve_formation.bags.measure_link; '
            "print(sorted(m for m in sys.modules "
            "if m.split('.')[0] in ('rclpy', 'rosidl_runtime_py')))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == '[]', out


def test_every_topic_and_profile_the_nodes_use_is_the_interfaces():
    from rclpy.qos import (
        DurabilityPolicy,
        HistoryPolicy,
        qos_profile_sensor_data,
        ReliabilityPolicy,
    )

    from curve_formation.nodes import qos, topics
    assert set(topics.REGISTRY) == set(interface.TOPICS)
    for name, spec in interface.TOPICS.items():
        topic = topics.REGISTRY[name]
        assert topic.type_name == spec.type_name   # the class resolved from the type name
        assert topic.profile == qos.profile(spec.qos)
        assert topic.reader_qos == interface.QOS[spec.reader_qos_name or spec.qos_name]
    for name, spec in interface.QOS.items():
        profile = getattr(qos, name)
        assert (profile.reliability == ReliabilityPolicy.RELIABLE) == spec.reliable
        assert ((profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
                == spec.transient_local)
        assert (profile.history == HistoryPolicy.KEEP_ALL) == (spec.depth is None)
        assert spec.depth is None or profile.depth == spec.depth
    assert qos.SENSOR == qos_profile_sensor_data


def test_per_robot_names_are_placed_and_read_back():
    assert interface.robot_topic(3, interface.POSE) == '/robot_3/pose'
    assert interface.robot_of('/robot_12/cmd_vel') == (12, 'cmd_vel')
    assert interface.robot_of('/formation/curve') is None
    assert interface.robot_of('/robot_x/pose') is None
    assert interface.robot_of('/robot_2/pose', among=(interface.POSE,)) == (2, 'pose')
    assert interface.robot_of('/robot_2/cmd_vel', among=(interface.POSE,)) is None
    assert interface.type_name('/robot_4/disturbance_estimate') == \
        'geometry_msgs/msg/Vector3Stamped'
    assert interface.type_name(interface.CURVE) == 'std_msgs/msg/Float64MultiArray'
    assert interface.type_name('/pose') is None        # per-robot names only under a robot
    assert interface.type_name('/robot_1/lidar') is None


def test_a_state_message_carries_news_of_the_leader_that_came_after_the_pose():
    """leader_age is the news's age when the pose was taken: slightly negative for news that
    came after it, and NO_NEWS (not a small negative age) before any.
    """
    from curve_formation.core.controller.inputs import State
    from curve_formation.nodes import messages
    for age in (0.4, 0.0, -0.03, None):
        msg = messages.state_to_msg(State((0.01, -0.02), 3, 12.5, age))
        assert messages.state_from_msg(msg) == (0.01, -0.02, 3, 12.5, age)
