"""Pre-flight: before a formation drives real (or emulated) robots, every robot is checked.

For PREFLIGHT_WINDOW s (after every robot's first pose, POSES_TIMEOUT s at most) each robot's
link gets its firmware's stop line every STOP_PERIOD s, straight from this process (no robot
bridge holds the link yet), and its answers are counted; meanwhile every robot's pose is
read from /robot_<i>/pose. A robot passes when its marker is seen (pose fresh, inside the
arena, not on top of another robot), its link answers (where its firmware answers at all),
and the stop is confirmed: answered, and the robot does not move while stopped. Nothing on
the domain may serve another formation, and a camera tracker heard on /diagnostics must have
its arena calibration. The result is a table, a PreflightResult for
metrics.json, and a latched /formation/preflight message for the bag.

Poses in the arena frame (m); times in s.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.node import Node

from curve_formation import diagnostics, wire
from curve_formation.core.config.experiment import Experiment
from curve_formation.fleet import FleetRobot
from curve_formation.interface import robot_name
from curve_formation.links import LinkError, robot_link
from curve_formation.nodes import messages, topics
from curve_formation.nodes.runtime import now_seconds


PREFLIGHT_WINDOW = 1.5   # s of stop lines and poses judged
POSES_TIMEOUT = 6.0      # s at most from the first stop line until every robot is seen
STOP_PERIOD = 0.1        # s between two stop lines to a robot
SETTLE = 0.3             # s a robot may take to come to rest after the first stop line
STILL = 0.005            # m a stopped robot may seem to move over the window (camera noise)
REPLY_FRESH = 0.5        # s: an older last answer is a link that does not answer


class MissingRobotsError(Exception):
    """Pre-flight failed only for robots that may be missing: start without them."""

    def __init__(self, result):
        super().__init__(f'robots {result.failing} left out')
        self.result = result


class PreflightError(ValueError):
    """Pre-flight refused the run; `result` says why, robot by robot."""

    def __init__(self, result: 'PreflightResult', hint: str = '') -> None:
        self.result = result
        failing = '; '.join(f'robot {r.agent}: {", ".join(r.problems)}'
                            for r in result.robots if not r.passed)
        problems = '; '.join(result.problems)
        super().__init__('pre-flight refused: ' + '; '.join(filter(None, [failing, problems]))
                         + (f' ({hint})' if hint else ''))


@dataclass
class RobotCheck:
    """One robot's pre-flight: what was seen of it and why it fails (problems)."""

    agent: int
    marker: int | None
    link: str
    replies_expected: bool = True
    seen: bool = False
    pose: tuple[float, float, float] | None = None
    pose_age: float | None = None
    replies: int = 0
    reply_age: float | None = None
    moved: float | None = None          # m over the judged window
    problems: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.problems

    @property
    def link_up(self) -> bool | None:
        """The link answered lately (None: its firmware does not answer)."""
        if not self.replies_expected:
            return None
        return self.reply_age is not None and self.reply_age <= REPLY_FRESH

    @property
    def stop_confirmed(self) -> bool:
        """Stop answered (where the firmware answers) and the robot seen not moving."""
        still = self.moved is not None and self.moved <= STILL
        return still and self.link_up is not False

    def as_dict(self) -> dict[str, Any]:
        return {'robot': self.agent, 'marker': self.marker, 'link': self.link,
                'seen': self.seen, 'pose': None if self.pose is None else list(self.pose),
                'pose_age_s': self.pose_age, 'link_up': self.link_up,
                'replies': self.replies, 'reply_age_s': self.reply_age,
                'moved_m': self.moved, 'stop_confirmed': self.stop_confirmed,
                'passed': self.passed, 'problems': list(self.problems)}


