"""DDS discovery in the test's process: a late participant finds more participants than
Fast DDS's default range on this machine, and a second formation on a domain is refused.
"""

import os
import subprocess
import sys
import time

import pytest
import rclpy

from conftest import DATA_DIR


# `count` participants (one per rclpy context) in one process, each with a subscriber; DDS
# discovery runs in Fast DDS's own threads, so nothing needs spinning.
LISTENERS = """
import sys, time, rclpy
from rclpy.context import Context
from std_msgs.msg import Bool
first, count = int(sys.argv[1]), int(sys.argv[2])
nodes = []
for k in range(first, first + count):
    context = Context()
    rclpy.init(context=context)
    nodes.append(rclpy.create_node(f'listener_{k}', context=context))
    nodes[-1].create_subscription(Bool, '/discovery_probe', lambda m: None, 1)
print('ready', flush=True)
while True:
    time.sleep(1.0)
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
    # two processes of 17 participants (one rclpy context each): the same participant ports
    # as 34 processes, started in seconds
    procs = [subprocess.Popen([sys.executable, '-c', LISTENERS, str(first), str(count // 2)],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
             for first in (0, count // 2)]
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
            # The writer goes while its 34 readers live: destroyed after they were killed,
            # Fast DDS 2.14 hung in Publisher.destroy for over 5 minutes once (2026-12-03).
            node.destroy_publisher(publisher)
    finally:
        for proc in procs:
            proc.terminate()
        deadline = time.monotonic() + 60.0
        for proc in procs:
            try:   # drains stdout too: a listener blocked on a full pipe would never exit
                proc.communicate(timeout=max(deadline - time.monotonic(), 1.0))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()


def test_a_second_formation_on_a_domain_is_refused(ros, tmp_path):
    """A curve server already serves the domain (here a stand-in publishing the curve):
    `run` says so before its own curve server starts, and with real robots before any of their
    controllers starts.
    """
    from curve_formation.nodes import topics
    context, add, _ = ros
    stand_in = add(rclpy.create_node('curve_server', context=context))
    topics.publisher(stand_in, topics.CURVE)
    domain = os.environ['ROS_DOMAIN_ID']
    for real in (True, False):
        out = tmp_path / ('real' if real else 'simulated')
        proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'run',
                               str(DATA_DIR / 'fast_closed.yaml'), '--out', str(out),
                               '--duration', '3'] + (['--no-sim'] if real else []),
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, proc.stdout + proc.stderr
        assert (f'error: a formation is already running on ROS_DOMAIN_ID={domain} (discovery '
                'LOCALHOST)') in proc.stderr
        assert '--isolated' in proc.stderr
        if real:   # no controller of real robots started before the domain was looked at
            assert not [*(out / 'logs').glob('*formation_controller*'),
                        *(out / 'logs').glob('controllers_*')]   # a process each, or groups
