"""Unicycle kinematics with constant input disturbance.

x' = cos(theta) (v + d_v), y' = sin(theta) (v + d_v), theta' = w + d_w; arena frame, metres,
radians, seconds. Plain scalar math: the batch simulator compiles it with numba and the fake
robot node calls it as is.
"""

from collections.abc import Sequence
import math
from typing import TypeVar

import numpy as np

from curve_formation.core.base.shapes import Command, FloatArray, Point, Pose


Speeds = TypeVar('Speeds', float, FloatArray)   # one speed (m/s, rad/s) or an array of them


def chord_ratio(half: float) -> float:
    """sin(h) / h: chord over arc length of an arc turning 2 h (rad); accurate as h -> 0."""
    return math.sin(half) / half if abs(half) > 1e-4 else 1.0 - half * half / 6.0


def arc_step(x: float, y: float, theta: float, v: float, w: float, dt: float) -> Pose:
    """Exact pose after dt (s) at constant body velocities v (m/s) and w (rad/s).

    The chord of the arc, v dt sin(h) / h with h = w dt / 2, points along the mid-period
    heading; this form stays accurate as w -> 0, where v / w times a sine difference does not.
    """
    half = 0.5 * w * dt
    chord = v * dt * chord_ratio(half)
    mid = theta + half
    return x + chord * math.cos(mid), y + chord * math.sin(mid), theta + w * dt


def offset_point(x: float, y: float, theta: float, offset: float) -> Point:
    """Offset control point xb (m) ahead of the axle centre by `offset` along the heading."""
    return x + offset * math.cos(theta), y + offset * math.sin(theta)


def offset_points(poses: FloatArray, offset: float) -> FloatArray:
    """(..., 2) offset points xb = x + l [cos theta, sin theta] (m) of poses (..., 3)."""
    th = poses[..., 2]
    return poses[..., :2] + offset * np.stack([np.cos(th), np.sin(th)], axis=-1)


def marker_centres(poses: FloatArray, marker_offset: Sequence[float]) -> FloatArray:
    """(..., 2) arena-frame centres of markers mounted at marker_offset (robot frame, m)."""
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    return np.stack([poses[..., 0] + c * marker_offset[0] - s * marker_offset[1],
                     poses[..., 1] + s * marker_offset[0] + c * marker_offset[1]], axis=-1)


def measured_velocity(x0: float, y0: float, theta0: float, x1: float, y1: float, theta1: float,
                  dt: float) -> Command:
    """Constant (v, w) (m/s, rad/s) that moves a unicycle from pose 0 to pose 1 in dt (s).

    Exact for an arc (the inverse of arc_step); the heading change must be below
    pi over dt. The sign of v follows the chord's direction relative to the mean heading.
    """
    turn = math.atan2(math.sin(theta1 - theta0), math.cos(theta1 - theta0))
    mid = theta0 + 0.5 * turn
    along = (x1 - x0) * math.cos(mid) + (y1 - y0) * math.sin(mid)
    return along / (dt * chord_ratio(0.5 * turn)), turn / dt


def wheel_speeds(v: Speeds, w: Speeds, wheel_base: float) -> tuple[Speeds, Speeds]:
    """(left, right) rim speeds (m/s) of body velocities (v, w) on a differential drive of
    wheel_base (m); no limit applied. v and w may be arrays of one shape (then so are both).
    """
    return v - 0.5 * wheel_base * w, v + 0.5 * wheel_base * w


def body_from_wheels(left: float, right: float, wheel_base: float) -> Command:
    """(v, w) (m/s, rad/s) of rim speeds left, right (m/s) on a differential drive of
    wheel_base (m): the inverse of wheel_speeds.
    """
    return 0.5 * (left + right), (right - left) / wheel_base


