"""A node's last messages before it ends are acknowledged by a reader in another process
within the node's wait (nodes/runtime.py shut_down; the writer profiles in fastdds_udp.xml):
a reader acknowledges only on the writer's heartbeat, every 3 s by Fast DDS's default.
"""

import subprocess
import sys

import pytest

from curve_formation.nodes import topics


READER = """
import sys, rclpy
from curve_formation.nodes import topics
from curve_formation.paths import use_dds_profile
use_dds_profile()
rclpy.init()
node = rclpy.create_node('last_messages_reader')
topics.subscription(node, sys.argv[1], lambda message: None)
print('ready', flush=True)
try:
    rclpy.spin(node)
except BaseException:
    pass
"""

WRITER = """
import sys, time, rclpy
from rclpy.duration import Duration
from curve_formation.nodes import topics
from curve_formation.paths import use_dds_profile
use_dds_profile()
rclpy.init()
node = rclpy.create_node('last_messages_writer')
publisher = topics.publisher(node, sys.argv[1])
deadline = time.monotonic() + 20.0
while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(1.0)   # the match settled on both sides
for _ in range(3):
    publisher.publish(topics.REGISTRY[sys.argv[1]].msg_class())
    print(publisher.wait_for_all_acked(Duration(seconds=1.0)), flush=True)
    time.sleep(0.3)
"""


@pytest.mark.parametrize('topic', [topics.DIAGNOSTICS, topics.CURVE, topics.ESTOP])
def test_a_last_message_is_acknowledged_within_a_second(ros_domain, topic):
    """The fake arena's last contact tally, the curve server's last curve and the e-stop
    command's last message (each waited for 1 s or less): acknowledged, 3 times of 3, by a
    reader in another process (the tally, without its writer profile: 1 of 3).
    """
    reader = subprocess.Popen([sys.executable, '-c', READER, topic], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert reader.stdout.readline().strip() == 'ready'
        writer = subprocess.run([sys.executable, '-c', WRITER, topic], capture_output=True,
                                text=True, timeout=60)
    finally:   # the reader is the test's own: one that hangs as it ends is killed
        reader.terminate()
        try:
            reader.wait(10)
        except subprocess.TimeoutExpired:   # once, in a loaded default run
            reader.kill()
            reader.wait(10)
    assert writer.stdout.split() == ['True'] * 3, writer.stdout + writer.stderr
