"""camera_tracker and fake_camera in-process: messages in and out, diagnostics, parameters."""

import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from curve_formation.core.config.loading import load_experiment
from curve_formation.nodes import messages, qos, topics
from curve_formation.nodes.camera_tracker import CameraTracker
from curve_formation.nodes.fake_camera import FakeCamera
from curve_formation.nodes.params import ParameterError
from curve_formation.paths import resolve_config
from curve_formation.vision.camera import overhead_camera
from curve_formation.vision.markers import MarkerLayout
from curve_formation.vision.render import ArenaRenderer
from curve_formation.vision.tracker import Calibration, MarkerTracker


TRUTH = {1: (0.4, 0.3, 0.5), 2: (0.8, 0.5, -2.0), 3: (1.2, 0.35, 3.0), 4: (1.5, 0.6, 1.0)}


def params(**values):
    return [Parameter(k, value=v) for k, v in {'experiment': 'arena_demo', **values}.items()]


def rendered(extra_markers=(), size=(1280, 720)):
    camera = load_experiment(resolve_config('arena_demo')).spec.camera
    layout = MarkerLayout.from_spec(camera)
    return ArenaRenderer(overhead_camera((1.8, 0.8), size), layout, (1.8, 0.8)).render(
        TRUTH, extra_markers=extra_markers)


class Listener:
    """Collects what camera_tracker publishes."""

    def __init__(self, node):
        self.poses = {}
        self.arrays = []
        self.diagnostics = []
        self.debug = []
        for i in range(1, 10):
            node.create_subscription(PoseStamped, topics.robot_topic(i, topics.POSE),
                                     lambda m, i=i: self.poses.setdefault(i, m), qos.SENSOR)
        node.create_subscription(PoseArray, topics.CAMERA_POSES, self.arrays.append, qos.SENSOR)
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self.diagnostics.append,
                                 qos.EVENTS)
        node.create_subscription(Image, topics.CAMERA_DEBUG, self.debug.append, qos.IMAGE)


def test_tracker_publishes_poses_with_the_image_stamp(ros, tmp_path):
    context, add, spin_until = ros
    calibration = tmp_path / 'calibration.yaml'
    add(CameraTracker(context=context, parameter_overrides=params(
        calibration_file=str(calibration), debug_rate_hz=50.0)))
    probe = add(Node('probe', context=context))
    listener = Listener(probe)
    image_pub = probe.create_publisher(Image, topics.CAMERA_IMAGE, qos.IMAGE)
    spin_until(lambda: image_pub.get_subscription_count() > 0)
    # Robot 3 also appears a second time: ambiguous, so not published.
    frame = rendered(extra_markers=((3, 0.3, 0.6, 0.0),))
    spin_until(lambda: _publish(image_pub, frame, 42.25) and len(listener.poses) >= 3
               and listener.debug, timeout=15.0)
    assert sorted(listener.poses) == [1, 2, 4]
    for agent, msg in listener.poses.items():
        x, y, theta, stamp = messages.pose_from_msg(msg)
        assert stamp == pytest.approx(42.25)
        tx, ty, tth = TRUTH[agent]
        assert math.hypot(x - tx, y - ty) < 0.002
        assert abs(math.remainder(theta - tth, 2 * math.pi)) < math.radians(1.0)
    poses = listener.arrays[-1].poses
    assert len(poses) == 9 and math.isnan(poses[2].position.x) and not math.isnan(
        poses[0].position.x)
    debug = messages.gray_from_image_msg(listener.debug[-1])
    assert debug.shape == frame.shape and listener.debug[-1].encoding == 'bgr8'
    listener.diagnostics.clear()
    spin_until(lambda: _publish(image_pub, frame, 42.25) and listener.diagnostics, timeout=3.0)
    status = {s.name: s for s in listener.diagnostics[-1].status}
    assert 'seen twice' in status['camera_tracker: robot 3'].message
    assert status['camera_tracker: robot 9'].message.startswith('lost')
    assert status['camera_tracker: robot 1'].message == 'tracked'
    values = {kv.key: kv.value for kv in status['camera_tracker: robot 1'].values}
    assert values['pattern_not_fitted'] == '0'   # clean marker: its pattern fitted every frame
    # The continuous calibration was saved, and a fixed-calibration tracker reloads it.
    saved = Calibration.load(calibration)
    # Contour-refined corners sit ~0.6 px inside each square, the same on every side: robot
    # centres and headings are unbiased (above); only the corner fit's residual shows it.
    assert saved.rms_px < 1.0
    fixed = CameraTracker(context=context, parameter_overrides=params(
        calibration='fixed', calibration_file=str(calibration)))
    np.testing.assert_allclose(fixed.tracker.calibration.homography, saved.homography)
    fixed.destroy_node()


