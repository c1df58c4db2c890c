"""DDS discovery on this machine holds for more participants than Fast DDS's default range."""

import subprocess
import sys
import time

import pytest
import rclpy


pytestmark = pytest.mark.ros

LISTENER = """
import sys, rclpy
from std_msgs.msg import Bool
rclpy.init()
node = rclpy.create_node('listener_' + sys.argv[1])
node.create_subscription(Bool, '/discovery_probe', lambda m: None, 1)
print('ready', flush=True)
rclpy.spin(node)
"""


def test_a_late_participant_discovers_34_others(ros):
    """Runs of 16 robots have 34 processes. With ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST a
    participant announces itself only to the first maxInitialPeersRange participant ports
    (Fast DDS's default: 32); our profile widens it, so the last one to start (this test's,
    the curve server in a run) still finds every subscriber.
    """
    from std_msgs.msg import Bool
    context, add, spin_until = ros
    count = 34
    procs = [subprocess.Popen([sys.executable, '-c', LISTENER, str(k)], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True) for k in range(count)]
    try:
        for proc in procs:   # every listener's participant exists before ours
            # (Fast DDS may log to stdout first, e.g. a shared-memory port it could not lock)
            assert any(line.strip() == 'ready' for line in iter(proc.stdout.readline, ''))
        node = add(rclpy.create_node('late_publisher', context=context))
        publisher = node.create_publisher(Bool, '/discovery_probe', 1)
        start = time.monotonic()
        try:
            spin_until(lambda: publisher.get_subscription_count() == count, timeout=60.0)
        except AssertionError:
            pytest.fail(f'{publisher.get_subscription_count()} of {count} subscribers found '
                        f'in {time.monotonic() - start:.0f} s')
    finally:
        for proc in procs:
            proc.terminate()
        deadline = time.monotonic() + 60.0   # 35 participants leaving at once on 2 cores
        for proc in procs:
            try:   # drains stdout too: a listener blocked on a full pipe would never exit
                proc.communicate(timeout=max(deadline - time.monotonic(), 1.0))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
