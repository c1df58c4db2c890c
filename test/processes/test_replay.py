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

from cases import tiny_bag
from conftest import DATA_DIR
from curve_formation.bags.analysis import analyze_bag, load_bag_run
from curve_formation.bags.bag import BagError, read_messages
from curve_formation.core.record import metrics


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
    result = analyze_bag(folder / 'bag', tmp_path / 'bags', compare=folder / 'bag')
    assert result['compare']['final_error_norm'] == pytest.approx(result['final_error_norm'])
    assert (tmp_path / 'bags' / 'compare_error_norm.png').exists()
    # the real run against a simulated one, from its folder (sim writes trajectory.npz)
    from curve_formation.cli import main
    assert main(['sim', str(DATA_DIR / 'fast_closed.yaml'), '--out', str(tmp_path / 'sim'),
                 '--rate', '10']) in (0, None)
    result = analyze_bag(folder / 'bag', tmp_path / 'real_vs_sim', compare=tmp_path / 'sim')
    simulated = json.loads((tmp_path / 'sim' / 'metrics.json').read_text())
    assert result['compare']['phases'][0]['initial_error_norm'] == pytest.approx(
        simulated['phases'][0]['initial_error_norm'])
    assert (tmp_path / 'real_vs_sim' / 'compare_error_norm.png').exists()


def test_a_topic_of_a_type_unknown_here_does_not_stop_the_analysis(recorded, tmp_path):
    """A lab records its own topics beside ours (`ros2 bag record -a`): the run's bag with a
    topic of a type no reader here knows is analysed as the bag alone is.
    """
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer

    from curve_formation.bags.bag import TYPESTORE
    folder, _ = recorded
    mixed = tmp_path / 'mixed'
    with Reader(folder / 'bag') as reader, \
            Writer(mixed, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for key, value in (reader.storage.metadata.custom or {}).items():
            writer.set_custom_data(key, value)
        out = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=TYPESTORE)
               for c in reader.connections}
        mystery = writer.add_connection('/lab/mystery', 'lab_msgs/msg/Mystery',
                                        msgdef='int32 x', rihs01='RIHS01_' + '0' * 64)
        for conn, stamp, raw in reader.messages():
            writer.write(out[conn.id], stamp, raw)
            if conn.topic == '/formation/curve':
                writer.write(mystery, stamp, b'\x00\x01\x00\x00\x2a\x00\x00\x00')
    alone = analyze_bag(folder / 'bag', tmp_path / 'alone')
    beside = analyze_bag(mixed, tmp_path / 'beside')
    assert beside['final_error_norm'] == pytest.approx(alone['final_error_norm'])
    assert beside['phases'][0]['settled'] == alone['phases'][0]['settled']


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


def listen_to_ticks(context):
    """A node recording every robot's control_tick: (node, {i: [{name: value}]})."""
    from sensor_msgs.msg import JointState

    from curve_formation.nodes import messages, qos
    node = rclpy.create_node('listener', context=context)
    got = {i: [] for i in range(1, 7)}
    for i in range(1, 7):
        node.create_subscription(JointState, f'/robot_{i}/control_tick', lambda m, i=i: got[
            i].append(messages.tick_from_msg(m)), qos.STATE)
    return node, got


def tick_key(tick):
    """The inputs a tick came from: its own pose stamp and its neighbours' state stamps."""
    return tuple(sorted((name, round(value, 9)) for name, value in tick.items()
                        if name not in ('v', 'w')))


def robot_of(topic):
    """3 for '/robot_3/pose'."""
    return int(topic.split('/')[1].split('_')[1])


def recorded_ticks(bag):
    from curve_formation.nodes import messages
    out = {i: [] for i in range(1, 7)}
    for topic, _, _, msg in read_messages(bag, [f'/robot_{i}/control_tick' for i in range(1, 7)]):
        out[robot_of(topic)].append(messages.tick_from_msg(msg))
    return out


