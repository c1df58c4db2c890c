"""fake_camera: renders the arena as the overhead camera would see it (tests and demos).

Subscribes every fake robot's ground truth (/robot_<i>/true_pose) and publishes mono8
sensor_msgs/Image frames on /camera/image_raw at `rate_hz`, stamped with the time of capture
(the newest true pose's stamp): floor, corner markers and each robot's ArUco marker at its
pose (layout from the experiment's `camera` section, markers at their height); with
`camera.drawn_curve`, the experiment's curves drawn on the floor, each from its start time
(counted from this node's start), moving as a moving curve moves. Options:
resolution, tilt, lens distortion, pixel noise, blur, brightness; and faults for a
time window counted from the first curve: cover some robots' markers, or show a second marker
with a robot's id.
"""

from typing import Any

from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

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
from curve_formation.vision.camera import overhead_camera
from curve_formation.vision.lens import Lens
from curve_formation.vision.markers import MarkerLayout
from curve_formation.vision.render import ArenaRenderer, FloorLine, RenderOptions


DRAWN_SAMPLES = 1000   # points along a drawn curve (a few mm apart on an arena's curve)
MOVED_BY = 2e-4        # m: a moving drawn curve is redrawn once it has moved this far


NODE_NAME = 'fake_camera'   # also its console script's name
PARAMETERS = (
    Param('experiment', 'string', None, 'experiment YAML with `arena` and `camera` sections'),
    Param('rate_hz', 'double', 30.0, 'frame rate (Hz)', positive=True),
    Param('resolution', 'int[]', [1280, 720], 'image width and height (pixels)'),
    Param('tilt_deg', 'double', 0.0, 'camera tilt from straight down (degrees)', low=0.0,
          high=59.0),
    Param('height', 'double', 2.0, 'camera distance from the arena centre (m)', positive=True),
    Param('noise', 'double', 0.0, 'pixel noise standard deviation (grey levels)', low=0.0),
    Param('blur', 'double', 0.0, 'Gaussian blur sigma (pixels)', low=0.0),
    Param('brightness', 'double', 1.0, 'brightness factor', positive=True),
    Param('distortion', 'double[]', [], 'lens distortion k1 k2 p1 p2 [k3] (OpenCV order); [] '
          '= an ideal lens'),
    Param('hide', 'int[]', [], 'fault: agents whose marker is covered'),
    Param('duplicate_of', 'int', 0, "fault: show a second marker with this agent's id "
          '(0 = none)', low=0),
    Param('duplicate_at', 'double[]', [0.3, 0.3], 'fault: where the second marker lies '
          '[x, y] (m, arena frame)'),
    Param('fault_from', 'double', 0.0, 'faults start this long after the first curve '
          'arrives on /formation/curve (s)', low=0.0),
    Param('fault_for', 'double', -1.0, 'and last this long (s); negative = for good'),
    Param('seed', 'int', 0, 'seed of the pixel noise'),
    Param('frame_id', 'string', 'camera', 'frame of the published images'),
)


TOPICS = (
    Use('sub', topics.TRUE_POSE, "each fake robot's ground-truth pose", '<i>'),
    Use('sub', topics.CURVE, 'the first curve starts the fault clock'),
    Use('pub', topics.CAMERA_IMAGE, 'mono8 frames at rate_hz'),
    REPORTED,
)


