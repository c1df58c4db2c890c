"""Record a run, replay its poses and curve into fresh controllers, analyse the bag."""

import json
import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest
import rclpy

from conftest import DATA_DIR
from curve_formation.analysis import analyze_bag, load_bag_run
from curve_formation.bag import BagError, read_messages
from curve_formation.core import metrics
from curve_formation.runner import Run


pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    """A 6 s run of the fast closed-curve experiment, recorded to a bag."""
    import random
    folder = tmp_path_factory.mktemp('recorded')
    os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(1, 101))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    with Run(DATA_DIR / 'fast_closed.yaml', folder / 'run', bag_path=folder / 'bag',
             log=lambda *_: None) as run:
        run.spin_for(6.0)
        live = run.write_results()
    del os.environ['ROS_DOMAIN_ID']
    return folder, live


def commands_by_robot(bag):
    out = {i: [] for i in range(1, 7)}
    for topic, _, stamp, msg in read_messages(bag, [f'/robot_{i}/cmd_vel' for i in range(1, 7)]):
        out[int(topic.split('_')[1].split('/')[0])].append((stamp * 1e-9, msg.linear.x,
                                                            msg.angular.z))
    return {i: np.array(v) for i, v in out.items()}


def test_analysis_of_the_bag_matches_the_live_run(recorded, tmp_path):
    folder, live = recorded
    result = analyze_bag(folder / 'bag', tmp_path)
    assert result['experiment'] == 'fast_closed'
    assert result['phases'][0]['initial_error_norm'] == pytest.approx(
        live['phases'][0]['initial_error_norm'], rel=0.05)
    # The same error at the same times as the live monitor saw (the bag also covers the
    # shutdown, so its last sample is later).
    run = load_bag_run(folder / 'bag')
    traj = np.load(folder / 'run' / 'trajectory.npz')
    bag_norm = metrics.error_norm(metrics.target_errors(run.poses, run.phase, run.experiment))
    live_norm = metrics.error_norm(metrics.target_errors(traj['poses'], traj['phase'],
                                                         run.experiment))
    for t in (1.0, 3.0, 5.0):
        assert np.interp(t, run.t, bag_norm) == pytest.approx(
            np.interp(t, traj['t'], live_norm), rel=0.05)
    assert json.loads((tmp_path / 'metrics.json').read_text())['bag']['messages']
    assert (tmp_path / 'paths.png').stat().st_size > 10_000


def test_compare_overlays_two_runs(recorded, tmp_path):
    folder, _ = recorded
    result = analyze_bag(folder / 'bag', tmp_path, compare=folder / 'bag')
    assert result['compare']['final_error_norm'] == pytest.approx(result['final_error_norm'])
    assert (tmp_path / 'compare_error_norm.png').exists()


def test_truncated_bag_is_a_clear_error(recorded, tmp_path):
    folder, _ = recorded
    broken = tmp_path / 'broken'
    broken.mkdir()
    (broken / 'metadata.yaml').write_text((folder / 'bag' / 'metadata.yaml').read_text())
    data = (folder / 'bag' / 'bag.db3').read_bytes()
    (broken / 'bag.db3').write_bytes(data[: len(data) // 3])
    with pytest.raises(BagError, match='broken'):
        load_bag_run(broken)
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'analyze', str(broken),
                           '--out', str(tmp_path / 'o')], capture_output=True, text=True)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert proc.stderr.startswith('error: ')


def listen_on_bag_time(context):
    """A node on /clock time recording every robot's cmd_vel: (node, {i: [(t, v, w)]})."""
    from geometry_msgs.msg import Twist
    from rclpy.parameter import Parameter

    from curve_formation.nodes import qos
    node = rclpy.create_node('listener', context=context, parameter_overrides=[
        Parameter('use_sim_time', value=True)])
    got = {i: [] for i in range(1, 7)}
    for i in range(1, 7):
        node.create_subscription(Twist, f'/robot_{i}/cmd_vel', lambda m, i=i: got[i].append(
            (node.get_clock().now().nanoseconds * 1e-9, m.linear.x, m.angular.z)), qos.COMMAND)
    return node, got


