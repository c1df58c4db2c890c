"""The camera in the loop over Fast DDS: fake_robot -> fake_camera (rendered 1280x720 frames)
-> camera_tracker (ArUco) -> formation_controller -> fake_robot, every node its own process.
"""

import re

import numpy as np
import pytest

from conftest import DATA_DIR, quiet
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


EXPERIMENT = DATA_DIR / 'camera_loop.yaml'


def error_norms(run, data, key):
    followed, phase = run.followed(data['t'])
    return metrics.error_norm(metrics.target_errors(data[key], phase, followed, t=data['t']))


# About a minute: slow, so that the default run stays under 10 minutes (the camera nodes are
# tested one by one in test_camera_nodes.py, a robot whose pose goes stale stops in
# test_agent.py; the closed loop through the camera runs in `-m slow` with this test).
@pytest.mark.slow
def test_closed_loop_through_the_camera_converges_and_a_covered_marker_stops_its_robot(
        ros_domain, tmp_path):
    """The loop converges as the simulator predicts, although robot 9's marker is covered
    for 2 s from t = 4 s (one run for both: a camera run's start-up is most of its cost):
    robot 9 stops for as long, and only it.
    """
    camera = {'hide': [9], 'fault_from': 4.0, 'fault_for': 2.0}
    with Run(EXPERIMENT, tmp_path, RunOptions(camera=camera), log=quiet) as run:
        run.spin_for(40.0)
        data = run.recording()
    assert_a_lost_marker_stops_its_robot_for_as_long_and_only_it(run, data, tmp_path)
    assert_converges_through_the_camera(run, data)


@pytest.mark.slow   # 70 s
def test_closed_loop_through_a_wide_lens_tilted_with_markers_above_the_floor(ros_domain,
                                                                             tmp_path):
    """The same loop seen as a real webcam sees it: barrel lens (k1 = -0.3), camera tilted
    25 degrees, markers 5 cm up; the lens calibrated from rendered ChArUco views as
    `calibrate-camera` does. It converges as through the ideal camera, and the robots' true
    poses settle within 1.1x of the simulator's time (the issue's goal; with cv2.aruco's
    outline corners their bias kept the true error at the tolerance, 1.8-2.2x).
    """
    import cv2

    from curve_formation.cli import main
    from curve_formation.vision.camera import overhead_camera
    from curve_formation.vision.intrinsics import BoardSpec
    from curve_formation.vision.lens import Lens
    from curve_formation.vision.render import BoardRenderer, RenderOptions
    lens = [-0.3, 0.1, 0.001, -0.001]
    boards = BoardRenderer(overhead_camera((1.8, 0.8), (1280, 720), 25.0), BoardSpec(),
                           Lens.from_coefficients(lens), RenderOptions(2.0, 0.7))
    (tmp_path / 'views').mkdir()
    for k, pose in enumerate(boards.random_poses(20, seed=3)):
        cv2.imwrite(str(tmp_path / 'views' / f'{k:02d}.png'), boards.render(*pose))
    assert main(['calibrate-camera', str(tmp_path / 'views'), '--out',
                 str(tmp_path / 'lens.yaml')]) == 0
    text = EXPERIMENT.read_text()
    assert '  corner_size: 0.06\n' in text and '  fake: {' in text
    text = text.replace('  corner_size: 0.06\n', '  corner_size: 0.06\n  marker_height: 0.05\n'
                        f'  intrinsics_file: {tmp_path / "lens.yaml"}\n')
    text = re.sub(r'  fake: \{[^}]*\}', f'  fake: {{tilt_deg: 25.0, height: 2.0, noise: 2.0, '
                  f'blur: 0.7, distortion: {lens}}}', text)
    experiment = tmp_path / 'wide_lens.yaml'
    experiment.write_text(text)
    with Run(experiment, tmp_path / 'run', RunOptions(camera={}), log=quiet) as run:
        run.spin_for(40.0)
        data = run.recording()
    assert_converges_through_the_camera(run, data)
    tolerance = 1e-3 * run.experiment.phases[0].curve.size()
    settled = metrics.settle_time(data['t'], error_norms(run, data, 'true_poses'), tolerance,
                                  0, np.inf)
    sim = simulate(run.experiment, duration=40.0)
    expected = metrics.settle_time(sim.t, sim.error_norm, tolerance, 0, np.inf)
    assert settled is not None and settled <= 1.1 * expected, (settled, expected)


