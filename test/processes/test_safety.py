"""Faults survived, over DDS with every node in its own process (fast closed-curve test case).

Graph of fast_closed.yaml: 1 -> 2, 3; 2 -> 3, 4; 3 -> 4; 4 -> 5, 6; 5 -> 6; 6 -> 2.
"""

import dataclasses
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest
from std_msgs.msg import Bool

from conftest import CONFIG_DIR, DATA_DIR, no_history_qos, quiet, SUPPORT
from curve_formation.core.config.agents import leader_relays
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.nodes import qos, topics
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run
import lossy_controller
import node_faults


PERIOD = 0.1


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
    return bool(np.all(run.monitor.latest.commands[[i - 1 for i in robots]] == 0.0))


def driving(run, robots):
    commands = run.monitor.latest.commands[[i - 1 for i in robots]]
    return bool(np.all(np.abs(commands).sum(axis=1) > 0))


def standing_still(run, robots, timeout=5.0):
    """Wait until each robot's pose stands still: a pose stamped later than the last one seen
    and equal to it (poses published before a stop may still be on their way, later under
    load). Returns the robots' poses then ((len(robots), 3) m, m, rad) and their stamps (s).
    """
    rows = [i - 1 for i in robots]
    latest = run.monitor.latest
    seen = {i: (latest.pose_stamps[i], latest.poses[i].copy()) for i in rows}
    still = set()

    def all_still():
        for i in rows:
            stamp, pose = seen[i]
            if run.monitor.latest.pose_stamps[i] > stamp:
                if np.array_equal(run.monitor.latest.poses[i], pose):
                    still.add(i)
                else:
                    still.discard(i)
                seen[i] = (run.monitor.latest.pose_stamps[i], run.monitor.latest.poses[i].copy())
        return len(still) == len(rows)

    run.spin_until(all_still, timeout, f'robots {list(robots)} to stand still')
    return run.monitor.latest.poses[rows].copy(), run.monitor.latest.pose_stamps[rows].copy()


def still_standing(run, robots, still, seconds=0.0):
    """Spin `seconds` s, then assert each robot has sent poses since `still` (standing_still's
    answer) and stands where it stood then.
    """
    rows = [i - 1 for i in robots]
    run.spin_for(seconds)
    poses, stamps = still
    assert np.all(run.monitor.latest.pose_stamps[rows] > stamps), 'no new pose came'
    np.testing.assert_allclose(run.monitor.latest.poses[rows], poses, atol=1e-9)


PUBLISHED_WITHIN = PERIOD / 4   # s: a tick's clock reading to its command's publication, at most
LOGGED_TO = 0.01   # s: the resolution of the ages the controllers log


def assert_first_tick_past(commands, robot, stopped_at, age, limit):
    """A robot's controller stopped at its first tick past an input's time limit: the input
    was `age` s old at the stop (log time `stopped_at`, s), at least `limit`, and the robot
    sent no driving command between the input going stale and that stop. That is one period
    plus the input's own period after the limit, usually; later when the whole process
    stalled, as Fast DDS's shared-memory port check after a kill can make it for 1-2 s
    (docs/limitations.md), and then it must not have driven meanwhile either. A command is
    timed when it was published (its DDS source time), after its tick read the clock, and the
    logged age is rounded to 10 ms: the tick before the stop may have seen the input a hair
    under the limit and published it a few ms past; PUBLISHED_WITHIN allows for both.
    """
    stale_at = stopped_at - age + limit + PUBLISHED_WITHIN
    driving = [row for row in commands.rows if row[0] == robot and (row[2] or row[3])
               and stale_at < row[1] < stopped_at - PERIOD / 2]
    # the logged age is rounded to 10 ms: 1.04 s may be 1.0433 s, past a limit of 1.0433 s
    assert age + LOGGED_TO / 2 >= limit and not driving, (robot, age, limit, driving[:3])


ALL = range(1, 7)
FOLLOWERS = range(2, 7)