# Flaky (about 1 run in 4 fails by ~0.2 rad/s on w where a robot rides its wheel limit): kept
# out of the default run until the comparison is redesigned; run it with `-m slow`.
@pytest.mark.slow
def test_replayed_poses_give_the_recorded_commands(recorded, tmp_path, ros_domain):
    """Fresh controllers on bag time (/clock) reproduce the recorded cmd_vel.

    The replayed controllers tick at 10 Hz of bag time but at their own phase, so a command is
    computed from a pose up to one tick (0.1 s) apart from the recording's. Each replayed
    command must lie within the range of the recorded commands less than two ticks (0.2 s)
    from it, widened by 10 % of the peak command: where a robot rides its wheel limit, (v, w)
    are scaled together and w changes by up to 0.25 rad/s between neighbouring ticks
    (measured). The first 2 s, while the controllers start one after the other, are left out.
    """
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    folder, _ = recorded
    env = dict(os.environ)
    procs = [subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.nodes.formation_controller', '--ros-args',
         '-r', f'__ns:=/robot_{i}', '--params-file',
         str(folder / 'run' / 'params' / f'robot_{i}.formation_controller.yaml'),
         '-p', 'use_sim_time:=true'], env=env, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL) for i in range(1, 7)]
    context = Context()
    rclpy.init(context=context)
    node, got = listen_on_bag_time(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        topics = ['/formation/curve'] + [f'/robot_{i}/pose' for i in range(1, 7)]
        replay = subprocess.run(
            [sys.executable, '-m', 'curve_formation.cli', 'replay', str(folder / 'bag'),
             '--topics', *topics, '--wait', '30'], env=env, capture_output=True, text=True,
            timeout=120)
        assert replay.returncode == 0, replay.stdout + replay.stderr
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            p.wait(20)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    recorded_cmds = commands_by_robot(folder / 'bag')
    first_motion = min(rec[np.abs(rec[:, 1:]).sum(axis=1) > 0][0, 0]
                       for rec in recorded_cmds.values())
    compared = 0
    for i in range(1, 7):
        rec = recorded_cmds[i]
        moving = rec[np.abs(rec[:, 1:]).sum(axis=1) > 0]
        peak = np.abs(moving[:, 1:]).max(axis=0)
        replayed = np.array([c for c in got[i] if c[0] > 1e9 and (c[1], c[2]) != (0.0, 0.0)])
        assert len(replayed) > 30, f'robot {i}: only {len(replayed)} replayed commands'
        for t, v, w in replayed[replayed[:, 0] >= first_motion + 2.0]:
            near = moving[np.abs(moving[:, 0] - t) <= 0.2]
            if len(near) == 0:
                continue
            lo, hi = near[:, 1:].min(axis=0) - 0.1 * peak, near[:, 1:].max(axis=0) + 0.1 * peak
            assert np.all((lo <= (v, w)) & ((v, w) <= hi)), (i, t, (v, w), lo, hi)
            compared += 1
    assert compared > 150   # about 40 ticks per robot from 2 s to 6 s


def tiny_bag(path, count=5, period_ms=20):
    """A bag of `count` std_msgs/Bool on /replay_test, `period_ms` apart, data alternating."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Bool

    from curve_formation.bag import BagWriter, qos
    with BagWriter(path) as writer:
        writer.add_topic('/replay_test', 'std_msgs/msg/Bool', qos(reliable=True))
        for k in range(count):
            writer.write('/replay_test', 1_000_000_000 + k * period_ms * 1_000_000,
                         serialize_message(Bool(data=k % 2 == 1)))
    return path


def test_replay_start_skips_the_beginning(tmp_path):
    from curve_formation.replay import load
    bag = tiny_bag(tmp_path / 'bag', count=10, period_ms=100)
    records, _ = load(bag, start=0.45)
    assert len(records) == 5
    assert records[0][0] == 1_000_000_000 + 500_000_000


def test_replay_loops_until_stopped(tmp_path, ros):
    from std_msgs.msg import Bool

    from curve_formation.replay import replay
    context, add, spin_until = ros
    bag = tiny_bag(tmp_path / 'bag')
    node = add(rclpy.create_node('player', context=context))
    received = []
    node.create_subscription(Bool, '/replay_test', lambda m: received.append(m.data), 10)
    stop = threading.Event()

    def joins():
        # The bag is F T F T F; passes join as ... F F T ...: two joins = 3 passes played.
        return sum(a is False and b is False
                   for a, b in zip(received, received[1:], strict=False))

    player = threading.Thread(target=replay, args=(node, bag), kwargs=dict(
        loop=True, clock=False, wait_for_subscribers=5.0, stop=stop, log=lambda *_: None))
    player.start()
    try:
        spin_until(lambda: joins() >= 2, timeout=10.0)
    finally:
        stop.set()
        player.join(5.0)
    assert not player.is_alive()   # and the stop event ended the loop
