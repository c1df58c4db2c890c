"""End to end over Fast DDS: every node in its own process, observed by the runner's monitor."""

import dataclasses
import json

import numpy as np
import pytest
from test_safety import settled_for

from conftest import DATA_DIR, quiet
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.run.run_experiment import run_experiment
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


def ros_error_norm(run, data):
    followed, phase = run.followed(data['t'])
    return metrics.error_norm(metrics.target_errors(data['poses'], phase, followed,
                                                    t=data['t']))


# The batch simulator ticks every controller at the same instant; the nodes tick at the same
# rate but unsynchronised. The ROS error norm must lie in the envelope of simulations with
# random tick phases, widened by ENVELOPE_MARGIN for what the simulator does not model:
# timer jitter under load on two cores, poses up to 33 ms old (30 Hz, as a camera), DDS
# latency. At a start the followers' start delays are drawn as well (see simulated_envelope).
ENVELOPE_MARGIN = 1.5


POSE_PERIOD = 1.0 / 30.0   # the fake robots publish poses at 30 Hz


def simulated_envelope(experiment, t, duration, runs=12, seed=0, initial_poses=None,
                       staggered_start=True):
    """(low, high) of the error norm at times t over runs with random tick phases and, for a
    start, random start delays: a follower starts once news of the leader has reached it, up
    to one pose period per hop from the leader plus one tick.
    """
    rng = np.random.default_rng(seed)
    hops = experiment.graph.hops_from_leader()

    def delays():
        if not staggered_start:
            return None
        return np.array([rng.uniform(0, POSE_PERIOD, h).sum() for h in hops]) + np.where(
            hops > 0, rng.uniform(0, 0.1, experiment.n), 0.0)

    norms = [np.interp(t, res.t, res.error_norm) for res in (
        simulate(experiment, duration=duration, record_dt=0.01, initial_poses=initial_poses,
                 tick_phases=rng.uniform(0, 1, experiment.n), start_delays=delays())
        for _ in range(runs))]
    return np.min(norms, axis=0), np.max(norms, axis=0)


def assert_within_envelope(t, ros, low, high, window, tolerance):
    """ROS error within the simulated envelope (x/÷ ENVELOPE_MARGIN) while the simulations are
    above the settling tolerance, and below ENVELOPE_MARGIN x the tolerance where every
    simulation has settled.

    Below the tolerance the error is a floor (exponentially small, or the residual motion the
    10 Hz law keeps under a disturbance) that depends on tick timing the simulator does not
    model; under full-suite load the ROS floor was measured at 0.37 and 0.59 of the simulated
    one (lower, not higher), so floors are not compared.
    """
    transient = window & (low > tolerance)
    below = ros[transient] / low[transient]
    above = ros[transient] / high[transient]
    assert below.min() > 1 / ENVELOPE_MARGIN and above.max() < ENVELOPE_MARGIN, (
        f'ROS/sim-envelope ratios {below.min():.3f} (at t = '
        f'{t[transient][np.argmin(below)]:.2f} s) .. {above.max():.3f} (at t = '
        f'{t[transient][np.argmax(above)]:.2f} s)')
    settled = window & (high < tolerance)
    assert np.all(ros[settled] < ENVELOPE_MARGIN * tolerance), (
        f'ROS error {ros[settled].max():.3g} above {ENVELOPE_MARGIN} x the tolerance '
        f'{tolerance:.3g} after every simulation settled')


# Behind `-m slow` (37 s): in the default run the bodies run is held to the simulator's
# envelope from its start, the curve-switch run (nine robots) after its switch, and both
# check the wheel limits.
@pytest.mark.slow
def test_closed_curve_matches_the_batch_simulator_and_converges(ros_domain, tmp_path):
    """Six robots, 13 processes: the ROS run behaves as the batch simulator predicts."""
    with Run(DATA_DIR / 'fast_closed.yaml', tmp_path, log=quiet) as run:
        run.spin_for(28.0)
        data = run.recording()
    ros = ros_error_norm(run, data)
    low, high = simulated_envelope(run.experiment, data['t'], 29.0)
    tolerance = 1e-3 * run.experiment.phases[0].curve.size()
    assert_within_envelope(data['t'], ros, low, high, data['t'] > 0.5, tolerance)
    sim = simulate(run.experiment, duration=29.0, record_dt=0.01)
    assert ros[-1] < tolerance < ros[0] / 100
    ros_settle = metrics.settle_time(data['t'], ros, tolerance, 0, np.inf)
    sim_settle = metrics.settle_time(sim.t, sim.error_norm, tolerance, 0, np.inf)
    assert ros_settle == pytest.approx(sim_settle, abs=3.0)
    # Every command that crossed DDS respected the configured wheel and turn-rate limits.
    cmd = data['commands']
    assert np.nanmax(np.abs(cmd[..., 1])) <= 10.0 + 1e-9
    assert np.nanmax(np.abs(cmd[..., 0]) + 0.05 * np.abs(cmd[..., 1])) <= 2.0 + 1e-9