@pytest.mark.slow   # 45 s: the default run stays under 10 minutes
def test_replayed_inputs_give_the_recorded_commands(recorded, tmp_path, ros_domain):
    """Fresh controllers on bag time (/clock), fed the bag's poses, curve and neighbour
    states, compute exactly the recorded law on the recorded inputs.

    Each controller publishes with every command the stamps of the inputs it used (own pose,
    each in-neighbour's state); the fresh controllers' own states go to another topic, so
    each sees the recorded neighbour states. A replayed tick falls at its own phase of the
    10 Hz bag-time clock (on sim time the timer runs on a grid of bag time), so it does not
    see the same latest pose or state as the recorded tick did: a follower's command is then
    a different one (measured: up to 0.8 rad/s apart from the recorded command nearest in
    time, robots at 2 m/s). So every replayed command must equal, to 1e-9, the law (core)
    evaluated on the bag's messages it names, and equal the recorded command wherever a
    recorded tick used the same inputs (this experiment has no estimator state). Stopped
    (zero) commands are not compared.
    """
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    folder, _ = recorded
    env = dict(os.environ)
    procs = [subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.nodes.formation_controller', '--ros-args',
         '-r', f'__ns:=/robot_{i}', '--params-file',
         str(folder / 'run' / 'params' / f'robot_{i}.formation_controller.yaml'),
         '-p', 'use_sim_time:=true', '-r', 'formation_state:=replayed_state'], env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(1, 7)]
    context = Context()
    rclpy.init(context=context)
    node, got = listen_to_ticks(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        topics = ['/formation/curve'] + [f'/robot_{i}/{name}' for i in range(1, 7)
                                         for name in ('pose', 'formation_state')]
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
    law = law_on_bag_inputs(folder / 'bag')
    recorded_by_robot = recorded_ticks(folder / 'bag')
    twins = 0
    for i in range(1, 7):
        table = {tick_key(t): (t['v'], t['w']) for t in recorded_by_robot[i]}
        moving = [t for t in got[i] if (t['v'], t['w']) != (0.0, 0.0)]
        assert len(moving) > 30, f'robot {i}: only {len(moving)} replayed commands'
        for t in moving:
            assert (t['v'], t['w']) == pytest.approx(law(i, t), abs=1e-9), (i, t)
            original = table.get(tick_key(t))
            if original is not None and original != (0.0, 0.0):
                assert (t['v'], t['w']) == pytest.approx(original, abs=1e-9), (i, t, original)
                twins += 1
    print(f'{twins} replayed ticks used the same inputs as a recorded one')


def law_on_bag_inputs(bag):
    """law(i, tick) -> (v, w): agent i's law (core) evaluated on the bag's messages whose
    stamps the tick names: its pose and its in-neighbours' states.
    """
    from curve_formation.core.controller.agent import AgentController
    from curve_formation.core.controller.agent_config import AgentConfig
    from curve_formation.nodes import messages
    run = load_bag_run(bag)
    experiment = run.experiment
    poses, states = {}, {}
    names = [f'/robot_{i}/{kind}' for i in range(1, 7) for kind in ('pose', 'formation_state')]
    for topic, _, _, msg in read_messages(bag, names):
        robot = robot_of(topic)
        if topic.endswith('/pose'):
            x, y, theta, stamp = messages.pose_from_msg(msg)
            poses[robot, round(stamp, 9)] = (x, y, theta, stamp)
        else:
            state = messages.state_from_msg(msg)
            states[robot, round(state[3], 9)] = state
    phase = experiment.phases[0]

    def law(i, tick):
        ctrl = AgentController(AgentConfig(
            index=i, agent_count=experiment.n, neighbours=tuple(
                experiment.graph.in_neighbours(i)), gains=experiment.gains,
            pinning=experiment.graph.follower_pinning, limits=experiment.limits,
            rate_hz=experiment.spec.controller.rate_hz))
        ctrl.set_curve(phase.curve, 0, phase.s)
        pose = poses[i, round(tick['pose_stamp'], 9)]
        # Freshness was the node's to judge, on receipt (core.controller.agent): here every input
        # the tick named counts as just received.
        ctrl.on_pose(*pose, received=pose[3])
        for name, stamp in tick.items():
            if name.startswith('stamp_'):
                j = int(name.split('_')[1])
                ctrl.on_neighbour(j, *states[j, round(stamp, 9)], received=pose[3])
        out = ctrl.tick(pose[3])
        assert out.stopped is None, out.stopped
        return out.v, out.w
    return law


def test_replay_start_skips_the_beginning(tmp_path):
    from curve_formation.bags.replay import load
    bag = tiny_bag(tmp_path / 'bag', count=10, period_ms=100)
    records, _ = load(bag, start=0.45)
    assert len(records) == 5
    assert records[0][0] == 1_000_000_000 + 500_000_000


def test_a_bag_of_another_tool_says_what_is_missing(tmp_path):
    """`analyze` on bags it cannot use: one error line each, never a traceback."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    from curve_formation.bags.bag import BagWriter, qos
    other = tmp_path / 'other'
    with BagWriter(other) as writer:      # /formation/curve of another type
        writer.add_topic('/formation/curve', 'std_msgs/msg/String', qos())
        writer.write('/formation/curve', 1_000_000_000, serialize_message(String(data='x')))
    empty = tiny_bag(tmp_path / 'no_curve')   # a bag without curves or an experiment
    for bag, expected in ((other, 'holds std_msgs/msg/String, expected'),
                          (empty, 'pass --experiment')):
        proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'analyze', str(bag),
                               '--out', str(tmp_path / 'o')], capture_output=True, text=True)
        assert proc.returncode == 2 and 'Traceback' not in proc.stderr, proc.stderr
        assert expected in proc.stderr and len(proc.stderr.splitlines()) == 1, proc.stderr
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'analyze', str(empty),
                           '--experiment', 'closed_curve', '--out', str(tmp_path / 'o2')],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and 'no /formation/curve message' in proc.stderr, proc.stderr