def _publish(publisher, frame, stamp):
    publisher.publish(messages.image_to_msg(frame, stamp))
    return True


def test_tracker_reads_a_video_file(ros, tmp_path):
    import cv2
    context, add, spin_until = ros
    video = tmp_path / 'arena.avi'
    frame = rendered()
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*'MJPG'), 30.0,
                             (frame.shape[1], frame.shape[0]), isColor=False)
    for _ in range(60):
        writer.write(frame)
    writer.release()
    add(CameraTracker(context=context, parameter_overrides=params(source=str(video))))
    probe = add(Node('probe', context=context))
    listener = Listener(probe)
    spin_until(lambda: len(listener.poses) == 4, timeout=15.0)
    x, y, _, _ = messages.pose_from_msg(listener.poses[2])
    assert math.hypot(x - 0.8, y - 0.5) < 0.003


def test_a_wide_lens_rendered_by_the_fake_camera_is_undone_by_the_calibration_file(ros,
                                                                                  tmp_path):
    """fake_camera renders through a barrel lens (k1 = -0.3); a tracker given the file that
    `calibrate-camera` wrote from board views of that lens tracks within a millimetre, one
    without it a centimetre or more off.
    """
    from curve_formation.vision.intrinsics import BoardSpec, calibrate, write_intrinsics
    from curve_formation.vision.lens import Lens
    from curve_formation.vision.render import BoardRenderer
    context, add, spin_until = ros
    lens = [-0.3, 0.1, 0.001, -0.001]
    boards = BoardRenderer(overhead_camera((1.8, 0.8), (1280, 720)), BoardSpec(),
                           Lens.from_coefficients(lens))
    write_intrinsics(tmp_path / 'lens.yaml',
                     calibrate(boards.render(*pose) for pose in boards.random_poses(14, 2)))
    add(FakeCamera(context=context, parameter_overrides=params(distortion=lens)))
    corrected = add(CameraTracker(context=context, parameter_overrides=params(
        intrinsics_file=str(tmp_path / 'lens.yaml'), debug_rate_hz=0.0)))
    probe = add(Node('probe', context=context))
    raw = MarkerTracker(corrected.layout)   # the same frames, without the lens file
    frames = []
    probe.create_subscription(Image, topics.CAMERA_IMAGE, frames.append, qos.IMAGE)
    listener = Listener(probe)
    pubs = {i: probe.create_publisher(PoseStamped, topics.robot_topic(i, topics.TRUE_POSE),
                                      qos.SENSOR) for i in TRUTH}
    spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()))

    def publish_truth():
        for i, (x, y, th) in TRUTH.items():
            pubs[i].publish(messages.pose_to_msg(x, y, th, 0.0))
        return True
    spin_until(lambda: publish_truth() and len(listener.poses) == 4 and frames, timeout=15.0)
    for agent, msg in listener.poses.items():
        x, y, _, _ = messages.pose_from_msg(msg)
        assert math.hypot(x - TRUTH[agent][0], y - TRUTH[agent][1]) < 0.001
    uncorrected = raw.process(messages.gray_from_image_msg(frames[-1])).poses
    assert max(math.hypot(uncorrected[a][0] - TRUTH[a][0], uncorrected[a][1] - TRUTH[a][1])
               for a in TRUTH) > 0.01


@pytest.mark.parametrize('values, name', [
    ({'experiment': 'closed_curve'}, 'experiment'),
    ({'intrinsics_file': '/nonexistent/lens.yaml'}, 'intrinsics_file'),
    ({'calibration': 'fixed', 'calibration_file': '/nonexistent/cal.yaml'},
     'calibration_file'),
    ({'source': '/nonexistent/video.avi'}, 'source'),
])
def test_tracker_refuses_bad_parameters_by_name(ros, values, name):
    context, _, _ = ros
    with pytest.raises(ParameterError, match=f"parameter '{name}'"):
        CameraTracker(context=context, parameter_overrides=params(**values))


