"""DDS discovery: more participants than Fast DDS's default range on this machine, and a run
through a Fast DDS discovery server (for networks where multicast fails).
"""

import json
import os
import random
import subprocess
import sys
import time

import pytest
import rclpy

from conftest import DATA_DIR
from curve_formation import paths
from curve_formation.paths import discovery_server_command


pytestmark = pytest.mark.ros

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


# A run in its own process: Fast DDS keeps the discovery settings of the first participant a
# process creates, so a run through a server inside the test process would leave every later
# test of that process a client of a server that is gone.
UNSERVED_RUN = """
import sys
from curve_formation.run import runner
runner.READY_TIMEOUT = 8.0
try:
    with runner.Run(sys.argv[1], sys.argv[2], log=lambda *_: None):
        print('started')
except TimeoutError as exc:
    print('timeout:', exc)
"""


# Behind `-m slow` (25 s), with the split-host runs that discover through a server on their
# own host (test_split_hosts.py).
@pytest.mark.slow
def test_a_run_discovers_through_a_discovery_server_and_only_through_it(ros_domain, tmp_path):
    """`run --discovery-server` sets ROS_DISCOVERY_SERVER: every node is the server's client
    and finds the others through it, with the range SUBNET (paths.use_discovery). Pointed
    at a port where no server listens, nothing is found: discovery went through the server.
    Traffic stays on this machine (the server on 127.0.0.1, the peers' own addresses).
    """
    port = random.SystemRandom().randint(5000, 5998)   # below our links' and DDS's ports
    argv, env = discovery_server_command('127.0.0.1', port)
    server = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True)
    env = {k: v for k, v in os.environ.items() if k != 'ROS_AUTOMATIC_DISCOVERY_RANGE'}
    experiment = str(DATA_DIR / 'fast_closed.yaml')
    try:
        assert any('Server is running' in line for line in iter(server.stdout.readline, ''))
        served = subprocess.run(
            [sys.executable, '-m', 'curve_formation.cli', 'run', experiment, '--duration', '3',
             '--out', str(tmp_path / 'served'), '--discovery-server', f'127.0.0.1:{port}'],
            env=env, capture_output=True, text=True, timeout=120)
        assert served.returncode == 0, served.stderr
        assert f'discovery SUBNET through the server 127.0.0.1:{port}' in served.stdout
        metrics = json.loads((tmp_path / 'served' / 'metrics.json').read_text())
        phase = metrics['phases'][0]   # the robots drove, towards the curve
        assert metrics['peak_v'] > 0 and phase['final_error_norm'] < phase['initial_error_norm']
        unserved = subprocess.run(
            [sys.executable, '-c', UNSERVED_RUN, experiment, str(tmp_path / 'unserved')],
            env=dict(env, ROS_DISCOVERY_SERVER=f'127.0.0.1:{port + 1}'), capture_output=True,
            text=True, timeout=120)
        assert 'timeout:' in unserved.stdout and 'pose' in unserved.stdout, unserved
    finally:
        server.terminate()
        server.wait(10)


def test_a_discovery_server_with_a_local_range_is_refused():
    env = {'ROS_DISCOVERY_SERVER': '10.0.0.2:11811', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    with pytest.raises(ValueError, match='ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST'):
        paths.use_discovery(env)
    env = {'ROS_DISCOVERY_SERVER': '10.0.0.2:11811'}
    paths.use_discovery(env)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
    env = {}
    paths.use_discovery(env)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}   # an isolated run stays on this machine
    paths.use_discovery(env)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    env = {}   # a lab's run: the caller's range, ROS's default when unset
    paths.use_discovery(env, isolated=False)
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in env




def test_a_runs_environment_is_given_back_after_it(monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', '7')
    monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE', raising=False)
    monkeypatch.delenv('ROS_DISCOVERY_SERVER', raising=False)
    with paths.ros_environment(42, '127.0.0.1:11811'):
        assert os.environ['ROS_DOMAIN_ID'] == '42'
        assert os.environ['ROS_DISCOVERY_SERVER'] == '127.0.0.1:11811'
        assert paths.discovery_text() == 'SUBNET through the server 127.0.0.1:11811'
    assert os.environ['ROS_DOMAIN_ID'] == '7'
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in os.environ
    assert 'ROS_DISCOVERY_SERVER' not in os.environ
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')
    with pytest.raises(ValueError, match='OFF'):   # refused, and nothing left changed
        with paths.ros_environment(42, '127.0.0.1:11811'):
            pass
    assert os.environ['ROS_DOMAIN_ID'] == '7' and 'ROS_DISCOVERY_SERVER' not in os.environ


def test_a_run_takes_the_callers_domain_and_an_isolated_one_a_private_domain(monkeypatch):
    from curve_formation.run.runner import run_domain_id
    monkeypatch.delenv('ROS_DOMAIN_ID')
    assert run_domain_id(False) == 0          # ROS's default, where the lab's tools are
    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    assert run_domain_id(False) == 42
    assert {run_domain_id(True) for _ in range(50)} - {42} <= set(range(1, 102))
    monkeypatch.setenv('ROS_DOMAIN_ID', 'lab')
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID='lab': expected a domain id"):
        run_domain_id(False)


@pytest.mark.ros
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
            assert not list((out / 'logs').glob('*formation_controller*'))