def test_estop_a_killed_follower_and_the_killed_leader_each_stop_whom_they_should(ros_domain,
                                                                                 tmp_path):
    """Three faults in turn on one run (one start-up instead of four): the e-stop stops every
    robot within a tick and its release lets them drive again; a killed follower stops its
    out-neighbours at their first tick past the neighbour timeout (and its own motors, by the
    driver's watchdog) and, restarted, rejoins; the killed leader stops every follower within
    its leader timeout (leader_timeout, plus the relay its hops from the leader may take).
    """
    # a process per controller, so that one can be killed alone
    with Run(DATA_DIR / 'fast_closed.yaml', tmp_path, RunOptions(controllers_per_process=1),
             log=quiet) as run:
        commands = CommandLog(run.observers.context, 6)
        run.observers.add_node(commands.node)
        run.spin_for(2.0)
        assert driving(run, ALL)
        # 1. e-stop, then release
        # as `ros2 topic pub /formation/estop std_msgs/msg/Bool "data: true"` sends it:
        # reliable and volatile, published as soon as it has found one reader
        estop = run.monitor.create_publisher(Bool, topics.ESTOP, no_history_qos())
        run.spin_until(lambda: estop.get_subscription_count() > 0, 10.0, 'a reader')
        estop.publish(Bool(data=True))
        wait_for(run, lambda: stopped(run, ALL), 'every robot to stop')
        still_standing(run, ALL, standing_still(run, ALL), 1.0)
        assert stopped(run, ALL)
        # a release must reach every node itself (nobody passes a release on)
        run.spin_until(lambda: estop.get_subscription_count() >= 2 * 6, 10.0, 'every reader')
        estop.publish(Bool(data=False))
        wait_for(run, lambda: driving(run, ALL), 'every robot to drive again')
        # 2. a follower killed (SIGKILL: silent at once), then restarted. Not on its first
        # driving tick: a kill in the middle of that publication can deliver the command to
        # this test's reader and not to the robot, which then never drove (inferred from
        # one failed run)
        run.spin_for(0.5)
        node_faults.kill(run, 'robot_2.formation_controller')
        wait_for(run, lambda: stopped(run, [3, 4]), 'robots 3 and 4 (out-neighbours of 2) to stop')
        # `estop on` cannot stop a robot whose controller is dead, and says so
        status, out, err = estop_cli(run, 'on', '--expect', '6', wait=4.0)
        assert status == 1 and 'no confirmation from robot_2' in err and '5 of 6' in err, err
        status, out, err = estop_cli(run, 'off', '--experiment',
                                     str(DATA_DIR / 'fast_closed.yaml'), wait=4.0)
        assert status == 1 and 'no confirmation from robot_2' in err, err   # released, but 2
        assert driving(run, [1])                       # the leader is unaffected
        # Robot 2 itself: its driver's watchdog turns the motors off 1 s after the last
        # command (exactly: test_dynamics), unless that command had turned them off already
        # (a controller killed on the tick after a stop); from then on it stands still.
        last = max((row for row in commands.rows if row[0] == 2), key=lambda row: row[1])
        if last[2] or last[3]:
            wait_for(run, lambda: logged(tmp_path, 'robot_2.fake_robot', 'no command for 1 s'),
                     "robot 2's watchdog")
        still_standing(run, [2], standing_still(run, [2]), 0.5)
        node_faults.restart(run, 'robot_2.formation_controller')
        wait_for(run, lambda: driving(run, [2, 3, 4]), 'robots 2, 3, 4 to drive again', 30.0)
        # 3. the leader killed
        wait_for(run, lambda: driving(run, FOLLOWERS), 'every follower to drive')
        node_faults.kill(run, 'robot_1.formation_controller')
        wait_for(run, lambda: stopped(run, FOLLOWERS), 'every follower to stop')
        run.spin_for(1.0)
        assert stopped(run, FOLLOWERS)
    # The e-stop: every robot stopped at its first tick after the e-stop reached it.
    for i in ALL:
        node = f'robot_{i}.formation_controller'
        engaged, stop = (logged(tmp_path, node, 'e-stop engaged')[0],   # the first e-stop
                         logged(tmp_path, node, 'stopped: e-stop engaged')[0])
        assert 0 <= stop[0] - engaged[0] <= PERIOD + 0.05, (i, engaged, stop)
        assert logged(tmp_path, node, 'e-stop released')
    # The killed follower: 3 and 4 each stopped at its first tick past the neighbour timeout.
    timeout = 0.5
    for robot in (3, 4):
        stops = logged(tmp_path, f'robot_{robot}.formation_controller',
                       r'stopped: neighbour 2 stale \((\d+\.\d+) s old\)')
        assert stops, robot
        assert_first_tick_past(commands, robot, stops[0][0], float(stops[0][1]), timeout)
    # The killed leader: each follower's last stop came at its first tick past its timeout
    # (leader_timeout 1 s plus the relay its hops from the leader may take, leader_relays;
    # neighbour_timeout for an out-neighbour of the leader).
    relays = leader_relays(load_experiment(DATA_DIR / 'fast_closed.yaml'))
    for i in FOLLOWERS:
        log = (tmp_path / 'logs' / f'robot_{i}.formation_controller.log').read_text()
        last = logged(tmp_path, f'robot_{i}.formation_controller',
                      r'stopped: (no news from the leader|neighbour 1 stale) '
                      r'\((\d+\.\d+) s old\)')[-1]
        limit = 1.0 + relays[i - 1] if last[1].startswith('no news') else timeout
        assert_first_tick_past(commands, i, last[0], float(last[2]), limit)
        # logged when the reason changes, not on every tick while it lasts
        kinds = [re.sub(r'\(.*?\)|for [\d.]+ s', '#', line)   # the reason, not its age
                 for line in re.findall(r': (stopped: .*|driving)$', log, re.MULTILINE)]
        assert all(a != b for a, b in zip(kinds, kinds[1:], strict=False)), (i, log)


