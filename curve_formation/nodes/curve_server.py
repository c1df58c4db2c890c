"""curve_server: publishes the desired curve of an experiment, switching on its schedule.

Publishes /formation/curve (Float64MultiArray, latched: late joiners get the current curve),
/formation/curve_path (nav_msgs/Path) and /formation/markers (MarkerArray: the curve and each
agent's target point) for RViz. Accepts a newly observed curve as ordered sampled points on
/formation/observed_curve (PolygonStamped; closed when its last point repeats the first), fits it
by its shape (curve_sources.fit_points) and publishes it as the next curve; with `schedule` false
only observed curves are published (a curve drawn on the floor). Curve ids count up from 0 in the
order curves are published. Each curve carries every agent's curve parameter s_i, as the
experiment's `spacing` and `assignment` give them (an observed curve is assigned from the previous
curve's targets). The current curve is published again every `refresh_period` s (same id), for
readers that missed it; with `reassign_every`, the current curve is published again (same id)
whenever re-assigning its targets among the robots, from their poses on /formation/robot_poses,
shortens their squared trips by 10 %; the next scheduled curve is then assigned from the targets as
re-assigned (Phase.assigned_from), as the simulator does. Where the controllers have measured
their robots' wheels (each robot's top_speed), a curve switched to is assigned by trip time
where that shortens the longest trip enough (assignment.timed_order), the first from where the
robots are at the start (with the motor check, which measures them, the start waits for every
robot's). What is published when is
core.schedule.curve_schedule's, which the nodes' pipeline steps too.
"""

import math
from typing import Any

from geometry_msgs.msg import Point, PolygonStamped, PoseStamped
from nav_msgs.msg import Path
import numpy as np
from rclpy.node import Node
from rclpy.timer import Timer
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Float64
from visualization_msgs.msg import Marker, MarkerArray

from curve_formation.core.config.checks import points_outside_arena
from curve_formation.core.config.experiment import ANNOUNCE_AHEAD
from curve_formation.core.controller.motor_probe import CHECK_SECONDS
from curve_formation.core.controller.plausibility import MAX_COORDINATE
from curve_formation.core.controller.settings import default
from curve_formation.core.formation.assignment import (
    AssignmentError,
    phase_parameters,
    TIMED_GAIN,
)
from curve_formation.core.formation.curve_sources import fit_points
from curve_formation.core.formation.curves import Curve, CurveError, make_basis
from curve_formation.core.formation.dynamics import offset_points
from curve_formation.core.schedule.curve_schedule import CurveSchedule, Publication
from curve_formation.nodes import messages, topics
from curve_formation.nodes.estop import estop_uses, EstopHolder
from curve_formation.nodes.params import (
    declare_parameters,
    experiment_parameter,
    Param,
)
from curve_formation.nodes.readiness import ReadyCount
from curve_formation.nodes.runtime import LastMessages, now_seconds, run_node
from curve_formation.nodes.topics import Use