@dataclass
class PreflightResult:
    """Every robot's check, the problems of the whole (another formation), the time taken."""

    robots: list[RobotCheck]
    problems: list[str] = field(default_factory=list)
    duration: float = 0.0
    left_out: list[int] = field(default_factory=list)   # robots --allow-missing removed
    calibration: str | None = None   # the camera tracker's residual (px), 'none', or unheard

    @property
    def failing(self) -> list[int]:
        return [r.agent for r in self.robots if not r.passed]

    @property
    def passed(self) -> bool:
        return not self.problems and not self.failing

    def table(self) -> str:
        """The result as a table: robot, marker seen, link, reply age, stop confirmed."""
        rows = [('robot', 'marker', 'seen', 'link', 'reply age', 'stop confirmed', 'problems')]
        for r in self.robots:
            age = '-' if r.reply_age is None else f'{r.reply_age:.2f} s'
            link = {True: 'up', False: 'down', None: 'no replies'}[r.link_up]
            rows.append((robot_name(r.agent), '-' if r.marker is None else str(r.marker),
                         'yes' if r.seen else 'no', link, age,
                         'yes' if r.stop_confirmed else 'no',
                         ', '.join(r.problems) or 'ok'))
        widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]) - 1)]
        lines = ['  '.join(cell.ljust(w) for cell, w in zip(row, widths, strict=False))
                 + '  ' + row[-1] for row in rows]
        if self.calibration is not None:
            lines.append(f'camera: arena calibration residual {self.calibration} px')
        lines += [f'pre-flight: {p}' for p in self.problems]
        verdict = ('passed' if self.passed else
                   f'FAILED for robot(s) {", ".join(map(str, self.failing))}' if self.failing
                   else 'FAILED')
        lines.append(f'pre-flight {verdict} ({len(self.robots)} robots, {self.duration:.1f} s)')
        return '\n'.join(lines)

    def as_dict(self) -> dict[str, Any]:
        return {'passed': self.passed, 'duration_s': round(self.duration, 3),
                'camera_calibration_rms_px': self.calibration,
                'robots': [r.as_dict() for r in self.robots], 'problems': list(self.problems),
                'failing': self.failing, 'left_out': list(self.left_out)}

    def message(self, stamp: float) -> DiagnosticArray:
        """The result as a /formation/preflight DiagnosticArray: one status per robot and one
        for the whole fleet.
        """
        statuses = [DiagnosticStatus(
            level=DiagnosticStatus.OK if r.passed else DiagnosticStatus.ERROR,
            name=robot_name(r.agent), hardware_id=r.link,
            message='ok' if r.passed else ', '.join(r.problems),
            values=[KeyValue(key=k, value=str(v)) for k, v in r.as_dict().items()
                    if k not in ('robot', 'link', 'problems')]) for r in self.robots]
        statuses.append(DiagnosticStatus(
            level=DiagnosticStatus.OK if self.passed else DiagnosticStatus.ERROR,
            name='preflight', message='passed' if self.passed else 'refused',
            values=[KeyValue(key='failing', value=','.join(map(str, self.failing))),
                    KeyValue(key='left_out', value=','.join(map(str, self.left_out))),
                    KeyValue(key='problems', value='; '.join(self.problems))]))
        msg = DiagnosticArray(status=statuses)
        msg.header.stamp = messages.seconds_to_stamp(stamp)
        return msg


class PoseWatch(Node):
    """Every robot's poses as they come (/robot_<i>/pose), on this node's clock, and whether
    another formation's curve server is on the domain.
    """

    def __init__(self, n: int, **kwargs: Any) -> None:
        super().__init__('preflight', **kwargs)
        # robot (1-based) -> [(received s, x, y, theta)]
        self.poses: dict[int, list[tuple[float, float, float, float]]] = {
            i: [] for i in range(1, n + 1)}
        self.watching = [topics.subscription(self, topics.POSE,
                                             lambda msg, i=i: self._on_pose(i, msg), robot=i)
                         for i in range(1, n + 1)]
        self.publisher = topics.publisher(self, topics.PREFLIGHT)
        # the camera tracker's arena calibration as its /diagnostics says: None before it
        # reported, 'none' while it has none, else its residual (px)
        self.calibration: str | None = None
        self.watching.append(topics.subscription(self, topics.DIAGNOSTICS,
                                                 self._on_diagnostics))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == diagnostics.CAMERA_STATUS:
                self.calibration = next((kv.value for kv in status.values
                                         if kv.key == 'calibration_rms_px'), None)

    def stop_watching(self) -> None:
        """Drop the pose subscriptions (the result's publisher stays, latched)."""
        for subscription in self.watching:
            self.destroy_subscription(subscription)
        self.watching = []

    def _on_pose(self, i: int, msg: PoseStamped) -> None:
        x, y, theta, _ = messages.pose_from_msg(msg)
        if math.isfinite(x) and math.isfinite(y) and math.isfinite(theta):
            self.poses[i].append((now_seconds(self), x, y, theta))

    def another_formation(self) -> bool:
        return self.count_publishers(topics.CURVE) > 0

    def now(self) -> float:
        return now_seconds(self)