@pytest.mark.slow   # 45 s each: the default run keeps under 10 minutes
@pytest.mark.parametrize('told', [True, False], ids=['latency-told', 'latency-untold'])
def test_dropped_messages_and_latency_still_converge_at_arena_speeds(ros_domain, tmp_path, told,
                                                                    monkeypatch):
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
    # the states are lost by a variant of the controller (test/support/lossy_controller.py)
    monkeypatch.setenv('PYTHONPATH', os.pathsep.join(
        [str(SUPPORT), *filter(None, [os.environ.get('PYTHONPATH')])]))
    monkeypatch.setenv(lossy_controller.STATE_DROP_ENV, '0.2')
    options = RunOptions(command_latency=0.2, bag_path=tmp_path / 'bag',
                         faults={'pose_drop': 0.2}, node_variants={
                             'curve_formation.nodes.formation_controller':
                             lossy_controller.MODULE})
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
    # the fault-free reference: no latency (the batch simulator refuses a told one)
    spec = run.experiment.spec
    clean_case = dataclasses.replace(run.experiment, spec=spec.model_copy(update={
        'controller': spec.controller.model_copy(update={'command_latency': 0.0})}))
    sim = simulate(clean_case, duration=30.0)
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


def test_estop_with_nobody_on_the_domain_exits_1_naming_the_domain(ros_domain):
    started = time.monotonic()
    done = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'estop', 'on',
                           '--wait', '1'], capture_output=True, text=True, timeout=60)
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert f'ROS_DOMAIN_ID={ros_domain}' in done.stderr and 'LOCALHOST' in done.stderr
    assert 'Ctrl-C' not in done.stdout + done.stderr
    assert time.monotonic() - started < 1.0 + 10.0   # --wait, and starting Python and rclpy


class CommandLog:
    """Every cmd_vel of robots 1..n with its DDS source time: (robot, sent s, v, w)."""

    def __init__(self, context, n):
        from geometry_msgs.msg import Twist
        from rclpy.node import Node

        from curve_formation.nodes.runtime import WithMessageInfo
        self.node = Node('command_log', context=context, start_parameter_services=False)
        self.rows = []
        for i in range(1, n + 1):
            self.node.create_subscription(
                Twist, topics.robot_topic(i, topics.CMD_VEL),
                WithMessageInfo(lambda m, info, i=i: self.rows.append(
                    (i, info['source_timestamp'] * 1e-9, m.linear.x, m.angular.z))),
                qos.COMMAND)

    def since(self, t):
        return [row for row in self.rows if row[1] >= t]


def settled_for(run, since, tolerance, seconds):
    """The run's error norm has stayed below tolerance for the last `seconds` s after `since`
    (checked once a second of run time).
    """
    last = run.monitor.recording.last('t')
    if last is None or last - since < seconds or int(last) == getattr(run, '_checked', -1):
        return False
    run._checked = int(last)
    data = run.recording()
    followed, phase = run.followed(data['t'])
    norm = metrics.error_norm(metrics.target_errors(data['poses'], phase, followed,
                                                    t=data['t'], stamps=data['pose_stamps']))
    recent = data['t'] >= data['t'][-1] - seconds
    return bool((norm[recent] < tolerance).all())


