"""DDS discovery of a run: through a Fast DDS discovery server (for networks where multicast
fails) and only through it, and the domain and environment a run takes and gives back.
"""

import json
import os
import random
import subprocess
import sys

import pytest

from conftest import DATA_DIR
from curve_formation import paths
from curve_formation.paths import discovery_server_command


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
    from curve_formation.paths import run_domain_id
    monkeypatch.delenv('ROS_DOMAIN_ID')
    assert run_domain_id(False) == 0          # ROS's default, where the lab's tools are
    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    assert run_domain_id(False) == 42
    assert {run_domain_id(True) for _ in range(50)} - {42} <= set(range(1, 102))
    monkeypatch.setenv('ROS_DOMAIN_ID', 'lab')
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID='lab': expected a domain id"):
        run_domain_id(False)