@pytest.mark.slow
def test_observer_law_learns_the_disturbance_from_camera_rate_poses(ros_domain, tmp_path):
    """The shipped law over DDS: each node estimates d from differences of 30 Hz poses (not
    the exact held motion the simulator uses) and still settles as the simulator predicts.
    Behind `-m slow` (41 s): the default run's camera loop test also has the observer learn
    d from 30 Hz (camera) poses over DDS and settle as the simulator predicts.
    """
    with Run(DATA_DIR / 'fast_disturbed.yaml', tmp_path, log=quiet) as run:
        run.spin_for(28.0)
        data = run.recording()
    experiment = run.experiment
    ros = ros_error_norm(run, data)
    low, high = simulated_envelope(experiment, data['t'], 29.0)
    tolerance = 1e-3 * experiment.phases[0].curve.size()
    assert_within_envelope(data['t'], ros, low, high, data['t'] > 0.5, tolerance)
    assert ros[-1] < tolerance
    # Published estimates have converged to the paper's d / k2 in every node.
    np.testing.assert_allclose(data['dhat'][-1], experiment.disturbance / experiment.gains.k2,
                               atol=0.01)


def test_curve_switch_is_picked_up_within_one_control_period(ros_domain, tmp_path):
    with Run(DATA_DIR / 'fast_switch.yaml', tmp_path, log=quiet) as run:
        run.spin_for(17.0)   # the switch at 7 s, and 10 s on the second curve
        data = run.recording()
        monitor = run.monitor
    switch = monitor.curve_times[1]
    # publication times on the senders' clocks: from the curve server publishing the new
    # curve to each controller publishing its first state on it
    delays = [monitor.adopted[(i, 1)] - switch for i in range(1, 10)]
    print('adoption delays (s):', np.round(delays, 4))
    period = 1.0 / 10.0
    assert max(delays) < period, delays
    ros = ros_error_norm(run, data)
    t = data['t']
    on_second = data['curve_id'] == 1
    before, after = ros[~on_second][-1], ros[on_second][0]
    assert after > 10 * before and after > 30.0   # the second curve is 36 away
    # Every command that crossed DDS respected the configured wheel and turn-rate limits.
    cmd = data['commands']
    assert np.nanmax(np.abs(cmd[..., 1])) <= 10.0 + 1e-9
    assert np.nanmax(np.abs(cmd[..., 0]) + 0.05 * np.abs(cmd[..., 1])) <= 2.0 + 1e-9
    # After the switch the error follows the simulation started from the poses the robots
    # had when the new curve arrived (their earlier history does not matter); the first
    # 0.5 s are left out, while the controllers are still adopting the new curve.
    k = np.argmax(on_second)
    after_switch = dataclasses.replace(run.experiment, phases=(dataclasses.replace(
        run.experiment.phases[1], start=0.0),))
    rel_t = t[on_second] - t[k]
    low, high = simulated_envelope(after_switch, rel_t, rel_t[-1] + 1.0,
                                   initial_poses=data['poses'][k], staggered_start=False)
    assert_within_envelope(rel_t, ros[on_second], low, high, rel_t > 0.5,
                           1e-3 * run.experiment.phases[1].curve.size())


def test_runner_writes_params_metrics_and_figures_single_process(ros_domain, tmp_path):
    # 12 s: beside the other worker's nodes the start (discovery, the first poses) has
    # taken up to 2 s of the run, the formation then had 6 s (4x smaller once, not 5x)
    result = run_experiment(DATA_DIR / 'fast_closed.yaml', tmp_path, 12.0,
                            RunOptions(single_process=True), log=quiet)
    assert result['mode'] == 'single process'
    saved = json.loads((tmp_path / 'metrics.json').read_text())
    assert saved['phases'][0]['final_error_norm'] < saved['phases'][0]['initial_error_norm'] / 5
    assert (tmp_path / 'paths.png').stat().st_size > 10_000
    params = sorted(p.name for p in (tmp_path / 'params').glob('*.yaml'))
    assert 'robot_6.formation_controller.yaml' in params and 'curve_server.yaml' in params