def estop_cli(run, *args, wait=5.0):
    """Run `curve-formation estop ...` while the run spins; (exit status, stdout, stderr)."""
    proc = subprocess.Popen([sys.executable, '-m', 'curve_formation.cli', 'estop', *args,
                             '--wait', str(wait)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    run.spin_until(lambda: proc.poll() is not None, 60.0, 'the estop command to end')
    out, err = proc.communicate()
    return proc.returncode, out, err


def test_estop_cli_stops_all_nine_robots_at_once_holds_them_and_releases(ros_domain, tmp_path):
    """The arena demo, one process per node: `estop on` (no --hold) at t = 5 s stops all 9
    robots within 2 control periods of the first robot's receipt and exits 0 saying so; they
    stay stopped for 10 s after it has exited, a controller killed and restarted meanwhile
    included; `estop off` releases and the formation settles, the e-stop in metrics.json and
    the phase settled only after the release. (`estop on` with a controller killed:
    test_estop_a_killed_follower_and_the_killed_leader_each_stop_whom_they_should.)
    """
    import time as clock
    with Run(CONFIG_DIR / 'arena_demo.yaml', tmp_path, RunOptions(
            bag_path=tmp_path / 'bag', controllers_per_process=1), log=quiet) as run:
        log = CommandLog(run.observers.context, 9)
        run.observers.add_node(log.node)
        run.spin_until(lambda: (run.monitor.recording.last('t') or 0.0) >= 5.0,
                       30.0, 't = 5 s')
        assert driving(run, range(1, 10))
        status, out, err = estop_cli(run, 'on')
        exited = clock.time()
        assert status == 0 and '9 of 9 robots stopped within' in out, (out, err)
        assert 'Ctrl-C' not in out + err
        still = standing_still(run, range(1, 10))
        run.spin_for(2.0)
        node_faults.kill(run, 'robot_4.formation_controller')
        node_faults.restart(run, 'robot_4.formation_controller')
        run.spin_until(lambda: clock.time() >= exited + 10.0, 20.0, '10 s after the command')
        held = log.since(exited)
        assert {row[0] for row in held} == set(range(1, 10))
        assert all(row[2] == 0.0 and row[3] == 0.0 for row in held), \
            [row for row in held if row[2] or row[3]][:5]
        still_standing(run, range(1, 10), still)
        asked = run.monitor.recording.last('t')
        status, out, err = estop_cli(run, 'off', '--experiment', 'arena_demo')   # by name
        assert status == 0 and '9 of 9 robots released' in out, (out, err)
        released = run.monitor.recording.last('t')   # the command has ended
        # settled ~15 s after the release (measured): spin until it has stayed below the
        # tolerance as long as metrics asks of a settled phase (it failed with 1 s: the phase
        # had held 1.7 s when the run ended, under metrics.SETTLE_HOLD)
        tolerance = 1e-3 * run.experiment.phases[0].curve.size()
        run.spin_until(lambda: settled_for(run, released, tolerance, metrics.SETTLE_HOLD + 0.5),
                       50.0, 'settling')
        result = run.write_results()
        last = {holder: (t, engaged) for t, holder, engaged in run.monitor.estop_events}
        holding = ({h: t for h, (t, engaged) in last.items() if engaged}, out)   # (failures)
    # Every robot's first zero command within 2 periods of the first robot's receipt.
    receipts = [logged(tmp_path, f'robot_{i}.formation_controller', 'e-stop engaged by')[0][0]
                for i in range(1, 10)]
    first = min(receipts)
    zeros = [min(t for robot, t, v, w in log.rows if robot == i and t >= first and v == w == 0)
             for i in range(1, 10)]
    assert max(zeros) - first <= 2 * PERIOD, (first, zeros)
    restarted = (tmp_path / 'logs' / 'robot_4.formation_controller.log').read_text()
    assert 'passed on by' in restarted.split('agent 4/9')[-1], restarted[-2000:]
    phase = result['phases'][0]
    # (failed in full runs when the spin above stopped after 1 s below the tolerance)
    assert phase['settled'] and phase['interrupted_by_estop'], (
        phase['not_settled_because'], phase['interrupted_by_estop'], phase['final_error_norm'],
        phase['tolerance'], result.get('estop'), result.get('node_deaths'), holding)
    (start, stop), = result['estop']['intervals']
    # released while the command ran (it keeps discovering holders for a while after)
    assert 4.5 < start < 9.0 and asked < stop <= released, (asked, released, result['estop'])
    assert phase['settle_time'] >= stop, (phase, stop)
    # The bag says the same: the e-stop states are recorded.
    from curve_formation.bags.analysis import analyze_bag
    bagged = analyze_bag(tmp_path / 'bag', tmp_path / 'analysis')
    # and what RViz or Foxglove draw from: the arena's poses (~30 Hz) and the curve's markers
    import yaml
    meta = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    counts = {entry['topic_metadata']['name']: entry['message_count'] for entry in
              meta['rosbag2_bagfile_information']['topics_with_message_count']}
    assert counts.get('/formation/robot_poses', 0) > 30 * 20 and counts.get(
        '/formation/markers', 0) >= 1, counts
    (bag_start, bag_stop), = bagged['estop']['intervals']
    assert abs(bag_start - start) < 0.2 and abs(bag_stop - stop) < 0.2, bagged['estop']
    assert bagged['phases'][0]['settled'] and bagged['phases'][0]['settle_time'] >= stop


def test_a_release_is_done_only_when_the_nodes_that_move_the_robots_have_it_too():
    """`estop off` reached every controller but not the fake arena once (the arena's robots
    stayed stopped while the command said all were released): the command waits for every
    holder it has heard, and names one that did not confirm.
    """
    from curve_formation.core.controller.estop import EstopReport
    from curve_formation.run.estop_command import _report, Tally

    tally = Tally(engage=False, expect=2)
    for robot in ('robot_1', 'robot_2'):
        tally.add(EstopReport(f'/{robot}/formation_controller', 'formation_controller', robot,
                              False, '/formation_estop', 1.0, 2), 0.05)
    tally.add(EstopReport('/fake_arena', 'fake_arena', '', True, '/formation_estop', 0.0, 2),
              0.06)
    assert tally.missing() == [] and tally.others_missing() == ['/fake_arena']
    assert not tally.done()
    said = []
    assert _report(tally, 'off', 4.0, lambda text, ok: said.append((text, ok))) == 1
    assert 'no confirmation from /fake_arena' in said[0][0] and said[0][1] is False
    tally.add(EstopReport('/fake_arena', 'fake_arena', '', False, '/formation_estop', 1.0, 2),
              0.9)
    assert tally.done()
    # Once more, with the arena's state not heard yet at all (the command a new participant,
    # the arena's announcement still on its way): discovered, it is waited for as well.
    tally.discovered = {'/fake_arena', '/robot_1/fake_robot'}
    assert not tally.done() and tally.others_missing() == ['/robot_1/fake_robot']


def test_a_release_waits_for_the_holders_the_others_hear_and_discovery_has_not_shown():
    """`estop off` said all nine robots were released while the curve server, which discovery
    had not shown the command within its time, kept the e-stop (a release comes only from a
    command; the run's record then held the e-stop to its end): each holder tells how many
    holders it hears, and the command waits until it has heard as many.
    """
    from curve_formation.core.controller.estop import EstopReport
    from curve_formation.run.estop_command import _report, Tally

    tally = Tally(engage=False, expect=2)
    for robot in ('robot_1', 'robot_2'):
        tally.add(EstopReport(f'/{robot}/formation_controller', 'formation_controller', robot,
                              False, '/formation_estop', 1.0, 2, holders=3), 0.05)
    assert tally.missing() == [] and tally.others_missing() == [] and tally.unheard() == 1
    assert not tally.done()
    said = []
    assert _report(tally, 'off', 4.0, lambda text, ok: said.append((text, ok))) == 1
    assert '1 holder(s) the others hear' in said[0][0] and said[0][1] is False
    tally.add(EstopReport('/curve_server', 'curve_server', '', False, '/formation_estop', 1.0,
                          2, holders=3), 0.9)
    assert tally.done()