def assert_converges_through_the_camera(run, data):
    t = data['t']
    truth = error_norms(run, data, 'true_poses')
    tracked = error_norms(run, data, 'poses')
    tolerance = 1e-3 * run.experiment.phases[0].curve.size()
    late = t > 36.0
    # The robots' true poses end within the settling tolerance (noise-limited: the camera
    # sees each robot to ~0.5 mm), from 0.33 at the start, as the simulator predicts.
    assert truth[0] > 300 * tolerance
    # What the camera reports carries its noise (~0.4 mm per robot, 1.2 mm stacked): median.
    assert truth[late].max() < 2 * tolerance and np.median(tracked[late]) < 2 * tolerance
    sim = simulate(run.experiment, duration=40.0)
    sim_settle = metrics.settle_time(sim.t, sim.error_norm, tolerance, 0, np.inf)
    assert truth[np.searchsorted(t, sim_settle + 5.0):].max() < 2 * tolerance
    # What the controllers saw was the truth, up to one frame of motion; and the poses their
    # laws used, carried forward to each tick through the commands sent since the frame's
    # capture, within half a millimetre of the truth at the tick (measured on the arena demo:
    # 0.27-0.29 mm, against 0.88 mm acting on the frame as it came).
    seen = np.isfinite(data['poses']).all(axis=2)
    gap = np.linalg.norm(data['poses'][..., :2] - data['true_poses'][..., :2], axis=2)[seen]
    assert np.sqrt(np.mean(gap ** 2)) < 0.003
    assert run.monitor.law_pose_tally[0] > 9 * 300 and run.monitor.law_pose_rms() < 0.0005
    # The observer learnt d / k2 = [0.015, 0.3] from camera poses.
    miss = np.abs(data['dhat'][-1] - run.experiment.disturbance / run.experiment.gains.k2)
    assert miss[:, 0].max() < 0.005 and miss[:, 1].max() < 0.06, miss


def commands_during(data, robot, start, end):
    window = (data['t'] >= start) & (data['t'] <= end)
    return np.abs(data['commands'][window, robot - 1]).sum(axis=1)


# Behind `-m slow` (28 s): the tracker's refusal of an id seen twice is tested in
# test_camera_nodes, and what the loop does with a missing pose is tested with a covered
# marker in the default run's closed-loop test.
@pytest.mark.slow
def test_a_marker_id_seen_twice_stops_its_robot_for_as_long_and_only_it(ros_domain, tmp_path):
    """Robot 9's id shown a second time for 2 s from t = 4 s: its pose is not published."""
    camera = {'duplicate_of': 9, 'duplicate_at': [0.3, 0.4], 'fault_from': 4.0,
              'fault_for': 2.0}
    with Run(EXPERIMENT, tmp_path, RunOptions(camera=camera), log=quiet) as run:
        run.spin_for(9.0)
        data = run.recording()
    assert_a_lost_marker_stops_its_robot_for_as_long_and_only_it(run, data, tmp_path)


def assert_a_lost_marker_stops_its_robot_for_as_long_and_only_it(run, data, tmp_path):
    """Robot 9 (a leaf: nobody follows it) lost its pose for 2 s from t = 4 s."""
    # The fault clock starts when fake_camera gets the curve, the monitor's a little later.
    assert commands_during(data, 9, 1.0, 3.0).min() > 0                     # driving before
    stopped = commands_during(data, 9, 3.0, 7.5) == 0.0
    assert 1.2 < stopped.sum() / 20.0 < 2.0 + 0.5                           # 20 Hz samples
    # Driving again afterwards, and the others throughout. Camera poses reach a controller
    # ~0.1 s after capture, and on these two shared cores a late frame now and then makes a
    # pose 0.5 s old: that robot then stops for a tick, as it must (seen in 1 of 4 runs).
    assert np.mean(commands_during(data, 9, 7.5, 9.0) > 0) > 0.8
    for robot in range(1, 9):
        assert np.mean(commands_during(data, robot, 3.0, 7.5) > 0) > 0.9, robot
    # Stopped at the first tick after the pose timeout.
    # robot 9's controller's lines, from its own process's log or its group's
    log = '\n'.join(line for path in (tmp_path / 'logs').glob('*.log')
                    for line in path.read_text().splitlines()
                    if '[robot_9.formation_controller]' in line)
    first_age = float(re.search(r'own pose stale \(([0-9.]+) s old\)', log).group(1))
    assert first_age < run.experiment.spec.safety.pose_timeout + 0.1 + 0.05