def test_a_start_that_times_out_stops_the_nodes_it_started(tmp_path, ros_domain, monkeypatch):
    """--no-sim without robots: no pose ever comes; while it waits, a line every few seconds
    names the missing poses, the domain and discovery range and what to check; the start
    times out saying the same, and nothing lingers.
    """
    import subprocess

    from curve_formation.run import node_graph, runner
    monkeypatch.setattr(runner, 'READY_TIMEOUT', 8.0)
    monkeypatch.setattr(runner, 'STATUS_PERIOD', 3.0)
    monkeypatch.setattr(runner, 'FORMATION_CHECK', 0.5)
    started = []
    popen = subprocess.Popen

    def recording_popen(*args, **kwargs):
        proc = popen(*args, **kwargs)
        if 'curve_formation.nodes' in ' '.join(map(str, args[0])):   # a node, not git
            started.append(proc)
        return proc
    monkeypatch.setattr(node_graph.subprocess, 'Popen', recording_popen)
    lines = []
    with pytest.raises(TimeoutError, match='pose') as failed:
        with Run(DATA_DIR / 'fast_closed.yaml', tmp_path, RunOptions(
                with_robots=False, controllers_per_process=1), log=lines.append):
            pass
    assert len(started) == 6   # the controllers; the curve server was never reached
    assert all(proc.poll() is not None for proc in started)
    where = f'ROS_DOMAIN_ID={ros_domain}, discovery LOCALHOST'
    waiting = [line for line in lines if line.startswith('waiting for /robot_1/pose')]
    assert len(waiting) >= 2, lines
    assert all(where in line and "robots' drivers" in line for line in waiting)
    assert '/robot_6/pose' in str(failed.value) and where in str(failed.value)


# Over UDP bridges: 40 s, slow so that the default run stays under 10 min; the default run
# drives robots through bridges over pseudo-terminals (the link-down test below).
@pytest.mark.parametrize('bridge', [None, pytest.param('udp', marks=pytest.mark.slow)],
                         ids=['cmd_vel', 'udp-bridge'])
def test_bodies_avoid_each_other_over_dds_as_the_simulator_predicts(ros_domain, tmp_path,
                                                                    bridge):
    """Six 8 cm robots in one fake_arena, every one heading through the middle of the arena
    to the point opposite: each controller's safety filter keeps them apart from the poses
    on /formation/robot_poses, as in the batch simulator (the envelope test, with bodies).
    With a bridge, fake_arena's robots are emulated firmware: every command travels as a
    wheel-speed line from a robot_bridge over UDP, and the run is held to the same envelope.
    """
    with Run(DATA_DIR / 'arena_bodies.yaml', tmp_path, RunOptions(bridge=bridge),
             log=quiet) as run:
        # 200 simulations with random tick phases settle at median 18.6 s, at most 23.4 s:
        # 28 s leaves the ROS run room to settle (a 25 s run once ended before it had). It
        # ends sooner once settled as long as metrics asks of a settled phase.
        tolerance = 1e-3 * run.experiment.phases[0].curve.size()
        try:
            run.spin_until(lambda: settled_for(run, 0.0, tolerance, metrics.SETTLE_HOLD + 0.5),
                           28.0, 'settling')
        except TimeoutError:
            pass   # the envelope and all_settled below say how far it got
        data = run.recording()
        result = run.write_results()
    experiment = run.experiment
    followed, phase = run.followed(data['t'])
    ros = metrics.error_norm(metrics.target_errors(data['poses'], phase, followed, t=data['t']))
    # Who gives way to whom depends on tick timing, and the settling time with it: the high
    # edge of 12 simulations at 19.8 s ranged from 0.0095 to 0.30 over 20 seeds, so the
    # envelope is drawn from 100 (2 s of simulation), not from 12 as for the runs without
    # bodies. A single ROS run was measured 16x above a 12-run envelope at 19.8 s.
    # Half the simulations start every follower at once: news of the leader may cross every
    # hop within one pose instant (each state is sent on the pose fake_arena sends to all at
    # once): a ROS run was 0.52x the staggered starts' lower edge at 12.4 s (1 of 5 runs),
    # 100 simulations starting at once reach 0.51x of it there; the upper edge is unchanged.
    staggered = simulated_envelope(experiment, data['t'], 29.0, runs=50)
    at_once = simulated_envelope(experiment, data['t'], 29.0, runs=50, staggered_start=False)
    low, high = np.minimum(staggered[0], at_once[0]), np.maximum(staggered[1], at_once[1])
    assert_within_envelope(data['t'], ros, low, high, data['t'] > 0.5, tolerance)
    assert result['all_settled'], result['phases']
    bodies = result['bodies']
    # Counted by fake_arena at every physics step: no two bodies ever touched.
    assert bodies['contacts'] == {'count': 0, 'time': 0.0}, bodies
    margin = experiment.avoidance.margin
    assert bodies['smallest_gap'] > 0.9 * margin, bodies
    cmd = data['commands']
    assert np.nanmax(np.abs(cmd[..., 0]) + 0.04 * np.abs(cmd[..., 1])) <= 0.08 + 1e-9
    if bridge:
        links = result['links']
        assert sorted(links) == [f'robot_{i}' for i in range(1, 7)], links
        for name, link in links.items():
            # Lines were answered 'ok' by the robot's firmware, all but the stop lines sent
            # (into a UDP port nobody read yet) before fake_arena had started: 20 of 293.
            assert link['sent'] > 200 and link['failed'] == link['malformed'] == 0, (name, link)
            assert link['replies'] >= 0.85 * link['sent'] and not link['lost_at'], (name, link)