NODE_NAME = 'curve_server'   # also its console script's name
PARAMETERS = (
    Param('experiment', 'string', None, 'experiment YAML (path or shipped name) whose curve '
          'schedule is served'),
    Param('path_samples', 'int', 200, 'points in the published Path and curve marker', low=3),
    Param('observed_basis', 'string', 'auto', "basis for observed curves; 'auto' = fourier "
          'for a closed one (its last point repeats the first), polynomial for an open one',
          choices=('auto', 'fourier', 'polynomial')),
    Param('observed_size', 'int', 8, 'harmonics K (fourier) or order p (polynomial) for '
          'observed curves', low=1),
    Param('moving_rate_hz', 'double', 10.0, 'how often a moving curve (curves[].motion) is '
          'published again, with its coefficients and their rate', positive=True),
    Param('announce_ahead', 'double', ANNOUNCE_AHEAD, 'a curve that begins to move where it '
          "is (the next phase's curve and targets are the current ones, with a motion) is "
          'published this long (s) before its start, dated by its clock to begin moving then: '
          "every controller's tick before the start already has it, and the robots move off "
          'with the curve instead of up to a control period after it (0 = at the start)',
          low=0.0),
    Param('schedule', 'bool', True, "publish the experiment's `curves` on their schedule; "
          'false = only observed curves (a curve drawn on the floor)'),
    Param('frame_id', 'string', 'arena', 'frame of the published curve'),
    Param('reassign_every', 'double', -1.0, 'period (s) at which targets are re-assigned among '
          "the robots from their poses on /formation/robot_poses (assignment.reassigned); "
          "negative = the experiment's agents.reassign_every (0 = never)"),
    Param('pose_timeout', 'double', default('safety.pose_timeout'), 'robot poses older than '
          'this are not used to re-assign (s)', positive=True),
    Param('wait_for_ready', 'int', 0, 'start the schedule (t = 0) only once this many nodes '
          'have said on /formation/ready that they receive /formation/curve from this server '
          '(a controller with controller.motor_check: once its check is done), and its '
          'publisher has matched as many subscriptions, so all robots start together '
          '(readiness.py)', low=0),
    Param('wait_for_poses', 'bool', False, "start the schedule only once every robot's pose "
          '(/robot_<i>/pose) has been received, so that t = 0 is not spent waiting for a '
          'robot (a graph started by hand; the runner waits for them itself)'),
    Param('refresh_period', 'double', 1.0, 'the current curve is published again (same id, '
          'same agent parameters) once nothing was published on /formation/curve for this '
          'long (s), so a reader that missed the latched message (a restarted controller: '
          'Fast DDS can fail to deliver a late joiner its history) gets it; 0 = never',
          low=0.0),
)


TOPICS = (
    Use('pub', topics.CURVE),
    Use('pub', topics.CURVE_PATH),
    Use('pub', topics.CURVE_MARKERS),
    Use('sub', topics.OBSERVED_CURVE, 'a newly observed curve as ordered points, fitted and '
        'published as the next curve'),
    Use('sub', topics.ROBOT_POSES, "every robot's pose, to re-assign targets (with "
        'reassign_every) and to assign the first curve from where the robots are once their '
        'top speeds are known'),
    Use('sub', topics.TOP_SPEED, 'how fast each robot drives, its wheels measured: curves '
        'are assigned by trip time (with controller.motor_check the start waits for every '
        "robot's)", robot='<i>'),
    Use('sub', topics.READY, 'names of the nodes that receive the curve, counted before the '
        'first curve (wait_for_ready)'),
    Use('sub', topics.POSE, 'before the first curve only (wait_for_poses): has every robot a '
        'pose yet', robot='<i>'),
) + estop_uses('held (latched) for the nodes that start while it is engaged')

WAIT_POLL = 0.05   # s, how often readiness is checked before the first curve
# An observed curve of more points than this is refused (the fit costs points x basis size).
MAX_OBSERVED_POINTS = 20_000