class LinkProbe:
    """Stop lines to one robot over its link, straight from this process, and its answers."""

    def __init__(self, robot: FleetRobot) -> None:
        self.robot = robot
        self.format = wire.wire_format(robot.format)
        self.link = robot_link(robot.address.bridge_text, robot.address.baud)
        self.seq = 0
        self.replies = 0
        self.first_reply: float | None = None
        self.last_reply: float | None = None
        self.error = ''

    def stop(self) -> None:
        self.seq += 1
        try:
            self.link.send(wire.encode_stop(self.format, self.seq))
        except LinkError as exc:
            self.error = str(exc)

    def read(self, now: float) -> None:
        for line in self.link.lines():
            if wire.is_reply(line):
                self.replies += 1
                self.last_reply = now
                if self.first_reply is None:
                    self.first_reply = now

    def close(self) -> None:
        self.link.close()


def judge(experiment: Experiment, fleet: Sequence[FleetRobot],
          poses: dict[int, list[tuple[float, float, float, float]]],
          probes: Sequence[LinkProbe], began: float, now: float) -> list[RobotCheck]:
    """Each robot's RobotCheck from its poses (received s, x, y, theta), its link's
    answers and the time the first stop line went (began) and now (s, one clock).
    """
    spec = experiment.spec
    size = spec.arena.size if spec.arena is not None else None
    timeout = spec.safety.pose_timeout
    checks = []
    latest: dict[int, tuple[float, float]] = {}
    for robot, probe in zip(fleet, probes, strict=True):
        check = RobotCheck(robot.agent, robot.marker, robot.address.text, robot.replies)
        seen = poses.get(robot.agent, [])
        if seen:
            t, x, y, theta = seen[-1]
            check.seen, check.pose, check.pose_age = True, (x, y, theta), now - t
            latest[robot.agent] = (x, y)
            judged = np.array([(px, py) for tp, px, py, _ in seen
                               if tp >= _stopped_from(probe, began)])
            if len(judged) >= 2:
                check.moved = float(np.linalg.norm(judged - judged[0], axis=1).max())
        check.replies = probe.replies
        check.reply_age = None if probe.last_reply is None else now - probe.last_reply
        if not check.seen:
            check.problems.append(f'marker {robot.marker} not seen' if robot.marker is not None
                                  else 'no pose')
        elif check.pose_age is not None and check.pose_age > timeout:
            check.problems.append(f'pose {check.pose_age:.1f} s old')
        elif size is not None and check.pose is not None and not (
                0.0 <= check.pose[0] <= size[0] and 0.0 <= check.pose[1] <= size[1]):
            check.problems.append(f'outside the arena at ({check.pose[0]:.3f}, '
                                  f'{check.pose[1]:.3f}) m')
        if check.link_up is False:
            check.problems.append(f'link {probe.error or "not answering"}' if probe.error
                                  else 'link not answering')
        if check.seen and check.moved is not None and check.moved > STILL:
            check.problems.append(f'moved {1e3 * check.moved:.0f} mm while stopped')
        elif check.seen and check.moved is None:
            check.problems.append('too few poses to see it stand still')
        checks.append(check)
    _overlaps(checks, latest, 2.0 * experiment.radius if experiment.radius > 0 else 0.01)
    return checks