# Behind `-m slow` (30 s), to keep the default run under 10 minutes: in the default run
# robot_bridge is tested against a silent robot, a serial robot that appears late and its send
# rate (test_robot_bridge), and controllers stopping on stale inputs by the fault runs.
@pytest.mark.slow
def test_a_robot_whose_link_goes_down_stops_on_its_watchdog_and_drives_on_after(ros_domain,
                                                                              tmp_path):
    """Over pseudo-terminals (serial lines), robot 3's link goes deaf for 2 s: its firmware
    hears nothing, so its watchdog (1 s) stops the motors; its bridge reports the link lost,
    then ok again once the robot answers, and the robot drives on.
    """
    down_from, down_for, watchdog = 5.0, 2.0, 1.0   # from when robot 3 first drives
    options = RunOptions(bridge='pty', faults={'link_down': [3, down_from, down_for]})
    with Run(DATA_DIR / 'fast_closed.yaml', tmp_path, options, log=quiet) as run:
        run.spin_for(16.0)
        data = run.recording()
        reports = run.monitor.links['/robot_3/robot_bridge']
    levels = [level for _, level, _, _ in reports]
    lost = [(t, values) for t, level, _, values in reports if level == 2]
    assert lost, reports
    assert 2 in levels and levels[-1] == 0, reports      # lost, then ok again
    assert all(message == 'no reply from the robot'
               for _, level, message, _ in reports if level == 2)
    t_lost, values = lost[0]
    last_reply = t_lost - float(values['reply_age_s'])     # when the link went deaf
    t, xy = data['t'], data['poses'][:, 2, :2]
    moved = np.linalg.norm(np.diff(xy, axis=0), axis=1).cumsum()
    moved = np.concatenate([[0.0], moved])

    def travelled(t0, t1):
        return np.interp(t1, t, moved) - np.interp(t0, t, moved)

    assert travelled(last_reply - 1.0, last_reply) > 0.05          # driving before
    # stopped from its watchdog (plus one 30 Hz pose and a physics step) to the link's return
    assert travelled(last_reply + watchdog + 0.15, last_reply + down_for - 0.1) < 1e-3
    assert travelled(last_reply + down_for + 1.0, t[-1]) > 0.05     # and driving again after


@pytest.mark.slow   # 4 minutes: three 60 s runs of the arena demo
def test_the_arena_demo_through_bridges_settles_as_with_fake_robots(ros_domain, tmp_path):
    """The issue's goal, as benchmarks/robot_bridge.py prints it: over UDP and over
    pseudo-terminals the demo settles within 1.1x of the fake robots' time.
    """
    settle = {}
    for bridge in (None, 'udp', 'pty'):
        result = run_experiment('arena_demo', tmp_path / str(bridge), 60.0,
                                RunOptions(bridge=bridge), log=quiet)
        settle[bridge] = result['phases'][0]['settle_time']
        if bridge:   # (before fake_arena is up, a pty is not there yet: failed, not lost)
            assert all(link['replies'] >= 0.9 * link['sent'] and not link['lost_at']
                       for link in result['links'].values()), result['links']
    assert settle[None] is not None, settle
    for bridge in ('udp', 'pty'):
        assert settle[bridge] is not None and settle[bridge] <= 1.1 * settle[None], settle


def test_a_moving_curve_is_followed_over_dds_with_the_feed_forward(ros_domain, tmp_path):
    """Four robots parked on a loop that moves at 1 cm/s: the curve server renews it ten
    times a second with its rate, each controller carries its target forward and adds its
    velocity: every robot stays within 2 mm of its moving target (10 mm behind without it, as
    the simulator shows in test_motion).
    """
    with Run(DATA_DIR / 'moving_loop.yaml', tmp_path, log=quiet) as run:
        run.spin_for(10.0)
        data = run.recording()
        moved, phase = run.followed(data['t'])
    assert len(moved.phases) == 1 and moved.phases[0].motion is not None
    errors = np.linalg.norm(metrics.target_errors(data['poses'], phase, moved, t=data['t']),
                            axis=2)
    late = data['t'] > 3.0
    print('largest error per robot after 3 s (mm):', np.round(1e3 * errors[late].max(axis=0), 2))
    assert errors[late].max() < 0.002
    # the formation went with the curve: 8 cm and more to the right
    travelled = data['poses'][-1, :, 0] - run.experiment.initial_poses[:, 0]
    assert travelled.min() > 0.08
