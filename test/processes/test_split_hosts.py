"""The node graph split over four "hosts" (network namespaces on a bridge), as a lab deploys
it: `curve-formation run EXP --only PARTS` on each, one command per host.
"""

import json
import os
from pathlib import Path
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from conftest import SUPPORT
from netns_hosts import available, Hosts, stop_groups


pytestmark = pytest.mark.slow

WHY_NOT = available()
PARTS = {1: 'curve_server', 2: 'controllers', 3: 'robots', 4: 'observer'}
DURATION = 45.0
DOWN_AT, DOWN_FOR = 15.0, 2.0   # s after the first curve: the robots' host loses its link
CLI = str(Path(sys.executable).parent / 'curve-formation')
HOST_CLOCK = SUPPORT / 'host_clock'


def start(hosts, k, out, domain, discovery, clock_offset=0.0):
    # the host's clock clock_offset s ahead: test/support/host_clock (its sitecustomize)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
               PYTHONUNBUFFERED='1', CURVE_FORMATION_TEST_CLOCK_OFFSET=str(clock_offset),
               PYTHONPATH=os.pathsep.join([str(HOST_CLOCK), *filter(None, [
                   os.environ.get('PYTHONPATH')])]))
    argv = [CLI, 'run', 'arena_demo', '--only', PARTS[k], '--out', str(out / f'host{k}'),
            '--duration', str(DURATION)]
    if discovery:
        argv += ['--discovery-server', discovery]
    log = open(out / f'host{k}.log', 'w')
    return subprocess.Popen(hosts.prefix(k) + argv, env=env, stdout=log,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def wait_for_line(path, text, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in path.read_text():
            return time.monotonic()
        time.sleep(0.05)
    raise AssertionError(f'{path.name}: no {text!r} within {timeout} s:\n{path.read_text()}')


@pytest.mark.skipif(bool(WHY_NOT), reason=WHY_NOT or 'namespaces available')
@pytest.mark.parametrize('discovery', ['multicast', 'discovery server'])
def test_the_demo_split_over_four_hosts_settles_and_survives_a_lost_link(tmp_path, ros_domain,
                                                                          discovery):
    """Curve server, controllers, robots and observer each on a host of their own, talking
    UDP over the bridge, the robots' host's clock 3 s ahead of the others': the demo settles
    within 1.1x of the simulator's settling time plus the outage; while the robots' host is
    cut off for 2 s every controller stops (its poses are stale) and they all drive again
    once the link is back.
    """
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.core.record.metrics import settle_time
    from curve_formation.core.sim.batch import simulate
    from curve_formation.paths import discovery_server_command, resolve_config
    with Hosts(4) as hosts:
        server = None
        address = ''
        if discovery == 'discovery server':
            address = f'{hosts.address(1)}:11811'
            argv, env = discovery_server_command(hosts.address(1), 11811)
            server = subprocess.Popen(hosts.prefix(1) + argv, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      start_new_session=True)
        # the robots' host's clock 3 s ahead (no time sync): its poses' stamps are 3 s off
        runs = {k: start(hosts, k, tmp_path, ros_domain, address, 3.0 if k == 3 else 0.0)
                for k in PARTS}
        try:
            t0 = wait_for_line(tmp_path / 'host4.log', 'first curve received', 120.0)
            time.sleep(max(0.0, t0 + DOWN_AT - time.monotonic()))
            hosts.link(3, up=False)
            time.sleep(DOWN_FOR)
            hosts.link(3, up=True)
            assert runs[4].wait(timeout=DURATION + 60.0) == 0, (
                tmp_path / 'host4.log').read_text()
        finally:
            stop_groups([*runs.values(), server])
    result = json.loads((tmp_path / 'host4' / 'metrics.json').read_text())
    data = np.load(tmp_path / 'host4' / 'trajectory.npz')
    t, commands = data['t'], np.abs(data['commands']).sum(axis=2)
    # cut off: every controller stopped once its poses went stale (0.5 s), until the link
    # came back (the monitor's clock, so a loaded machine may shift the window a little)
    cut = (t > DOWN_AT + 0.8) & (t < DOWN_AT + DOWN_FOR - 0.2)
    assert cut.any() and np.all(commands[cut] == 0.0)
    before = (t > DOWN_AT - 3.0) & (t < DOWN_AT - 0.5)
    after = (t > DOWN_AT + DOWN_FOR + 1.5) & (t < DOWN_AT + DOWN_FOR + 4.0)
    assert (commands[before] > 0).any(axis=0).all() and (commands[after] > 0).any(axis=0).all()
    experiment = load_experiment(resolve_config('arena_demo'))
    sim = simulate(experiment)
    tolerance = 1e-3 * experiment.phases[0].curve.size()
    sim_settle = settle_time(sim.t, sim.error_norm, tolerance, 0.0, np.inf)
    phase = result['phases'][0]
    print(f'{discovery}: settled in {phase["settle_time"]} s (simulator {sim_settle:.1f} s, '
          f'+{DOWN_FOR:g} s cut off)')
    assert phase['settled'] and phase['settle_time'] < 1.1 * sim_settle + DOWN_FOR


@pytest.mark.skipif(bool(WHY_NOT), reason=WHY_NOT or 'namespaces available')
def test_hosts_are_cut_off_by_their_link_not_shared_memory(ros_domain):
    """A message crosses from one host to another over the bridge, and not with the link down
    (Fast DDS takes the namespaces for different hosts: no shared-memory shortcut).
    """
    code = ('import sys, time, rclpy\n'
            'from std_msgs.msg import String\n'
            'rclpy.init()\n'
            'node = rclpy.create_node("n" + sys.argv[1])\n'
            'got = []\n'
            'if sys.argv[1] == "pub":\n'
            '    pub = node.create_publisher(String, "/probe", 10)\n'
            '    end = time.monotonic() + 6\n'
            '    while time.monotonic() < end:\n'
            '        pub.publish(String(data="x")); rclpy.spin_once(node, timeout_sec=0.1)\n'
            'else:\n'
            '    node.create_subscription(String, "/probe", got.append, 10)\n'
            '    end = time.monotonic() + 6\n'
            '    while time.monotonic() < end: rclpy.spin_once(node, timeout_sec=0.1)\n'
            '    print(len(got))\n')
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET')
    counts = {}
    with Hosts(2, net=232) as hosts:
        for up in (True, False):
            hosts.link(2, up)
            sub = subprocess.Popen(hosts.prefix(2) + [sys.executable, '-c', code, 'sub'],
                                   env=env, stdout=subprocess.PIPE, text=True)
            pub = threading.Thread(target=subprocess.run, args=(
                hosts.prefix(1) + [sys.executable, '-c', code, 'pub'],), kwargs={'env': env})
            pub.start()
            out, _ = sub.communicate(timeout=30)
            pub.join()
            counts[up] = int(out.strip().splitlines()[-1])
    assert counts[True] > 20 and counts[False] == 0, counts