class FakeCamera(Node):
    """Arena renderer over the fake robots' true poses."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.params = declare_parameters(self, PARAMETERS)
        experiment = experiment_parameter(p.experiment, needs=('camera', 'arena'))
        if len(p.resolution) != 2 or min(p.resolution) < 16:
            raise ParameterError(f"parameter 'resolution' must be [width, height] >= 16, got "
                                 f'{p.resolution}')
        if len(p.duplicate_at) != 2:
            raise ParameterError("parameter 'duplicate_at' must be [x, y]")
        n = experiment.n
        bad = [i for i in list(p.hide) + ([p.duplicate_of] if p.duplicate_of else [])
               if not 1 <= i <= n]
        if bad:
            raise ParameterError(f"parameters 'hide'/'duplicate_of': agents {bad} are not in "
                                 f'1..{n}')
        try:
            lens = Lens.from_coefficients(p.distortion)
        except ValueError as exc:
            raise ParameterError(f"parameter 'distortion': {exc}") from None
        spec = experiment.spec
        assert spec.camera is not None and spec.arena is not None   # checked on loading
        arena = spec.arena.size
        self.layout = MarkerLayout.from_spec(spec.camera)
        camera = overhead_camera(arena, tuple(p.resolution), p.tilt_deg, p.height)
        self.renderer = ArenaRenderer(camera, self.layout, arena,
                                      RenderOptions(p.noise, p.blur, p.brightness),
                                      robot_radius=experiment.spec.robots.radius, seed=p.seed,
                                      lens=lens)
        # a drawn curve: the experiment's curves drawn on the floor, each from its start time
        self.drawn = spec.camera.drawn_curve
        self.phases = experiment.phases
        self.started = now_seconds(self)
        self.drawn_phase: int | None = None
        self.drawn_points: np.ndarray | None = None
        self.poses: dict[int, tuple[float, float, float]] = {}
        self.stamps: dict[int, float] = {}   # when each true pose held (s)
        self.first_curve: float | None = None
        subscribe_to_curve(self, self._on_curve)
        for i in range(1, n + 1):
            topics.subscription(self, topics.TRUE_POSE, lambda m, i=i: self._on_pose(i, m),
                                robot=i)
        self.image_pub = topics.publisher(self, topics.CAMERA_IMAGE)
        self.create_timer(1.0 / p.rate_hz, self._on_timer)

    def _on_pose(self, i: int, msg: PoseStamped) -> None:
        x, y, theta, stamp = messages.pose_from_msg(msg)
        self.poses[i] = (x, y, theta)
        self.stamps[i] = stamp

    def _on_curve(self, _msg: Float64MultiArray) -> None:
        if self.first_curve is None:
            self.first_curve = now_seconds(self)

    def faulty(self, now: float) -> bool:
        """Whether the configured faults act at time `now` (s)."""
        p = self.params
        if self.first_curve is None:
            return False
        elapsed = now - self.first_curve
        return elapsed >= p.fault_from and (p.fault_for < 0 or elapsed <= p.fault_from
                                            + p.fault_for)

    def _on_timer(self) -> None:
        now = now_seconds(self)
        faulty = self.faulty(now)
        hidden = tuple(self.params.hide) if faulty else ()
        extra: tuple[tuple[int, float, float, float], ...] = ()
        if faulty and self.params.duplicate_of:
            x, y = self.params.duplicate_at
            extra = ((self.layout.robot_ids[self.params.duplicate_of - 1], x, y, 0.0),)
        if self.drawn is not None:
            self._draw_curve(now - self.started)
        image = self.renderer.render(self.poses, hidden, extra)
        # Stamped with when the scene it shows held, as a camera stamps its exposure.
        scene = max(self.stamps.values(), default=now)
        self.image_pub.publish(messages.image_to_msg(image, scene, self.params.frame_id))

    def _draw_curve(self, elapsed: float) -> None:
        """Draw the curve of the phase in force `elapsed` (s) after start on the floor, where
        it is then if it moves (redrawn once it has moved MOVED_BY).
        """
        index = max(k for k, ph in enumerate(self.phases) if ph.start <= elapsed or k == 0)
        phase = self.phases[index]
        if index == self.drawn_phase and phase.motion is None:
            return   # drawn already, and it stays
        _, points = phase.curve.sample(DRAWN_SAMPLES)
        if phase.motion is not None:
            points = phase.motion.points(points, max(elapsed - phase.start, 0.0))
        if (index == self.drawn_phase and self.drawn_points is not None
                and np.abs(points - self.drawn_points).max() < MOVED_BY):
            return
        self.drawn_phase, self.drawn_points = index, points
        assert self.drawn is not None   # drawn only where the camera has a drawn curve
        self.renderer.draw_on_floor(FloorLine(points, phase.curve.basis.closed,
                                              self.drawn.width, self.drawn.grey))


def main(args: list[str] | None = None) -> int:
    return run_node(FakeCamera, args, large_data=True)   # camera frames


if __name__ == '__main__':
    raise SystemExit(main())
