"""Faults survived, over DDS with every node in its own process (fast closed-curve test case).

Graph of fast_closed.yaml: 1 -> 2, 3; 2 -> 3, 4; 3 -> 4; 4 -> 5, 6; 5 -> 6; 6 -> 2.
"""

import os
import re
import signal
import subprocess
import sys

import numpy as np
import pytest
import rclpy
from std_msgs.msg import Bool

from conftest import CONFIG_DIR, DATA_DIR, no_history_qos
from curve_formation.core import metrics
from curve_formation.core.simulator import simulate
from curve_formation.nodes import qos, topics
from curve_formation.run_options import RunOptions
from curve_formation.runner import Run


pytestmark = pytest.mark.ros
PERIOD = 0.1


def quiet(*_):
    pass


def wait_for(run, predicate, what, timeout=5.0):
    """Wait (wall clock, generously) for an event; how late it came is read from the nodes'
    own logs, which a loaded machine delaying this process or DDS cannot falsify.
    """
    run.spin_until(predicate, timeout, what)


def logged(tmp_path, node, pattern):
    """[(log time s, *groups)] of each line of a node's log matching pattern."""
    text = (tmp_path / 'logs' / f'{node}.log').read_text()
    return [(float(m.group(1)), *m.groups()[1:])
            for m in re.finditer(r'^\[\w+\] \[(\d+\.\d+)\] \[[\w.]+\]: ' + pattern, text,
                                 re.MULTILINE)]


def stopped(run, robots):
    return bool(np.all(run.monitor.commands[[i - 1 for i in robots]] == 0.0))


def driving(run, robots):
    return bool(np.all(np.abs(run.monitor.commands[[i - 1 for i in robots]]).sum(axis=1) > 0))


ALL = range(1, 7)
FOLLOWERS = range(2, 7)


def test_estop_a_killed_follower_and_the_killed_leader_each_stop_whom_they_should(ros_domain,
                                                                                 tmp_path):
    """Three faults in turn on one run (one start-up instead of four): the e-stop stops every
    robot within a tick and its release lets them drive again; a killed follower stops its
    out-neighbours at their first tick past the neighbour timeout (and its own motors, by the
    driver's watchdog) and, restarted, rejoins; the killed leader stops every follower within
    leader_timeout.
    """
    with Run(DATA_DIR / 'fast_closed.yaml', tmp_path, log=quiet) as run:
        run.spin_for(2.0)
        assert driving(run, ALL)
        # 1. e-stop, then release
        estop = run.monitor.create_publisher(Bool, topics.ESTOP, qos.LATCHED)
        estop.publish(Bool(data=True))
        wait_for(run, lambda: stopped(run, ALL), 'every robot to stop')
        run.spin_for(0.2)          # poses published before the stop are still arriving
        before = run.monitor.poses.copy()
        run.spin_for(1.0)
        assert stopped(run, ALL)
        np.testing.assert_allclose(run.monitor.poses, before, atol=1e-9)   # standing still
        estop.publish(Bool(data=False))
        wait_for(run, lambda: driving(run, ALL), 'every robot to drive again')
        # 2. a follower killed (SIGKILL: silent at once), then restarted
        run.kill('robot_2.formation_controller')
        wait_for(run, lambda: stopped(run, [3, 4]), 'robots 3 and 4 (out-neighbours of 2) to stop')
        assert driving(run, [1])                       # the leader is unaffected
        # Robot 2 itself: its driver's watchdog turns the motors off 1 s after the last
        # command (exactly: test_dynamics); from then on it stands still.
        wait_for(run, lambda: logged(tmp_path, 'robot_2.fake_robot', 'no command for 1 s'),
                 "robot 2's watchdog")
        run.spin_for(0.2)          # poses published before the stop are still arriving
        pose = run.monitor.poses[1].copy()
        run.spin_for(0.5)
        np.testing.assert_allclose(run.monitor.poses[1], pose, atol=1e-9)
        run.restart('robot_2.formation_controller')
        wait_for(run, lambda: driving(run, [2, 3, 4]), 'robots 2, 3, 4 to drive again', 30.0)
        # 3. the leader killed
        wait_for(run, lambda: driving(run, FOLLOWERS), 'every follower to drive')
        run.kill('robot_1.formation_controller')
        wait_for(run, lambda: stopped(run, FOLLOWERS), 'every follower to stop')
        run.spin_for(1.0)
        assert stopped(run, FOLLOWERS)
    # The e-stop: every robot stopped at its first tick after the e-stop reached it.
    for i in ALL:
        node = f'robot_{i}.formation_controller'
        (engaged,), (stop,) = (logged(tmp_path, node, 'e-stop engaged'),
                               logged(tmp_path, node, 'stopped: e-stop engaged'))
        assert 0 <= stop[0] - engaged[0] <= PERIOD + 0.05, (i, engaged, stop)
        assert logged(tmp_path, node, 'e-stop released')
    # The killed follower: 3 and 4 each stopped at its first tick past the neighbour timeout
    # (one period late at most, plus a period between the states 2 sent).
    timeout = 0.5
    for robot in (3, 4):
        stops = logged(tmp_path, f'robot_{robot}.formation_controller',
                       r'stopped: neighbour 2 stale \((\d+\.\d+) s old\)')
        assert stops and timeout <= float(stops[0][1]) <= timeout + 2 * PERIOD, (robot, stops)
    # The killed leader: each follower's last stop came at its first tick past its timeout
    # (leader_timeout 1 s; neighbour_timeout for an out-neighbour of the leader).
    for i in FOLLOWERS:
        log = (tmp_path / 'logs' / f'robot_{i}.formation_controller.log').read_text()
        last = re.findall(r'stopped: (no news from the leader|neighbour 1 stale) '
                          r'\((\d+\.\d+) s old\)', log)[-1]
        limit = 1.0 if last[0].startswith('no news') else timeout
        assert limit <= float(last[1]) <= limit + 2 * PERIOD, (i, log)
        # logged when the reason changes, not on every tick while it lasts
        kinds = [re.sub(r'\(.*?\)|for [\d.]+ s', '#', line)   # the reason, not its age
                 for line in re.findall(r': (stopped: .*|driving)$', log, re.MULTILINE)]
        assert all(a != b for a, b in zip(kinds, kinds[1:], strict=False)), (i, log)


