"""camera_tracker: robot poses from the overhead camera's ArUco markers.

Input: sensor_msgs/Image on /camera/image_raw from any camera driver, or, with `source` set, a
device number or video file opened with cv2.VideoCapture and read at `rate_hz`. Markers,
arena corners and calibration come from the experiment's `camera` section. Each frame gives
/robot_<i>/pose (PoseStamped, axle centre, arena frame, stamped with the image's stamp) for
every robot seen exactly once, and /camera/robot_poses (PoseArray of all robots in agent
order, NaN when not seen). A robot not seen is simply not published, so its controller stops
it after its pose timeout; a marker id seen twice in one frame is ambiguous and not published
either. /diagnostics (1 Hz) reports per robot the detection rate, whether it is lost
(unseen for `lost_timeout`) and in how many frames its pattern could not be fitted (a
smudged or partly covered marker), the frame latency, and the calibration.
/camera/debug_image (bgr8, `debug_rate_hz`, only while someone subscribes) shows detections,
ids, the desired curve and each robot's target point for the arena operator.
"""

import math
from pathlib import Path
import time
from typing import Any

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PolygonStamped
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import Float64MultiArray

from curve_formation import diagnostics
from curve_formation.core.config.camera_schema import CameraSpec
from curve_formation.core.config.experiment import beside_experiment
from curve_formation.core.formation.curves import Curve
from curve_formation.nodes import messages, topics
from curve_formation.nodes.params import (
    declare_parameters,
    experiment_parameter,
    Param,
    ParameterError,
)
from curve_formation.nodes.readiness import REPORTED, subscribe_to_curve
from curve_formation.nodes.runtime import now_seconds, run_node
from curve_formation.nodes.topics import Use
from curve_formation.vision.camera import apply_homography
from curve_formation.vision.curve_detection import CurveWatch, finder_for
from curve_formation.vision.intrinsics import IntrinsicsError, read_intrinsics
from curve_formation.vision.markers import MarkerLayout
from curve_formation.vision.tracker import Calibration, CalibrationError, MarkerTracker


SAVE_INTERVAL = 5.0   # s between saves of a continuously re-estimated calibration


NODE_NAME = 'camera_tracker'   # also its console script's name
PARAMETERS = (
    Param('experiment', 'string', None, 'experiment YAML with a `camera` section (markers, '
          'corners, calibration)'),
    Param('source', 'string', '', "'' = subscribe to /camera/image_raw; else a device number "
          '(e.g. 0) or a video file for cv2.VideoCapture'),
    Param('rate_hz', 'double', 30.0, 'frames read per second from `source`', positive=True),
    Param('calibration', 'string', '', "'continuous' or 'fixed'; '' = the experiment's",
          choices=('', 'continuous', 'fixed')),
    Param('calibration_file', 'string', '', "saved homography (YAML), reloaded at start; '' = "
          "the experiment's camera.calibration_file (if any)"),
    Param('intrinsics_file', 'string', '', "lens calibration (YAML) of `curve-formation "
          "calibrate-camera`; '' = the experiment's camera.intrinsics(_file), if any"),
    Param('lost_timeout', 'double', 0.0, "a robot unseen this long is reported lost (s); 0 = "
          "the experiment's", low=0.0),
    Param('debug_rate_hz', 'double', 5.0, 'rate of the annotated debug image (Hz); 0 = off',
          low=0.0),
    Param('frame_id', 'string', 'arena', 'frame of the published poses'),
)


TOPICS = (
    Use('sub', topics.CAMERA_IMAGE, 'camera frames (mono8, bgr8, rgb8, ...); not used when '
        '`source` is set'),
    Use('sub', topics.CURVE, 'desired curve, drawn in the debug image'),
    Use('pub', topics.POSE, "each robot's pose, stamped with its image", '<i>'),
    Use('pub', topics.CAMERA_POSES, 'all robots in agent order, NaN when not seen'),
    Use('pub', topics.ROBOT_POSES, "the same as x, y, theta per robot, for the controllers' "
        'safety filter'),
    Use('pub', topics.DIAGNOSTICS, 'detection rate per robot, lost robots, frame latency, '
        'calibration (1 Hz)'),
    Use('pub', topics.CAMERA_DEBUG, 'annotated frame (bgr8) while subscribed'),
    Use('pub', topics.OBSERVED_CURVE, 'the curve drawn on the floor (camera.drawn_curve), when '
        'it is first seen and whenever it moves (a closed one repeats its first point last)'),
    REPORTED,
)