@pytest.mark.slow   # 2.5 minutes: the arena case's two 60 s phases
def test_the_mona_arena_case_through_the_camera_never_deadlocks(ros_domain, tmp_path):
    """`curve-formation run mona_arena --camera`, as a user runs it: it used to deadlock at
    7 s, robots parked on the leader's marker. Now no two bodies ever touch, no marker is ever
    hidden, and both curves settle to their tolerance on the robots' true poses (measured
    57.4 s and 33.1 s; before the tracker fitted each marker's pattern, the fast observer
    this case needs passed the outline corners' pixel noise into the commands and the second
    curve hovered at 1.4x its tolerance).
    """
    with Run('mona_arena', tmp_path, RunOptions(camera={}), log=quiet) as run:
        run.spin_for(121.0)
        result = run.write_results()
    bodies = result['bodies']
    assert bodies['contacts'] == {'count': 0, 'time': 0.0}, bodies
    assert bodies['marker_hidden_time'] == 0.0, bodies
    assert bodies['smallest_gap'] > 0.5 * run.experiment.avoidance.margin, bodies
    truth = result['ground_truth']['phases']
    for true, tracked in zip(truth, result['phases'], strict=True):
        assert true['settled'] and tracked['settled'], (true, tracked)


@pytest.mark.slow   # 2.5 minutes: a 60 s loop, then the line moved
def test_the_robots_follow_a_line_drawn_on_the_floor_and_moved(ros_domain, tmp_path):
    """`curve-formation run drawn_curve --camera`: the fake camera draws a loop on the floor,
    the tracker finds it, the server fits it and the nine robots spread out on it; at 60 s the
    line is moved to an open S and they follow. Exactly two curves are published (closed, then
    open), each within 2 mm of the drawn line, both settle as the simulator settles on the
    drawn curves (measured 50.8 s and 47.3 s against 50.3 s and 45.3 s), without a contact.
    """
    from curve_formation.core.formation.curve_sources import polyline_rms_distance
    with Run('drawn_curve', tmp_path, RunOptions(camera={}), log=quiet) as run:
        run.spin_for(128.0)
        result = run.write_results()
        followed, _ = run.followed(run.recording()['t'])
    drawn = run.experiment.phases
    assert [p.curve.basis.closed for p in followed.phases] == [True, False]
    for seen, line in zip(followed.phases, drawn, strict=True):
        _, fitted = seen.curve.sample(2000)
        _, truth = line.curve.sample(2000)
        assert polyline_rms_distance(fitted, truth, line.curve.basis.closed) < 0.002
    sim = simulate(run.experiment)
    sim_settle = [metrics.settle_time(sim.t, sim.error_norm, 1e-3 * p.curve.size(), p.start,
                                      end) for p, end in zip(drawn, [60.0, np.inf], strict=True)]
    for phase, expected in zip(result['phases'], sim_settle, strict=True):
        assert phase['settled'] and phase['settle_time'] < 1.3 * expected, (phase, expected)
    assert result['bodies']['contacts'] == {'count': 0, 'time': 0.0}


@pytest.mark.slow   # about a minute and a half
def test_the_arena_demo_settles_with_mujoco_robots_seen_through_the_camera(ros_domain,
                                                                          tmp_path):
    """`curve-formation run arena_demo --camera --physics mujoco`: robots with mass, motors
    and casters in MuJoCo (fake_arena), seen by the fake overhead camera, driven by the
    controllers over DDS. The formation settles on the robots' true poses with no contact
    between robots nor with a wall, within 1.2x of the same pipeline without ROS
    (core.sim.pipeline) in the MuJoCo world.
    """
    from curve_formation.core.sim.pipeline import simulate_pipeline
    options = RunOptions(camera={}, physics='mujoco')
    with Run('arena_demo', tmp_path, options, log=quiet) as run:
        run.spin_for(45.0)
        result = run.write_results()
    contacts = result['bodies']['contacts']
    assert contacts['count'] == 0 and contacts['walls'] == 0, result['bodies']
    truth = result['ground_truth']['phases']
    assert all(p['settled'] for p in truth), truth
    alone = metrics.result_metrics(simulate_pipeline(run.experiment, 'mujoco', duration=45.0))
    for true, batch in zip(truth, alone['phases'], strict=True):
        assert true['settle_time'] <= 1.2 * batch['settle_time'], (true, batch)