def test_estop_command_holds_the_stop_sending_it_again_until_ctrl_c(ros):
    """`curve-formation estop on --hold`: a controller that never got the latched message
    (a volatile subscription here: no history) still gets the stop, within a second; a late
    latched one gets it at once; Ctrl-C ends the command cleanly.
    """
    context, add, spin_until = ros
    node = add(rclpy.create_node('probe', context=context))
    volatile = []
    node.create_subscription(Bool, topics.ESTOP, lambda m: volatile.append(m.data),
                             no_history_qos())
    proc = subprocess.Popen([sys.executable, '-m', 'curve_formation.cli', 'estop', 'on',
                             '--hold', '--wait', '0'], env=dict(os.environ),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        spin_until(lambda: len(volatile) >= 2, timeout=20.0)
        assert all(volatile)
        latched = []
        node.create_subscription(Bool, topics.ESTOP, lambda m: latched.append(m.data),
                                 qos.LATCHED)
        spin_until(lambda: latched, timeout=5.0)
        assert latched[0] is True
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and 'e-stop on' in out, (out, err)


@pytest.mark.parametrize('told', [True, pytest.param(False, marks=pytest.mark.slow)],
                         ids=['latency-told', 'latency-untold'])
def test_dropped_messages_and_latency_still_converge_at_arena_speeds(ros_domain, tmp_path, told):
    """20 % of poses and of neighbour states dropped, commands delayed 200 ms, on the arena demo
    (Mona wheel limits, 10 Hz, robots drifting with d = [5 mm/s, 0.1 rad/s]). Tolerance: the
    error never exceeds its start by more than 1 % (the drift acts before the observer has
    learnt it), and it comes down to 30 %, 10 % and 3 % of its start at most `late` s later
    than in the fault-free batch simulation.
    told: the experiment states the latency (controller.command_latency), so the controllers
    carry poses forward to when a command acts and the observer pairs the motion with the
    command acting on it: 0.3-0.4 s late measured (the 0.2 s itself and DDS), 1 s allowed.
    Not told (slow test): 0.6-1.3 s late here, 2.0 s once in CI; 3 s allowed.
    Not a ratio of errors at a fixed time: at 30 s the simulated error falls threefold per
    second (0.025 at 29 s, 0.0086 at 30 s), so such a ratio only measures a 0.2 s timing.
    At the fast test case's ~10 m/s the same faults make the law diverge (docs/safety.md).
    """
    experiment = CONFIG_DIR / 'arena_demo.yaml'
    late = 3.0
    if told:
        text = experiment.read_text()
        assert text.count('predict_pose: true,') == 1
        experiment = tmp_path / 'arena_demo_told.yaml'
        experiment.write_text(text.replace('predict_pose: true,',
                                           'predict_pose: true, command_latency: 0.2,'))
        late = 1.0
    options = RunOptions(command_latency=0.2, bag_path=tmp_path / 'bag',
                         faults={'pose_drop': 0.2, 'state_drop': 0.2})
    with Run(experiment, tmp_path, options, log=quiet) as run:
        run.spin_for(30.0)
        data = run.recording()
    # The faults drop messages before they are published: the bag has every one that was
    # (poses are best effort: DDS may drop a few under this load, measured 0 to 7 of ~7000).
    accounting = run.bag_accounting()
    assert accounting['published'] > 10_000 and accounting['lost'] == 0, accounting
    assert accounting['lost_best_effort'] < 0.005 * accounting['published'], accounting
    followed, phase = run.followed(data['t'])   # targets as the curve server re-assigned them
    errors = metrics.target_errors(data['poses'], phase, followed, t=data['t'])
    norm = metrics.error_norm(errors)
    assert norm.max() <= norm[0] * 1.01
    sim = simulate(run.experiment, duration=30.0)
    lags = {}
    for fraction in (0.3, 0.1, 0.03):
        tolerance = fraction * norm[0]
        faulty = metrics.settle_time(data['t'], norm, tolerance, 0.0, np.inf)
        clean = metrics.settle_time(sim.t, sim.error_norm, tolerance, 0.0, np.inf)
        lags[fraction] = None if faulty is None else round(faulty - clean, 2)
    # On failure: how late, which robot lagged, and the logs (a stop for stale inputs shows).
    per_robot = np.linalg.norm(errors[-1], axis=1).round(4).tolist()
    assert all(lag is not None and lag <= late for lag in lags.values()), (
        lags, per_robot, tmp_path / 'logs')