class CurveServer(Node):
    """Publishes the experiment's curves on schedule and fits observed ones."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.params = declare_parameters(self, PARAMETERS)
        self.experiment = experiment_parameter(self.params.experiment)
        self.curve_pub = topics.publisher(self, topics.CURVE)
        self.path_pub = topics.publisher(self, topics.CURVE_PATH)
        self.marker_pub = topics.publisher(self, topics.CURVE_MARKERS)
        topics.subscription(self, topics.OBSERVED_CURVE, self._on_observed)
        # Holds the e-stop for controllers and bridges that (re)start while it is engaged.
        self.estop = EstopHolder(self, robots=self.experiment.n)
        # What is published when, on this node's clock (core.schedule.curve_schedule, as the nodes'
        # pipeline steps it); its last publication is the current curve.
        self.schedule = CurveSchedule(self.experiment, self.params.schedule,
                                      self.params.announce_ahead)
        self.start: float | None = None
        # fires refresh_period after the last curve message
        self.refresh_timer: Timer | None = None
        # (stamp s, closed, points bytes) of the last observed curve
        self.last_observed: tuple[float, bool, bytes] | None = None
        # (poses (n, 3), stamp s) last received
        self.poses: tuple[np.ndarray, float] | None = None
        every = self.params.reassign_every
        if every < 0:
            every = self.experiment.spec.agents.reassign_every or 0.0
        self.reassign_every = every
        topics.subscription(self, topics.ROBOT_POSES, self._on_poses)
        # each robot's top speed (m/s; NaN until heard, or refused: taken at the wheels'
        # limit), as its controller measured it; the robots heard from (1-based)
        self.speeds = np.full(self.experiment.n, np.nan)
        self.speeds_heard: set[int] = set()
        for i in range(1, self.experiment.n + 1):
            topics.subscription(self, topics.TOP_SPEED, lambda msg, i=i: self._on_speed(i, msg),
                                i)
        # Polls for subscribers every WAIT_POLL s until the start, then wakes at each switch.
        self.ready = ReadyCount(self)
        self.unposed = set(range(1, self.experiment.n + 1)) if self.params.wait_for_poses \
            else set()   # robots whose pose has not come yet (before the start)
        self.pose_waits = [topics.subscription(self, topics.POSE,
                                               lambda _, i=i: self.unposed.discard(i), i)
                           for i in sorted(self.unposed)]
        self.timer = self.create_timer(WAIT_POLL, self._on_timer)
        self._on_timer()

    def _on_timer(self) -> None:
        if self.start is None:
            # Both sides of each link: a reader that has found this server says so on
            # /formation/ready; this server's writer must have found as many readers, or its
            # first curve is not sent to those it has not (they would get a later one).
            awaited = self.params.wait_for_ready
            matched = self.curve_pub.get_subscription_count()
            if len(self.ready) < awaited or matched < awaited:
                checks = ('; controllers say so once their motor check is done '
                          f'({CHECK_SECONDS:g} s)'
                          if self.experiment.spec.controller.motor_check else '')
                self.get_logger().warn(
                    f'waiting for {awaited} curve subscribers to be ready, '
                    f'{len(self.ready)} so far: {sorted(self.ready.names)}; this server '
                    f'reaches {matched}{checks}', skip_first=True, throttle_duration_sec=5.0)
                return
            if self.unposed:
                self.get_logger().warn(
                    'waiting for the poses of robots '
                    f'{", ".join(map(str, sorted(self.unposed)))} (/robot_<i>/pose)',
                    skip_first=True, throttle_duration_sec=5.0)
                return
            unmeasured = sorted(set(range(1, self.experiment.n + 1)) - self.speeds_heard)
            if self.experiment.spec.controller.motor_check and unmeasured:
                self.get_logger().warn(
                    'waiting for the top speeds of robots '
                    f'{", ".join(map(str, unmeasured))} (/robot_<i>/top_speed, sent once '
                    'their motor check is done)', skip_first=True, throttle_duration_sec=5.0)
                return
            for subscription in self.pose_waits:
                self.destroy_subscription(subscription)
            self.pose_waits = []
            self.schedule.robots_now(self._points(), self.speeds)
            if self.schedule.speeds is not None:
                slowest = int(np.argmin(self.schedule.speeds))
                self.get_logger().info(
                    "robots' top speeds known: curves assigned by trip time where that "
                    f'shortens the longest by {100 * TIMED_GAIN:g} % (slowest robot '
                    f'{slowest + 1}, {self.schedule.speeds[slowest]:.4f} m/s)')
            self.start = now_seconds(self)
            self.schedule.begin(self.start)
            if self.reassign_every > 0:
                self.create_timer(self.reassign_every, self._reassign)
            self.create_timer(1.0 / self.params.moving_rate_hz, self._renew_moving)
            if self.params.refresh_period > 0:
                self.refresh_timer = self.create_timer(self.params.refresh_period,
                                                       self._refresh)
        for publication in self.schedule.due(now_seconds(self)):
            self.publish_curve(publication)
        due = self.schedule.next_due()
        if due is None:
            self.timer.cancel()
            return
        self.timer.timer_period_ns = max(1_000_000, int((due - now_seconds(self)) * 1e9))
        self.timer.reset()

    def _renew_moving(self) -> None:
        """Publish the moving curve where it is now, with its rate (same id)."""
        publication = self.schedule.renewal(now_seconds(self))
        if publication is not None:
            self.publish_curve(publication, quiet=True)

    def _refresh(self) -> None:
        """Publish the current curve message again: refresh_period has passed without one
        (a moving curve is renewed more often than that anyway).
        """
        if self.schedule.last is not None and self.schedule.moving_since is None:
            self._send(self.schedule.last)

    def _send(self, publication: Publication) -> None:
        """Publish a curve message; the refresh waits a whole period from now."""
        if self.refresh_timer is not None:
            self.refresh_timer.reset()
        self.curve_pub.publish(messages.curve_to_msg(
            publication.curve, publication.curve_id, publication.s, publication.rate,
            publication.clock))

    def on_shutdown(self) -> LastMessages:
        """The last curve message, acknowledged (0.5 s at most) so that a recorder misses
        none of them.
        """
        return [(self.curve_pub, 0.5)]

    def _on_poses(self, msg: JointState) -> None:
        try:
            self.poses = messages.robot_poses_from_msg(msg)
        except messages.MessageError:
            self.poses = None

    def _on_speed(self, i: int, msg: Float64) -> None:
        """Robot i's top speed (m/s): curves switched to from now are assigned with it (one
        that is no speed is refused: the robot taken at the wheels' limit).
        """
        speed = float(msg.data)
        self.speeds_heard.add(i)
        if not (math.isfinite(speed) and speed > 0.0):
            self.get_logger().error(f'robot {i} top speed refused: {speed} m/s (expected a '
                                    "positive number; taken at the wheels' limit)",
                                    throttle_duration_sec=5.0)
            speed = math.nan
        self.speeds[i - 1] = speed
        self.schedule.robots_now(None, self.speeds)

    def _points(self) -> np.ndarray | None:
        """The robots' control points (n, 2; m, arena frame) from their latest poses, if every
        robot is in them and they are fresh (pose_timeout); else None.
        """
        if self.poses is None:
            return None
        poses, stamp = self.poses
        if (len(poses) != self.experiment.n or not np.isfinite(poses).all()
                or now_seconds(self) - stamp > self.params.pose_timeout):
            return None
        return offset_points(poses, self.experiment.gains.offset)

    def _reassign(self) -> None:
        """Give robots whose ways have come to cross each other's targets (the curve as it
        is, same id, with the agents' parameters permuted).
        """
        points = self._points()
        if points is None:
            return
        publication = self.schedule.reassign(points, now_seconds(self))
        if publication is not None:
            self.publish_curve(publication)
            self.get_logger().info(f'curve {publication.curve_id}: targets re-assigned')

    def publish_curve(self, publication: Publication, quiet: bool = False) -> None:
        """Publish a curve message of the schedule (core.schedule.curve_schedule.Publication) with
        its path
        and its markers: the next curve, or the current one with its agents re-assigned or
        moved on.
        """
        self._send(publication)
        curve = publication.curve
        stamp = self.get_clock().now().to_msg()
        pts = curve.outline(self.params.path_samples)
        path = Path()
        path.header.stamp, path.header.frame_id = stamp, self.params.frame_id
        for x, y in pts:
            pose = PoseStamped()
            pose.header = path.header
            pose.pose.position.x, pose.pose.position.y = float(x), float(y)
            pose.pose.orientation.w = 1.0
            path.poses.append(pose)
        self.path_pub.publish(path)
        self.marker_pub.publish(self._markers(pts, curve.points(publication.s), stamp))
        if not quiet:
            self.get_logger().info(f'published curve {publication.curve_id} '
                                   f'({curve.basis.describe()})')

    def _markers(self, pts: np.ndarray, targets: np.ndarray, stamp: Any) -> MarkerArray:
        line = Marker(ns='curve', id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
        line.scale.x = 0.005 * max(1.0, float(np.ptp(pts, axis=0).max()))
        line.color = ColorRGBA(r=0.1, g=0.1, b=0.1, a=1.0)
        line.points = [Point(x=float(x), y=float(y)) for x, y in pts]
        dots = Marker(ns='targets', id=1, type=Marker.SPHERE_LIST, action=Marker.ADD)
        dots.scale.x = dots.scale.y = dots.scale.z = 3 * line.scale.x
        dots.color = ColorRGBA(r=0.9, g=0.2, b=0.1, a=1.0)
        dots.points = [Point(x=float(x), y=float(y)) for x, y in targets]
        for marker in (line, dots):
            marker.header.stamp, marker.header.frame_id = stamp, self.params.frame_id
            marker.pose.orientation.w = 1.0
        return MarkerArray(markers=[line, dots])

    def _on_observed(self, msg: PolygonStamped) -> None:
        count = len(msg.polygon.points)
        if count > MAX_OBSERVED_POINTS:
            self.get_logger().error(f'observed curve refused: {count} points, at most '
                                    f'{MAX_OBSERVED_POINTS}')
            return
        points, closed = messages.polygon_from_msg(msg)
        # The camera tracker sends an observed curve again until it reads the answer; a busy
        # tracker may not have read it yet: the same message (stamp and points) is no news.
        seen = (messages.stamp_to_seconds(msg.header.stamp), closed, points.tobytes())
        if seen == self.last_observed:
            return
        self.last_observed = seen
        kind = self.params.observed_basis
        if kind == 'auto':
            kind = 'fourier' if closed else 'polynomial'
        elif closed and kind == 'polynomial':   # an open fit keeps the repeated end point
            points = np.vstack([points, points[:1]])
        try:
            basis = make_basis(kind, self.params.observed_size)
            fit = fit_points(basis, points)
            self._check_in_arena(fit.curve)
            agents = self.experiment.spec.agents
            s = phase_parameters(fit.curve, self.experiment.n, agents.spacing,
                                 agents.assignment, self.schedule.targets)
        except (CurveError, AssignmentError) as exc:
            self.get_logger().error(f'observed curve refused ({len(points)} points): {exc}')
            return
        self.get_logger().info(f'observed curve fitted from {len(points)} points, rms '
                               f'residual {fit.rms_residual:.3g}')
        self.publish_curve(self.schedule.observed(fit.curve, s, now_seconds(self)))

    def _check_in_arena(self, curve: Curve) -> None:
        """CurveError unless the curve lies in the arena as a curve of the experiment file must
        (core.config.experiment.points_outside_arena); without an arena, within MAX_COORDINATE.
        """
        _, points = curve.sample(2000)
        spec = self.experiment.spec
        if spec.arena is not None:
            width, height = spec.arena.size
            problem = points_outside_arena(points, width, height, spec.robots.radius)
        elif np.abs(points).max() > MAX_COORDINATE:
            problem = f'beyond +-{MAX_COORDINATE:g} m (it reaches {np.abs(points).max():.4g} m)'
        else:
            problem = None
        if problem is not None:
            raise CurveError(f'the fitted curve leaves the arena {problem}')


def main(args: list[str] | None = None) -> int:
    return run_node(CurveServer, args)


if __name__ == '__main__':
    raise SystemExit(main())
