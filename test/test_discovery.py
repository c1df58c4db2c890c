"""DDS discovery: more participants than Fast DDS's default range on this machine, and a run
through a Fast DDS discovery server (for networks where multicast fails).
"""

import os
import random
import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy

from conftest import DATA_DIR
from curve_formation import runner
from curve_formation.paths import discovery_server_command


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


def test_a_run_discovers_through_a_discovery_server_and_only_through_it(ros_domain, tmp_path,
                                                                         monkeypatch):
    """`run --discovery-server` sets ROS_DISCOVERY_SERVER: every node is the server's client
    and finds the others through it, with the range SUBNET (runner.use_discovery). Pointed
    at a port where no server listens, nothing is found: discovery went through the server.
    Traffic stays on this machine (the server on 127.0.0.1, the peers' own addresses).
    """
    port = random.SystemRandom().randint(5000, 5998)   # below our links' and DDS's ports
    argv, env = discovery_server_command('127.0.0.1', port)
    server = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True)
    try:
        assert any('Server is running' in line for line in iter(server.stdout.readline, ''))
        monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE')
        monkeypatch.setenv('ROS_DISCOVERY_SERVER', f'127.0.0.1:{port}')
        with runner.Run(DATA_DIR / 'fast_closed.yaml', tmp_path / 'served', log=quiet) as run:
            run.spin_for(2.0)
            assert (np.abs(run.monitor.commands).sum(axis=1) > 0).all()
            assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
        assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in os.environ   # given back at stop
        monkeypatch.setenv('ROS_DISCOVERY_SERVER', f'127.0.0.1:{port + 1}')
        monkeypatch.setattr(runner, 'READY_TIMEOUT', 8.0)
        with pytest.raises(TimeoutError, match='pose'):
            with runner.Run(DATA_DIR / 'fast_closed.yaml', tmp_path / 'unserved', log=quiet):
                pass
    finally:
        server.terminate()
        server.wait(10)


def test_a_discovery_server_with_a_local_range_is_refused():
    env = {'ROS_DISCOVERY_SERVER': '10.0.0.2:11811', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    with pytest.raises(ValueError, match='ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST'):
        runner.use_discovery(env)
    env = {'ROS_DISCOVERY_SERVER': '10.0.0.2:11811'}
    runner.use_discovery(env)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
    env = {}
    runner.use_discovery(env)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'


def quiet(*_):
    pass