def _stopped_from(probe: LinkProbe, began: float) -> float:
    """From when (s) a robot should stand: SETTLE after its first answer to a stop line (the
    first stop line's, for a firmware that does not answer or has not yet).
    """
    return (probe.first_reply if probe.first_reply is not None else began) + SETTLE


def _judged_span(poses: Sequence[tuple[float, float, float, float]], since: float) -> float:
    """How long (s) the poses received from `since` on span."""
    times = [t for t, *_ in poses if t >= since]
    return times[-1] - times[0] if len(times) >= 2 else 0.0


def _overlaps(checks: list[RobotCheck], latest: dict[int, tuple[float, float]],
              apart: float) -> None:
    """Add a problem to both robots of each pair seen closer than `apart` (m)."""
    agents = sorted(latest)
    for a_index, a in enumerate(agents):
        for b in agents[a_index + 1:]:
            gap = math.dist(latest[a], latest[b])
            if gap < apart:
                for one, other in ((a, b), (b, a)):
                    check = next(c for c in checks if c.agent == one)
                    check.problems.append(f'on top of robot {other} ({1e3 * gap:.0f} mm apart)')


def run_preflight(experiment: Experiment, fleet: Sequence[FleetRobot], watch: PoseWatch,
                  spin: Callable[[float], None], log: Callable[[str], None] = print,
                  ) -> PreflightResult:
    """Pre-flight of `fleet` (see the module): stop lines and answers over the links, poses
    through `watch` (spun by spin(s), taking every callback within s); returns the
    PreflightResult, logged as a table. Raises nothing for a failing robot: the caller
    decides (PreflightError).
    """
    started = time.monotonic()
    probes = [LinkProbe(robot) for robot in fleet]
    try:
        began = watch.now()
        next_stop = 0.0
        while True:
            now = time.monotonic()
            if now >= next_stop:
                for probe in probes:
                    probe.stop()
                next_stop = now + STOP_PERIOD
            spin(0.02)
            for probe in probes:
                probe.read(watch.now())
            waited = now - started
            watched = all(_judged_span(watch.poses[robot.agent], _stopped_from(probe, began))
                          >= PREFLIGHT_WINDOW for robot, probe in zip(fleet, probes,
                                                                       strict=True))
            if watched or waited >= POSES_TIMEOUT + SETTLE + PREFLIGHT_WINDOW:
                break
        checks = judge(experiment, fleet, watch.poses, probes, began, watch.now())
    finally:
        for probe in probes:
            probe.close()
    problems = []
    if watch.another_formation():
        problems.append('a curve server of another formation is on this domain')
    if watch.calibration == 'none':
        problems.append('the camera tracker has no arena calibration (corner markers not '
                        'seen, or no calibration_file)')
    result = PreflightResult(checks, problems, time.monotonic() - started,
                             calibration=watch.calibration)
    log(result.table())
    return result


def preflight_command(experiment: Experiment, fleet: Sequence[FleetRobot],
                      allow_missing: frozenset[int] = frozenset(),
                      log: Callable[[str], None] = print) -> PreflightResult:
    """`curve-formation preflight`: the pre-flight of the file's fleet on this process' ROS
    domain, with the robots' poses from whatever publishes them (the camera tracker, or the
    robots' own drivers); to run before the robot bridges start (they hold the links). Raises
    PreflightError if a robot fails that is not in allow_missing, or for another formation.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from curve_formation.nodes.runtime import make_executor
    if not fleet:
        raise ValueError(f'{experiment.source}: robots.fleet: no robots listed: pre-flight '
                         'checks the robots behind their links')
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        watch = PoseWatch(experiment.n, context=context)
        executor = make_executor(context)
        executor.add_node(watch)

        def spin(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=max(end - time.monotonic(), 0.0))
        result = run_preflight(experiment, fleet, watch, spin, log)
        watch.publisher.publish(result.message(now_seconds(watch)))
        executor.shutdown(timeout_sec=1.0)
        watch.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    failing = set(result.failing)
    if result.problems or not failing <= allow_missing:
        raise PreflightError(result)
    return result
