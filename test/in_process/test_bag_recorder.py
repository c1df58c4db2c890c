"""The bag recorder over DDS: a late recorder accounts exactly for what it missed, and the
recorder console script records what the test's nodes publish.
"""

import signal
import subprocess
import sys

from geometry_msgs.msg import Twist
import pytest
import rclpy

from curve_formation.bags.analysis import bag_accounting
from curve_formation.bags.bag import BagWriter, read_messages
from curve_formation.nodes.runtime import PublicationCounter


def test_a_late_recorder_accounts_exactly_over_dds(ros, tmp_path):
    """Messages published before the recorder was matched are not expected in the bag; the
    ones after are, to the message, and their DDS sequence numbers say which is which.
    """
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from curve_formation.nodes import topics
    from curve_formation.nodes.recorder import Recorder
    context, add, spin_until = ros
    node = add(rclpy.create_node('talker', context=context))
    cmd = '/robot_1/cmd_vel'
    publisher = node.create_publisher(Twist, cmd, QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))
    counter = PublicationCounter(node)
    for _ in range(5):
        publisher.publish(Twist())
    with BagWriter(tmp_path / 'bag') as writer:
        recorder = add(Recorder(writer, [t for t in topics.recorded(1) if t.name == cmd],
                                context=context))
        spin_until(lambda: publisher.get_subscription_count() == 1)
        for _ in range(20):
            publisher.publish(Twist())
        spin_until(lambda: recorder.received[cmd] == 20)
    folder = tmp_path / 'publications'
    folder.mkdir()
    counter.save(folder, 'talker')
    out = bag_accounting(tmp_path / 'bag', folder, recorder.streams)
    assert recorder.streams[cmd]['first'] == 6 and recorder.streams[cmd]['in_order']
    assert out['topics'][cmd] == {'published': 25, 'expected': 20, 'recorded': 20, 'lost': 0,
                                  'best_effort': False}


def test_recorder_console_script_records_over_dds(ros, ros_env, tmp_path):
    """`ros2 run curve_formation formation_recorder` in its own process (its executor is the
    one every node process spins) records what is published here and closes its bag on SIGINT.
    """
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    context, add, spin_until = ros
    path = tmp_path / 'bag'
    proc = subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.nodes.recorder', '--ros-args',
         '-p', f'bag:={path}', '-p', 'agent_count:=1'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env)
    try:
        node = add(rclpy.create_node('talker', context=context))
        cmd = '/robot_1/cmd_vel'
        publisher = node.create_publisher(Twist, cmd, QoSProfile(
            depth=20, reliability=ReliabilityPolicy.RELIABLE))   # keeps a burst of 20
        spin_until(lambda: publisher.get_subscription_count() == 1 or proc.poll() is not None,
                   timeout=60)
        for k in range(20):
            msg = Twist()
            msg.linear.x = 0.001 * k
            publisher.publish(msg)
        assert publisher.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    got = [m.linear.x for topic, _, _, m in read_messages(path) if topic == cmd]
    assert got == pytest.approx([0.001 * k for k in range(20)]), out