class CommandQueue:
    """Velocity commands on their way to a robot's motors: each acts `latency` s (plus a
    uniform +-`jitter` s, its own draw from `seed`, never before the one before it) after it
    was received and holds until the next; a zero command means motors off, and so does a
    command older than `timeout` s (a robot-side watchdog; 0 = none). Times in s.
    """

    def __init__(self, latency: float = 0.0, timeout: float = 0.0, jitter: float = 0.0,
                 seed: int | Sequence[int] | None = None) -> None:
        from collections import deque
        self.latency = latency
        self.timeout = timeout
        self.jitter = jitter
        self.rng = np.random.default_rng(seed) if jitter > 0 else None
        self.last_due = -math.inf
        self.command = (0.0, 0.0)   # in force at self.time
        self.pending: deque[tuple[float, float, float]] = deque()   # (due s, v, w)
        self.time: float | None = None
        self.last_command_time: float | None = None

    def push(self, v: float, w: float, now: float) -> None:
        """A command (m/s, rad/s) received at `now`."""
        due = now + self.latency
        if self.rng is not None:
            due = max(due + self.rng.uniform(-self.jitter, self.jitter), self.last_due)
        self.last_due = due
        self.pending.append((due, v, w))
        self.last_command_time = now

    def upcoming(self, until: float) -> list[Command]:
        """The commands in force from now up to `until`: the current one and those due."""
        return [self.command] + [(v, w) for due, v, w in self.pending if due <= until]

    def segments(self, until: float
                 ) -> tuple[list[tuple[float, float, Command]], bool]:
        """Consume the queue up to `until`: [(from s, to s, (v, w)), ...] covering
        [self.time, until] with the command in force over each, and whether the watchdog
        turned the motors off on the way (at its own time, not at the caller's next step).
        """
        if self.time is None:
            self.time = until
        out: list[tuple[float, float, tuple[float, float]]] = []
        while self.pending and self.pending[0][0] <= until:
            due, v, w = self.pending.popleft()
            self._hold(max(due, self.time), out)
            self.command = (v, w)
        watchdog = self.watchdog_time()
        if until > watchdog:
            self._hold(watchdog, out)
            self.command = (0.0, 0.0)
            self._hold(until, out)
            return out, True
        self._hold(until, out)
        return out, False

    def watchdog_time(self) -> float:
        """When (s) the watchdog turns the motors off if no command comes (inf: it will not,
        the motors are off already or there is no watchdog).
        """
        if self.timeout <= 0 or self.command == (0.0, 0.0) or self.last_command_time is None:
            return math.inf
        return self.last_command_time + self.timeout + self.latency

    def next_change(self) -> float:
        """When (s) the command in force changes next: the next one due, or the watchdog."""
        due = self.pending[0][0] if self.pending else math.inf
        return min(due, self.watchdog_time())

    def _hold(self, until: float, out: list[tuple[float, float, Command]]) -> None:
        assert self.time is not None   # segments set it
        if until > self.time:
            out.append((self.time, until, self.command))
        self.time = max(self.time, until)


class DrivenUnicycle:
    """A robot driven by velocity commands, as its motor driver would move it (plain Python,
    for the fake robot nodes; the batch simulator has its own compiled loop).

    Commands pass through a CommandQueue (latency, watchdog); advance(t) integrates exactly
    (arc_step) up to t, switching to each command at its due time. The disturbance (m/s,
    rad/s) acts on a driven input only: motors off, it does not. Times in s.
    """

    def __init__(self, pose: Sequence[float], disturbance: Sequence[float] = (0.0, 0.0),
                 latency: float = 0.0, timeout: float = 0.0, jitter: float = 0.0,
                 seed: int | Sequence[int] | None = None) -> None:
        self.pose = (float(pose[0]), float(pose[1]), float(pose[2]))
        self.disturbance = tuple(disturbance)
        self.queue = CommandQueue(latency, timeout, jitter, seed)

    def drive(self, v: float, w: float, now: float, advance: bool = True) -> None:
        """A command received at `now`; it takes effect the queue's latency later.
        advance=False leaves moving up to `now` to the caller's next advance() (a world that
        steps every robot together).
        """
        if advance:
            self.advance(now)
        self.queue.push(v, w, now)

    @property
    def command(self) -> Command:
        """The command (m/s, rad/s) in force up to where the robot was advanced."""
        return self.queue.command

    def top_speed(self, until: float) -> float:
        """The fastest (m/s) the centre moves up to `until` under the command in force and
        those due by then.
        """
        return max(0.0 if (v, w) == (0.0, 0.0) else abs(v + self.disturbance[0])
                   for v, w in self.queue.upcoming(until))

    def advance(self, until: float) -> bool:
        """Move exactly up to `until`, switching commands at their due times. Returns
        True when the watchdog turned the motors off on the way.
        """
        segments, stopped = self.queue.segments(until)
        d = self.disturbance
        for start, end, (v, w) in segments:
            if v != 0.0 or w != 0.0:
                self.pose = arc_step(*self.pose, v + d[0], w + d[1], end - start)
        return stopped