class CameraTracker(Node):
    """ArUco detection and arena calibration over a camera stream."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.params = declare_parameters(self, PARAMETERS)
        self.experiment = experiment_parameter(p.experiment, needs=('camera',))
        camera = self.experiment.spec.camera
        assert camera is not None   # experiment_parameter checked it is there
        self.n = self.experiment.n
        self.lost_timeout = p.lost_timeout or camera.lost_timeout
        mode = p.calibration or camera.calibration
        self.calibration_path = self._calibration_path(camera)
        calibration = None
        if self.calibration_path is not None and self.calibration_path.exists():
            try:
                calibration = Calibration.load(self.calibration_path)
            except CalibrationError as exc:
                raise ParameterError(f"parameter 'calibration_file': {exc}") from None
            self.get_logger().info(f'calibration loaded from {self.calibration_path}')
        elif mode == 'fixed':
            raise ParameterError(f"parameter 'calibration_file': calibration 'fixed' needs a "
                                 f'saved calibration, {self.calibration_path} does not exist')
        intrinsics = self._intrinsics(camera)
        self.layout = MarkerLayout.from_spec(camera)
        self.tracker = MarkerTracker(self.layout, calibration, mode == 'continuous', intrinsics,
                                     camera.corner_refinement)
        self.pose_pubs = [topics.publisher(self, topics.POSE, robot=i)
                          for i in range(1, self.n + 1)]
        self.array_pub = topics.publisher(self, topics.CAMERA_POSES)
        self.robot_poses_pub = topics.publisher(self, topics.ROBOT_POSES)
        self.diag_pub = topics.publisher(self, topics.DIAGNOSTICS)
        self.debug_pub = topics.publisher(self, topics.CAMERA_DEBUG)
        self.observed_pub = topics.publisher(self, topics.OBSERVED_CURVE)
        self.curve_finder = None
        if camera.drawn_curve is not None:
            spec = self.experiment.spec
            assert spec.arena is not None   # a camera experiment has one (config.checks)
            self.curve_finder = finder_for(self.tracker, camera, spec.arena.size,
                                           spec.robots.radius)
            self.curve_watch = CurveWatch(camera.drawn_curve.change,
                                          width=camera.drawn_curve.width)
            self.curve_period = 1.0 / camera.drawn_curve.rate_hz
            self.last_curve_search = -math.inf
            # agent -> (x, y) last seen (m): where its body hides line
            self.positions: dict[int, tuple[float, float]] = {}
            # (observed curve message, curve id when it was sent)
            self.unanswered: tuple[PolygonStamped, int | None] | None = None
        self.curve_id: int | None = None   # of the last curve on /formation/curve
        subscribe_to_curve(self, self._on_curve)
        self.curve: Curve | None = None
        self.targets: np.ndarray | None = None
        self.last_seen: dict[int, float] = {}
        self.seen_counts = np.zeros(self.n + 1, int)
        self.frames = 0
        self.latencies: list[float] = []
        self.process_times: list[float] = []
        self.duplicates: set[int] = set()
        self.last_saved = -math.inf
        self.last_debug = -math.inf
        self.capture = None
        if p.source:
            target = int(p.source) if p.source.isdigit() else p.source
            self.capture = cv2.VideoCapture(target)
            if not self.capture.isOpened():
                raise ParameterError(f"parameter 'source': cannot open {p.source!r}")
            self.create_timer(1.0 / p.rate_hz, self._on_capture)
        else:
            topics.subscription(self, topics.CAMERA_IMAGE, self._on_image)
        self.create_timer(1.0, self._publish_diagnostics)

    def _calibration_path(self, camera: CameraSpec) -> Path | None:
        return self._path(self.params.calibration_file, camera.calibration_file)

    def _path(self, parameter: str, experiment_key: str | None) -> Path | None:
        """The file a parameter names (as given), else the experiment's (relative to it)."""
        if parameter:
            return Path(parameter)
        return beside_experiment(self.experiment, experiment_key)

    def _intrinsics(self, camera: CameraSpec) -> tuple[Any, Any] | None:
        """(K, distortion) to undistort corner pixels with, or None (an ideal lens)."""
        path = self._path(self.params.intrinsics_file, camera.intrinsics_file)
        if path is None:
            if camera.intrinsics is None:
                return None
            return camera.intrinsics.camera_matrix, camera.intrinsics.distortion
        try:
            lens = read_intrinsics(path, camera.resolution)
        except IntrinsicsError as exc:
            raise ParameterError(f"parameter 'intrinsics_file': {exc}") from None
        self.get_logger().info(f'lens calibration loaded from {path} (reprojection '
                               f'{lens.rms:.2f} px)')
        return lens.camera_matrix, lens.distortion

    def _on_curve(self, msg: Float64MultiArray) -> None:
        try:
            curve, self.curve_id = messages.curve_from_msg(msg)
            s = messages.agent_parameters_from_msg(msg)
        except messages.MessageError:
            return
        self.curve = curve
        # Each robot's target as the curve server assigned it (None: the curve alone).
        self.targets = None if s is None or len(s) != self.n else curve.points(s)

    def _on_capture(self) -> None:
        assert self.capture is not None   # the capture timer runs only with a capture
        ok, frame = self.capture.read()
        if not ok:
            self.get_logger().warning('no frame from the camera source',
                                      throttle_duration_sec=5.0)
            return
        gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        self.process(gray, now_seconds(self))

    def _on_image(self, msg: Image) -> None:
        try:
            gray = messages.gray_from_image_msg(msg)
        except messages.MessageError as exc:
            self.get_logger().error(f'image refused: {exc}', throttle_duration_sec=5.0)
            return
        self.process(gray, messages.stamp_to_seconds(msg.header.stamp))

    def process(self, gray: np.ndarray, stamp: float) -> None:
        """Detect, publish poses stamped `stamp` (s), keep statistics, save calibration."""
        started = time.perf_counter()
        frame = self.tracker.process(gray)
        now = now_seconds(self)
        for agent, (x, y, theta) in frame.poses.items():
            self.pose_pubs[agent - 1].publish(messages.pose_to_msg(
                x, y, theta, stamp, self.params.frame_id))
            self.last_seen[agent] = now
            self.seen_counts[agent] += 1
        self.array_pub.publish(messages.pose_array_to_msg(frame.poses, self.n, stamp,
                                                          self.params.frame_id))
        every = np.full((self.n, 3), np.nan)
        for agent, pose in frame.poses.items():
            every[agent - 1] = pose
        self.robot_poses_pub.publish(messages.robot_poses_to_msg(every, stamp,
                                                                 self.params.frame_id))
        if self.curve_finder is not None and now - self.last_curve_search >= self.curve_period:
            self.last_curve_search = now
            self._find_curve(gray, frame, stamp)
        self.frames += 1
        self.latencies.append(now - stamp)
        self.process_times.append(time.perf_counter() - started)
        self.duplicates.update(frame.duplicates)
        if not frame.calibrated:
            self.get_logger().warning(
                f'not calibrated: {frame.corners_seen} corner markers seen, need 2',
                throttle_duration_sec=5.0)
        calibration = self.tracker.calibration
        if (frame.recalibrated and calibration is not None and self.calibration_path is not None
                and now - self.last_saved > SAVE_INTERVAL):
            calibration.save(self.calibration_path)
            self.last_saved = now
        if (self.params.debug_rate_hz > 0 and self.debug_pub.get_subscription_count() > 0
                and now - self.last_debug >= 1.0 / self.params.debug_rate_hz):
            self.last_debug = now
            self.debug_pub.publish(messages.image_to_msg(self.annotate(gray, frame), stamp))

    def _find_curve(self, gray: np.ndarray, frame: Any, stamp: float) -> None:
        """Search the frame for the drawn curve; publish it when first seen or moved."""
        assert self.curve_finder is not None   # called only when the drawn curve is sought
        self.positions.update({agent: pose[:2] for agent, pose in frame.poses.items()})
        found = self.curve_finder.find(gray, list(self.positions.values()))
        publish = self.curve_watch.offer(found)
        if publish is None:
            if self.unanswered is not None and self.unanswered[1] == self.curve_id:
                self.observed_pub.publish(self.unanswered[0])   # not taken up yet: again
            return
        msg = messages.polygon_to_msg(publish.points, publish.closed, stamp,
                                      self.params.frame_id)
        self.observed_pub.publish(msg)
        self.unanswered = (msg, self.curve_id)   # until a new curve comes from the server
        self.get_logger().info(f"drawn curve published: {'closed' if publish.closed else 'open'}"
                               f', {len(publish.points)} points from {publish.pixels} pixels')

    def annotate(self, gray: np.ndarray, frame: Any) -> np.ndarray:
        """bgr8 debug image: detected markers with agent numbers, curve and targets."""
        image = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
        for agent, quad in frame.pixels.items():
            cv2.polylines(image, [np.round(quad).astype(np.int32)], True, (0, 200, 0), 2)
            cv2.putText(image, str(agent), tuple(np.round(quad[0]).astype(int)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 255), 2)
        calibration = self.tracker.calibration
        if calibration is not None and self.curve is not None:
            to_pixels = np.linalg.inv(calibration.homography)
            line = apply_homography(to_pixels, self.curve.points(np.linspace(0, 1, 300)))
            cv2.polylines(image, [np.round(line).astype(np.int32)], False, (255, 128, 0), 1)
            targets = [] if self.targets is None else apply_homography(to_pixels, self.targets)
            for agent, (u, v) in enumerate(targets, 1):
                cv2.circle(image, (int(round(u)), int(round(v))), 5, (0, 165, 255), 2)
                cv2.putText(image, str(agent), (int(round(u)) + 6, int(round(v)) - 6),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 165, 255), 1)
        return image

    def _publish_diagnostics(self) -> None:
        now = now_seconds(self)
        msg = DiagnosticArray()
        msg.header.stamp = messages.seconds_to_stamp(now)
        frames = max(self.frames, 1)
        for agent in range(1, self.n + 1):
            status = DiagnosticStatus(name=f'camera_tracker: robot {agent}',
                                      hardware_id=f'marker {self.layout.robot_ids[agent - 1]}')
            seen = self.last_seen.get(agent)
            lost = seen is None or now - seen > self.lost_timeout
            rate = self.seen_counts[agent] / frames
            unfitted = self._unfitted(self.layout.robot_ids[agent - 1])
            status.level = DiagnosticStatus.WARN if lost else DiagnosticStatus.OK
            status.message = ('lost' if lost else 'tracked') + (
                ', marker id seen twice' if agent in self.duplicates else '') + (
                f', pattern not fitted in {unfitted} frames (outline corners used: a '
                'smudged or partly covered marker?)' if unfitted else '')
            status.values = [KeyValue(key='detection_rate', value=f'{rate:.3f}'),
                             KeyValue(key='pattern_not_fitted', value=str(unfitted)),
                             KeyValue(key='last_seen_age_s', value='never' if seen is None
                                      else f'{now - seen:.3f}')]
            msg.status.append(status)
        camera = DiagnosticStatus(name=diagnostics.CAMERA_STATUS, hardware_id='camera')
        calibration = self.tracker.calibration
        calibrated = calibration is not None
        camera.level = DiagnosticStatus.OK if calibrated and self.frames else DiagnosticStatus.WARN
        camera.message = (f'{self.frames} frames' if self.frames else 'no frames') + (
            '' if calibrated else ', not calibrated')
        latency = np.array(self.latencies or [np.nan])
        processing = np.array(self.process_times or [np.nan])
        camera.values = [
            KeyValue(key='frames', value=str(self.frames)),
            KeyValue(key='latency_p50_s', value=f'{np.median(latency):.4f}'),
            KeyValue(key='latency_max_s', value=f'{np.max(latency):.4f}'),
            KeyValue(key='processing_p50_s', value=f'{np.median(processing):.4f}'),
            KeyValue(key='calibration_rms_px', value='none' if calibration is None
                     else f'{calibration.rms_px:.3f}')]
        msg.status.append(camera)
        self.diag_pub.publish(msg)
        self.seen_counts[:] = 0
        self.frames = 0
        self.latencies.clear()
        self.process_times.clear()
        self.duplicates.clear()
        if self.tracker.pattern_fit is not None:
            self.tracker.pattern_fit.misses.clear()

    def _unfitted(self, marker_id: int) -> int:
        """Frames since the last report in which marker_id's pattern fit was not used."""
        fit = self.tracker.pattern_fit
        return 0 if fit is None else fit.misses[marker_id]

    def on_shutdown(self) -> None:
        if self.capture is not None:
            self.capture.release()


def main(args: list[str] | None = None) -> int:
    return run_node(CameraTracker, args, large_data=True)   # camera frames


if __name__ == '__main__':
    raise SystemExit(main())