def test_fake_camera_renders_the_true_poses_and_covers_markers_on_cue(ros):
    context, add, spin_until = ros
    camera = add(FakeCamera(context=context, parameter_overrides=params(
        rate_hz=30.0, resolution=[640, 360], hide=[2], fault_from=0.0, fault_for=-1.0)))
    probe = add(Node('probe', context=context))
    frames = []
    probe.create_subscription(Image, topics.CAMERA_IMAGE, frames.append, qos.IMAGE)
    pubs = {i: probe.create_publisher(PoseStamped, topics.robot_topic(i, topics.TRUE_POSE),
                                      qos.SENSOR) for i in TRUTH}
    spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()))
    for i, (x, y, th) in TRUTH.items():
        pubs[i].publish(messages.pose_to_msg(x, y, th, 0.0))
    spin_until(lambda: len(camera.poses) == 4 and len(frames) > 2)
    msg = frames[-1]
    assert (msg.width, msg.height, msg.encoding) == (640, 360, 'mono8')
    tracker = MarkerTracker(camera.layout)
    assert sorted(tracker.process(messages.gray_from_image_msg(msg)).poses) == [1, 2, 3, 4]
    assert not camera.faulty(1e9)                      # no curve yet: the fault clock waits
    camera._on_curve(None)
    frames.clear()
    spin_until(lambda: len(frames) > 2)
    assert sorted(tracker.process(messages.gray_from_image_msg(frames[-1])).poses) == [1, 3, 4]


def test_tracker_marks_each_robots_target_as_the_curve_server_assigned_it(ros):
    """The debug image's targets: robot i's is G(s_i) xi with s_i from the curve message
    (nearest assignment permutes them), never re-derived from the spacing.
    """
    from std_msgs.msg import Float64MultiArray
    context, add, spin_until = ros
    tracker = add(CameraTracker(context=context, parameter_overrides=params()))
    probe = add(Node('probe', context=context))
    curve_pub = probe.create_publisher(Float64MultiArray, topics.CURVE, qos.LATCHED)
    phase = load_experiment(resolve_config('arena_demo')).phases[0]
    assert not np.allclose(phase.s, np.sort(phase.s))   # assigned, not in spacing order
    curve_pub.publish(messages.curve_to_msg(phase.curve, 0, phase.s))
    spin_until(lambda: tracker.targets is not None)
    np.testing.assert_allclose(tracker.targets, phase.targets)


def test_a_curve_drawn_on_the_floor_becomes_the_formation_curve(ros):
    """fake_camera draws drawn_curve's loop on the floor under nine robots at their start
    poses; camera_tracker finds it and curve_server (schedule off) publishes its fit: closed,
    within 2 mm RMS of the drawn line, and once only while noisy frames keep coming.
    """
    from std_msgs.msg import Float64MultiArray

    from curve_formation.core.formation.curve_sources import polyline_rms_distance
    from curve_formation.nodes.curve_server import CurveServer
    context, add, spin_until = ros
    experiment = load_experiment(resolve_config('drawn_curve'))
    add(FakeCamera(context=context, parameter_overrides=params(
        experiment='drawn_curve', rate_hz=10.0, noise=2.0, blur=0.7)))
    add(CameraTracker(context=context, parameter_overrides=params(
        experiment='drawn_curve', debug_rate_hz=0.0)))
    add(CurveServer(context=context, parameter_overrides=params(
        experiment='drawn_curve', schedule=False)))
    probe = add(Node('probe', context=context))
    curves = []
    probe.create_subscription(Float64MultiArray, topics.CURVE,
                              lambda m: curves.append(messages.curve_from_msg(m)), qos.LATCHED)
    pubs = {i: probe.create_publisher(PoseStamped, topics.robot_topic(i, topics.TRUE_POSE),
                                      qos.SENSOR) for i in range(1, 10)}

    def publish_truth():
        for i, (x, y, th) in enumerate(experiment.initial_poses, 1):
            pubs[i].publish(messages.pose_to_msg(x, y, th, 0.0))
        return True
    spin_until(lambda: publish_truth() and curves, timeout=20.0)
    curve, curve_id = curves[0]
    assert curve_id == 0 and curve.basis.closed
    _, drawn = experiment.phases[0].curve.sample(1000)
    _, fitted = curve.sample(2000)
    assert polyline_rms_distance(fitted, drawn, True) < 0.002
    assert polyline_rms_distance(drawn, fitted, True) < 0.002
    deadline = time.monotonic() + 4.0
    spin_until(lambda: publish_truth() and time.monotonic() > deadline)
    assert {curve_id for _, curve_id in curves} == {0}   # published again, never refitted
