"""One robot's controller, free of ROS: what a formation_controller node runs each tick.

Inputs arrive as plain numbers with stamps in seconds: the active curve, the robot's own pose
(arena frame, m and rad), its in-neighbours' target errors and the e-stop. How old an input is,
is judged by when it was received on this controller's clock (`received`; the stamp when not
given): stamps come from other hosts' clocks (the camera PC's, the neighbours'), which on lab
PCs without time sync can differ by more than any timeout. Stamps serve only differences
between samples of one source (the observer's elapsed time).
Each tick either computes a command with the paper's local law, or stops the robot (zero
velocity, at once: stopping is never rate-limited) and says why: e-stop, no curve yet, own
pose stale, outside the geofence, no news from the leader, a neighbour missing, stale or on
another curve. While stopped the disturbance estimate is frozen, so it does not wind up, and
with an acceleration limit the robot ramps up again from rest.

Leader heartbeat: every state carries the age of the newest news of the leader its sender has
when its pose was taken (the leader: its pose is the news); a receiver dates that news on its
own clock (when that pose was taken, by the sender's stamps: StampClock, minus the age) and
keeps the newest. Since the leader reaches every agent, each agent learns within a few hops
when the leader is gone (and stops after `leader_timeout`), and learns again when it is back.
Where the stamps share the controllers' clock (one camera, or one machine) a hop neither adds
nor loses time, and a state that sat in a queue (a stalled process, a Wi-Fi burst) brings
news exactly as old as it is: no stall or cycle of followers can revive a dead leader. Where
they do not, news is dated as if it came as fast as the sender's fastest state.
"""

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
from typing import NamedTuple, Optional

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import Command, FloatArray, Point, Pose
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.driving import (
    drive_direction,
    REVERSE_HYSTERESIS,
    steered_law,
)
from curve_formation.core.controller.gains import OBSERVER
from curve_formation.core.controller.law import (
    agent_command,
    follower_feedback,
    leader_feedback,
)
from curve_formation.core.controller.limits import inside_fence
from curve_formation.core.controller.link_estimate import ONLINE_LAGS, OnlineLatency
from curve_formation.core.controller.observer import observe
from curve_formation.core.controller.plausibility import (
    error_problem,
    jump_problem,
    plausible_box,
    position_problem,
)
from curve_formation.core.controller.safety import STOPPED, with_latency
from curve_formation.core.formation.assignment import AssignmentError, check_assumptions
from curve_formation.core.formation.curves import Curve
from curve_formation.core.formation.dynamics import (
    arc_step,
    body_from_wheels,
    measured_velocity,
    offset_point,
    wheel_speeds,
)


NO_OTHERS = np.zeros((0, 3))
# Longest a pose is carried forward (s): a camera pipeline's latency is well below it, a
# stamp older than it says the clocks disagree (predict_pose).
MAX_PREDICTION = 0.25
# How far back (s) the other robots' poses are kept to measure their velocities (others_ahead)
OTHERS_KEPT = 0.2


def is_stale(stamp: float | None, now: float, timeout: float) -> bool:
    """True when an input stamped `stamp` (s, None if never received) is older than timeout."""
    return stamp is None or now - stamp > timeout


def all_finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _receipt(stamp: float, received: float | None) -> float:
    """When an input was received (s, this controller's clock): `received`, else its stamp."""
    return stamp if received is None else received


class StampClock:
    """A source's stamps on this controller's clock, judged from the smallest lag (receipt
    minus stamp, s) seen so far: the stamp itself where that lag is 0 to `shared` s (the
    source shares this clock), else the stamp plus that lag (another clock: dated as if it
    came as fast as the fastest). A message held in a queue keeps its stamp's date, so it
    is as old as it is, where a per-message rule could not tell it from another clock.
    """

    def __init__(self, shared: float) -> None:
        self.shared = shared
        self.floor = math.inf

    def date(self, stamp: float, received: float) -> float:
        """When the stamp was (s, this clock), counting this message's lag."""
        self.floor = min(self.floor, received - stamp)
        return stamp if 0.0 <= self.floor <= self.shared else stamp + self.floor


def _drive(x: float, y: float, theta: float, v: float, w: float, drift_v: float,
           drift_w: float, dt: float) -> Pose:
    """Pose after dt (s) under command (v, w), plus the drift while driven (m/s, rad/s)."""
    if dt <= 0.0:
        return x, y, theta
    if v != 0.0 or w != 0.0:
        v, w = v + drift_v, w + drift_w
    return arc_step(x, y, theta, v, w, dt)


@dataclass
class Tick:
    """Outcome of one control step. v, w (m/s, rad/s) are what to send; 0, 0 when stopped."""

    v: float = 0.0
    w: float = 0.0
    stopped: Optional[str] = None
    error: Optional[Point] = None     # own e_i (m), published for out-neighbours
    error_stamp: Optional[float] = None
    curve_id: Optional[int] = None
    dhat: tuple[float, float] = (0.0, 0.0)
    feedback: Optional[Point] = None
    # ((j, stamp s), ...) of the in-neighbour states used
    neighbour_stamps: tuple[tuple[int, Optional[float]], ...] = ()
    filtered: bool = False            # the safety filter changed the law's command
    pose: Optional[Pose] = None       # the pose the law used (predicted, with predict_pose)


@dataclass(frozen=True)
class State:
    """What an agent tells its out-neighbours.

    error e_i (m), curve id, pose stamp (s, the pose source's clock), and the age of the newest
    news of the leader it has (s, when the pose was taken: negative, down to -MAX_PREDICTION,
    for news that came after; None before any news).
    """

    error: Point
    curve_id: int
    stamp: float
    leader_age: Optional[float]


class Sent(NamedTuple):
    """A command as sent at `at` (s, the controller's clock): (v, w) (m/s, rad/s); the
    observer's reference and the safety filter's shift of it, and whether the wheel limits
    cut it by more than control.RAY_CLIPPED (control.observe); driven: False for a stop
    (motors off, no drift).
    """

    at: float
    v: float
    w: float
    reference: Command
    shift: Command
    limited: bool
    driven: bool
    estimate: int = 0   # the observer's updates made before it (AgentController.updates)


@dataclass
class _Neighbour:
    error: Point = (0.0, 0.0)
    curve_id: Optional[int] = None
    stamp: Optional[float] = None       # s, the sender's pose source's clock
    received: Optional[float] = None    # s, this controller's clock


# observer_order 2 predicts the disturbance over the coming period only after this many
# updates in a row whose commands the wheel limits did not cut (its rate has settled)
TRACKING_TICKS = 10
# The poses an observer keeps to begin a motion at (a second at 30 Hz), and the shortest
# motion (s) it measures from a later start than the last tick's pose.
RECENT_POSES = 32
MIN_OBSERVED = 0.05


def _rate_update(rate: tuple[float, float], predicted: tuple[float, float],
                 corrected: tuple[float, float], alpha: float, elapsed: float, searching: bool
                 ) -> tuple[float, float]:
    """The second-order observer's rate of the estimate (per s) after a tick: an alpha-beta
    filter's, the estimate corrected by alpha of the innovation and its rate by beta of it
    over the elapsed time, beta = (1 - sqrt(1 - alpha))^2 so that the estimation error's
    two poles coincide at sqrt(1 - alpha) (critically damped: the error of a disturbance
    changing at a constant rate decays without overshoot); zero while the wheel limits cut
    the command (the motion shows the disturbance's direction, not its size, and the search
    along it is no change of the disturbance).
    """
    if searching:
        return 0.0, 0.0
    if alpha <= 0.0 or elapsed <= 0.0:
        return rate
    beta = (1.0 - math.sqrt(max(1.0 - alpha, 0.0))) ** 2
    gain = beta / alpha / elapsed
    return (rate[0] + gain * (corrected[0] - predicted[0]),
            rate[1] + gain * (corrected[1] - predicted[1]))


@dataclass(frozen=True)
class _CurveTargets:
    """Every agent's target on one curve (n, 2; m, arena frame) as it held at `dated` (s, this
    controller's clock) and their velocities (n, 2; m/s; zero on a still curve).
    """

    curve_id: int
    targets: FloatArray
    velocities: FloatArray
    dated: float

    def at(self, j: int, t: float) -> Point:
        """Agent j's (1-based) target at t (s)."""
        age = max(t - self.dated, 0.0)
        tx, ty = self.targets[j - 1] + self.velocities[j - 1] * age
        return float(tx), float(ty)


def compiled_command(config: AgentConfig) -> Callable[..., tuple]:
    """control.agent_command compiled (core.base.jit.compiled) and called once with the
    argument types of config's ticks, so that no tick waits for numba.
    """
    from curve_formation.core.base.jit import compiled
    command = compiled(agent_command)
    command(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            *config.pc_disturbance, config.law, config.limits, NO_OTHERS, config.index - 1,
            config.avoidance)
    return command


@dataclass
class AgentController:
    """Local law of one agent with its estimator; feed it inputs, call tick() at rate_hz."""

    config: AgentConfig
    dhat: list[float] = field(default_factory=lambda: [0.0, 0.0])

    def __post_init__(self) -> None:
        self.curve: Curve | None = None
        self.curve_id: int | None = None
        self.curve_rate: Curve | None = None   # a moving curve's coefficient rate (1/s)
        self.s: float | None = None
        self.target: Point | None = None   # this agent's, carried to where it is used
        # every agent's target and its velocity on the current curve, as it held when dated,
        # and on the one before it, which converts a neighbour's error on the curve before
        # into one on this (_neighbour_error)
        self.curve_targets: _CurveTargets | None = None
        self.previous_targets: _CurveTargets | None = None
        self.pose: Pose | None = None
        self.pose_stamp: float | None = None
        self.pose_received: float | None = None   # s, this controller's clock (as every
        self.neighbours = {j: _Neighbour() for j, _ in self.config.neighbours}   # *_received)
        self.rejected = 0
        self.rejection = ''   # why the last input was rejected
        self.box = plausible_box(self.config.geofence)   # where a measured pose may lie (m)
        self.others: FloatArray = NO_OTHERS   # every robot's pose (n, 3), for the safety filter
        self.others_received: float | None = None
        # (when taken (s, this controller's clock), poses (n, 3)) of the last OTHERS_KEPT s:
        # the others' velocities, to carry them to when a late command acts (others_ahead)
        self.others_seen: deque[tuple[float, FloatArray]] = deque()
        self.filtered = 0           # ticks whose command the safety filter changed
        # when the newest news of the leader was made, our clock; the clocks of the stamps
        # it is dated by (own poses, each in-neighbour's states), and when the own pose was
        # taken by that
        self.leader_heard: float | None = None
        shared = min(self.config.pose_timeout, MAX_PREDICTION)
        self.stamp_clocks = {j: StampClock(shared) for j in (self.config.index,
                                                             *self.neighbours)}
        self.pose_dated: float | None = None
        # the last poses (stamp, when taken on this clock, pose), where the observer may
        # begin a motion that answers its estimate (_answering_start)
        self.recent_poses: deque[tuple[float, float, Pose]] = deque(maxlen=RECENT_POSES)
        self.estop = False
        self.estop_reason = 'e-stop engaged'
        self.last_command: Command = (0.0, 0.0)
        # Observer law: the pose and stamp of the previous command's tick and that tick's
        # time (s, this controller's clock); the last command where the disturbance enters
        # (before a PC-injected disturbance, else as sent) and what the safety filter changed.
        self.anchor: tuple[Pose, float, float] | None = None
        self.reference: Command = (0.0, 0.0)
        self.shift: Command = (0.0, 0.0)
        self.limited = False
        self.idle = False   # the last command's wheels all within the dead band
        # control.ray_growth's state: (factor, last right, last left wheel speed m/s)
        self.ray: tuple[float, float, float] = (1.0, 0.0, 0.0)
        # +1: the law steers the point ahead of the axle, -1: the one behind it (reversing,
        # driving.drive_direction, chosen whenever the robot's pose comes); first_pose: the
        # next pose is a new curve's first, where the choice takes the sooner way outright
        self.front = 1.0
        self.first_pose = True
        # The commands sent (Sent), as far back as a pose may be (pose_timeout) plus the
        # command latency, for predict_pose and the observer.
        longest = (max(self.config.command_latency, float(ONLINE_LAGS.max()))
                   if self.config.estimate_latency else self.config.command_latency)
        self.sent: deque[Sent] = deque(maxlen=int(math.ceil(
            self.config.rate_hz * (self.config.pose_timeout + longest))) + 2)
        # s from a command leaving to the wheels: as told, or as estimated online
        self.latency = self.config.command_latency
        self.link = (OnlineLatency(self.latency, self.config.rate_hz,
                                   self.config.motor_time_constant)
                     if self.config.estimate_latency else None)
        self.command = compiled_command(self.config) if self.config.compiled else agent_command
        # added to the command before the limits (m/s, rad/s): the config's, or as it varies
        self.pc_disturbance: Command = self.config.pc_disturbance
        # observer_order 2: how fast the estimate changes (per s)
        self.dhat_rate: tuple[float, float] = (0.0, 0.0)
        self.tracking = 0   # observer updates since the wheel limits last cut a command
        # the observer's updates so far, and when the last one's motion ended (s, this
        # controller's clock; None: none since the robot last stopped)
        self.updates = 0
        self.observed_until: float | None = None
        # when the estimate's disturbance held (s, this controller's clock): the middle of
        # the motion it was learnt from
        self.estimated_at = 0.0

    def set_curve(self, curve: Curve, curve_id: int,
                  s_all: Sequence[float] | FloatArray | None, rate: Curve | None = None,
                  received: float = 0.0, valid_at: float | None = None) -> None:
        """Adopt a new curve; raises ValueError (AssignmentError) if it breaks the assumptions.

        s_all (n,): every agent's parameter as the sender (the curve server) assigned them;
        a curve without them is refused: agents never derive s_i themselves. rate: a moving
        curve's coefficient rate (1/s), received at `received` (s, this controller's clock)
        and holding at `valid_at` (s, the sender's clock; CurveClock): the target is carried
        forward from valid_at where the two clocks agree (within leader_timeout), else from
        its receipt, for at most leader_timeout, and its velocity added to the command
        (feed_forward).
        """
        n = self.config.agent_count
        if s_all is None:
            raise AssignmentError("the curve carries no agent parameters s_i (the curve "
                                  "server's curves do)")
        if len(s_all) != n:
            raise AssignmentError(f'the curve assigns {len(s_all)} agent parameters, this '
                                  f'team has {n} agents')
        s = np.array(s_all, dtype=float)
        check_assumptions(curve.basis, s)
        self.first_pose = self.first_pose or int(curve_id) != self.curve_id
        self.curve, self.curve_id = curve, int(curve_id)
        dated = (valid_at if valid_at is not None
                 and abs(received - valid_at) <= self.config.leader_timeout else received)
        self.curve_rate = rate
        targets = _CurveTargets(int(curve_id), curve.points(s),
                                np.zeros((n, 2)) if rate is None else rate.points(s), dated)
        if self.curve_targets is not None and self.curve_targets.curve_id != targets.curve_id:
            self.previous_targets = self.curve_targets
        self.curve_targets = targets
        self.s = float(s[self.config.index - 1])
        self.target = targets.at(self.config.index, dated)

    @property
    def curve_received(self) -> float:
        """When the current curve held (s, this controller's clock; set_curve); 0 before."""
        return 0.0 if self.curve_targets is None else self.curve_targets.dated

    @property
    def ahead(self) -> Point:
        """This agent's target's velocity on the current curve (m/s; zero on a still one)."""
        if self.curve_targets is None:
            return 0.0, 0.0
        vx, vy = self.curve_targets.velocities[self.config.index - 1]
        return float(vx), float(vy)

    def _move_target(self, now: float) -> bool:
        """Carry a moving curve's target to `now` (s); False if the curve is too old."""
        if self.curve_rate is None or self.curve_targets is None:
            return True
        if now - self.curve_targets.dated > self.config.leader_timeout:
            return False
        self.target = self.curve_targets.at(self.config.index, now)
        return True

    def on_pose(self, x: float, y: float, theta: float, stamp: float,
                received: float | None = None) -> bool:
        """Own pose (arena frame) taken at `stamp` (s, its source's clock), received at
        `received` (s, this controller's clock; default: stamp). Returns False (and ignores it,
        saying why in `rejection`) if not finite or not believable (core.controller.plausibility:
        outside
        the arena and more, or further from the last pose than the robot can drive).
        """
        at = _receipt(stamp, received)
        problem = ('not finite' if not all_finite(x, y, theta, stamp, at)
                   else position_problem(x, y, self.box))
        if problem is None and self.pose is not None and self.pose_stamp is not None:
            problem = jump_problem((self.pose[0], self.pose[1], self.pose_stamp), x, y, stamp,
                                   self.config.limits.max_wheel_speed)
        if problem is not None:
            return self.reject(f'own pose {problem}')
        self.pose, self.pose_stamp, self.pose_received = (x, y, theta), stamp, at
        self.recent_poses.append((stamp, self._taken_at(stamp, at), (x, y, theta)))
        self.pose_dated = self.stamp_clocks[self.config.index].date(stamp, at)
        if self.link is not None:
            self.link.seen(self._taken_at(stamp, at), x, y, theta)
        if self.config.is_leader:
            self.leader_heard = at
        if self.config.gains.reverse and self.target is not None:   # the point steered
            self.front = drive_direction(self.front, x, y, theta, *self.target, self.dhat[0],
                                         self.dhat[1], self.config.law, self.config.limits,
                                         0.0 if self.first_pose else REVERSE_HYSTERESIS)
            self.first_pose = False
        return True

    def on_neighbour(self, j: int, ex: float, ey: float, curve_id: int, stamp: float,
                     leader_age: float | None = None, received: float | None = None) -> bool:
        """In-neighbour j's error e_j (m) w.r.t. curve_id, from its pose at `stamp` (s, its
        clock), the age of its newest news of the leader (s), received at `received` (s, this
        controller's clock; default: stamp).

        Returns False (and ignores the message, saying why in `rejection`) if j is not an
        in-neighbour, a value is not finite or the error is larger than the arena.
        """
        at = _receipt(stamp, received)
        values = (ex, ey, stamp, at) + (() if leader_age is None else (leader_age,))
        if j not in self.neighbours:
            return self.reject(f'state of agent {j}, not an in-neighbour')
        if not all_finite(*values):
            return self.reject(f'state of neighbour {j} not finite')
        problem = error_problem(ex, ey, self.box)
        if problem is not None:
            return self.reject(f'state of neighbour {j}: {problem}')
        self.neighbours[j] = _Neighbour((ex, ey), int(curve_id), stamp, at)
        if leader_age is not None:
            heard = min(at, self.stamp_clocks[j].date(stamp, at) - leader_age)   # not ahead
            if self.leader_heard is None or heard > self.leader_heard:
                self.leader_heard = heard
        return True

    def on_others(self, poses: ArrayLike, stamp: float, received: float | None = None) -> bool:
        """Every robot's pose (n, 3; arena frame; NaN rows: not seen) at `stamp` (s), received
        at `received` (s, this controller's clock; default: stamp), for the safety filter.
        Returns False (and ignores it) if it does not hold n rows.
        """
        given = np.asarray(poses, dtype=float)
        at = _receipt(stamp, received)
        if given.shape != (self.config.agent_count, 3) or not all_finite(stamp, at):
            self.rejected += 1
            return False
        # A robot not seen now keeps its last known pose: unseen, its controller stops it.
        seen = np.isfinite(given)
        if self.others is not NO_OTHERS:
            given = np.where(seen, given, self.others)
        self.others, self.others_received = given, at
        taken = self._taken_at(stamp, at)
        kept = self.others_seen
        if kept and taken <= kept[-1][0]:
            kept.clear()   # a pose older than the last: start again
        kept.append((taken, np.where(seen, given, np.nan)))
        while taken - kept[0][0] > OTHERS_KEPT:
            kept.popleft()
        return True

    def others_ahead(self, at: float) -> FloatArray:
        """Every robot's pose (n, 3) carried from when it was taken to `at` (s, this
        controller's clock) at its velocity over the last OTHERS_KEPT s (no faster than
        the wheel limit; zero for a robot not seen at both ends), for the safety filter
        when commands act a latency after they leave.
        """
        kept = self.others_seen
        if len(kept) < 2 or kept[-1][0] - kept[0][0] <= 0.0:
            return self.others
        (start, first), (end, last) = kept[0], kept[-1]
        velocity = np.nan_to_num((last[:, :2] - first[:, :2]) / (end - start))
        top = self.config.limits.max_wheel_speed
        if 0.0 < top < math.inf:
            speed = np.linalg.norm(velocity, axis=1, keepdims=True)
            velocity *= np.minimum(1.0, top / np.maximum(speed, 1e-12))
        ahead = self.others.copy()
        ahead[:, :2] += velocity * min(max(at - end, 0.0), MAX_PREDICTION + self.latency)
        return ahead

    def reject(self, why: str) -> bool:
        """Count a rejected input and keep why; False (what the on_* methods return)."""
        self.rejected += 1
        self.rejection = why
        return False

    def set_estop(self, engaged: bool, reason: str = 'e-stop engaged') -> None:
        """Engage (True) or release (False) the e-stop; `reason`: why stopped, as reported."""
        self.estop = bool(engaged)
        self.estop_reason = reason

    def state(self) -> State | None:
        """This agent's State for its out-neighbours, or None before it has pose and curve."""
        error = self.own_error()
        if (error is None or self.curve_id is None or self.pose_stamp is None
                or self.pose_dated is None):
            return None
        age = (None if self.leader_heard is None   # negative: news that came after the pose
               else max(-MAX_PREDICTION, self.pose_dated - self.leader_heard))
        return State(error, self.curve_id, self.pose_stamp, age)

    def _neighbour_error(self, j: int, nb: _Neighbour) -> Point | None:
        """Neighbour j's error on this robot's curve: as sent, or, sent on the curve before
        (j has not had the new one yet, for a tick or two after a switch), its point measured
        against its target on this curve instead (xb_j = e_j + its old target), both targets
        where they were when j's pose was taken. None if on any other curve.
        """
        if nb.curve_id == self.curve_id:
            return nb.error
        old, new = self.previous_targets, self.curve_targets
        if (old is None or new is None or nb.curve_id != old.curve_id or nb.stamp is None
                or nb.received is None):
            return None
        taken = self._taken_at(nb.stamp, nb.received)
        (ox, oy), (tx, ty) = old.at(j, taken), new.at(j, taken)
        return nb.error[0] + ox - tx, nb.error[1] + oy - ty

    def own_error(self) -> Point | None:
        """e_i = xb_i - G(s_i) xi (m) from the latest pose (a moving curve's target taken
        when the pose came), or None.
        """
        if self.pose is None or self.target is None:
            return None
        if self.pose_received is not None and self.pose_stamp is not None:
            self._move_target(self._taken_at(self.pose_stamp, self.pose_received))
        return self._error_at(self.pose, self.target)

    def _taken_at(self, stamp: float, received: float) -> float:
        """When a pose was taken (s, this controller's clock): its stamp where the pose's
        source shares this clock (the pose is 0 to min(pose_timeout, MAX_PREDICTION) s old by
        it), else its receipt.
        """
        if 0.0 <= received - stamp <= min(self.config.pose_timeout, MAX_PREDICTION):
            return stamp
        return received

    def _error_at(self, pose: Pose, target: Point) -> Point:
        bx, by = offset_point(*pose, self.front * self.config.gains.offset)
        return bx - target[0], by - target[1]

    def tick(self, now: float) -> Tick:
        """One control step at time `now` (s, this controller's clock)."""
        if self.link is not None:
            self.latency = self.link.update(now)
        tick = self._tick(now)
        self.sent.append(Sent(now, tick.v, tick.w, self.reference, self.shift, self.limited,
                              tick.stopped is None and not self.idle, self.updates))
        if self.link is not None:
            self.link.sent(now, tick.v, tick.w)
        return tick

    def predicted(self, pose: Pose, stamp: float, received: float, now: float) -> Pose:
        """The pose taken at `stamp` (received at `received`) carried forward to `now` plus
        the command latency by the commands acting since (each from its sending plus the
        latency) and the estimated drift: the robot's pose when this tick's command reaches
        its wheels (arena frame).

        The pose's age is now - stamp when that lies in [0, MAX_PREDICTION], i.e. when the
        pose's source and this controller share a clock (or are synchronised); otherwise
        only the time the pose was held here (now - received) is made up for.
        """
        cfg = self.config
        longest = min(cfg.pose_timeout, MAX_PREDICTION)
        age = now - stamp
        if not 0.0 <= age <= longest:
            age = min(max(now - received, 0.0), longest)
        start = now - age
        delay = self.latency
        law = cfg.law
        # the robot moves by its command plus the disturbance while driven (motors off at 0)
        drift_v = 0.0 if law.on_pc else law.k2 * self.dhat[0]
        drift_w = 0.0 if law.on_pc else law.k2 * self.dhat[1]
        x, y, theta = pose
        v, w, at = 0.0, 0.0, start
        for sent in self.sent:
            acts = sent.at + delay
            if acts > start:
                x, y, theta = _drive(x, y, theta, v, w, drift_v, drift_w, acts - at)
                at = acts
            v, w = sent.v, sent.w
        return _drive(x, y, theta, v, w, drift_v, drift_w, now + delay - at)

    def _tick(self, now: float) -> Tick:
        cfg = self.config
        if self.estop:
            return self._stop(self.estop_reason)
        if self.curve is None or self.target is None:
            return self._stop('no curve received yet')
        pose, stamp, received = self.pose, self.pose_stamp, self.pose_received
        if pose is None or stamp is None or received is None:
            return self._stop('no pose received yet')
        if is_stale(received, now, cfg.pose_timeout):
            return self._stop(f'own pose stale ({now - received:.2f} s old)')
        if not inside_fence(pose[0], pose[1], cfg.geofence):
            return self._stop(f'outside the geofence at ({pose[0]:.3f}, {pose[1]:.3f}) m')
        measured = pose
        aim = now   # when the target is taken: with the pose predicted, when this command acts
        if cfg.predict_pose:
            pose = self.predicted(pose, stamp, received, now)
            aim = now + self.latency
        if not self._move_target(aim):
            return self._stop(f'moving curve not renewed for {now - self.curve_received:.2f} s')
        ex, ey = self._error_at(pose, self.target)
        base = Tick(error=(ex, ey), error_stamp=stamp, curve_id=self.curve_id)
        if cfg.is_leader:
            fx, fy = leader_feedback(ex, ey)
        else:
            if is_stale(self.leader_heard, now, cfg.leader_timeout):
                return self._stop('no news from the leader yet' if self.leader_heard is None
                                  else f'no news from the leader '
                                  f'({now - self.leader_heard:.2f} s old)', base)
            errors: list[Point] = []
            for j, nb in self.neighbours.items():
                if nb.received is None:
                    return self._stop(f'no state from neighbour {j} yet', base)
                if is_stale(nb.received, now, cfg.neighbour_timeout):
                    return self._stop(f'neighbour {j} stale ({now - nb.received:.2f} s old)',
                                      base)
                error = self._neighbour_error(j, nb)
                if error is None:
                    return self._stop(f'neighbour {j} is on curve {nb.curve_id}, this robot on '
                                      f'{self.curve_id}', base)
                errors.append(error)
            fx, fy = follower_feedback(ex, ey, errors, [w for _, w in cfg.neighbours],
                                       cfg.pinning)
            base.neighbour_stamps = tuple((j, nb.stamp) for j, nb in self.neighbours.items())
        if cfg.avoidance.on and is_stale(self.others_received, now, cfg.pose_timeout):
            return self._stop('no poses of the other robots yet' if self.others_received is None
                              else f"other robots' poses stale "
                              f'({now - self.others_received:.2f} s old)', base)
        law = cfg.law
        if law.code == OBSERVER:
            self._observe()
        ahead = (0.0, 0.0)
        if cfg.feed_forward:
            # the part of this command's period (from when it acts) in which the target moves:
            # all of it, except for a curve announced before it begins to move
            period = 1.0 / cfg.rate_hz
            moving = min(max((aim + period - self.curve_received) / period, 0.0), 1.0)
            ahead = (self.ahead[0] * moving, self.ahead[1] * moving)
        dhat_v, dhat_w = self.dhat
        if cfg.observer_order == 2 and self.tracking >= TRACKING_TICKS:
            # the estimate carried from the middle of the motion it was learnt from (a pose's
            # age counts) to the middle of the period this command holds for, once it acts
            period = 1.0 / cfg.rate_hz
            acts = now + self.latency + period / 2.0
            ahead_by = min(max(acts - self.estimated_at, 0.0),
                           period + self.latency + MAX_PREDICTION)
            dhat_v += self.dhat_rate[0] * ahead_by
            dhat_w += self.dhat_rate[1] * ahead_by
        v, w, ref_v, ref_w, ddv, ddw, code, shift_v, shift_w, limited = self.command(
            fx, fy, *ahead, ex, ey, *pose, dhat_v, dhat_w, *self.last_command,
            *self.pc_disturbance, steered_law(law, self.front), cfg.limits,
            self.others_ahead(aim) if cfg.predict_pose and self.latency > 0.0 else self.others,
            cfg.index - 1, with_latency(cfg.avoidance, 1.0 / cfg.rate_hz, self.latency))
        if law.code != OBSERVER:
            self.dhat[0] += law.period * ddv
            self.dhat[1] += law.period * ddw
        if code == STOPPED:
            return self._stop('safety filter: no motion keeps the robots apart', base)
        self.filtered += code != 0
        self.anchor = (measured, stamp, now)
        self.reference = self._dead_band_reference(v, w, ref_v, ref_w)
        self.shift = (shift_v, shift_w)
        self.limited = limited
        self.last_command = (v, w)
        base.v, base.w, base.dhat, base.feedback = v, w, (self.dhat[0], self.dhat[1]), (fx, fy)
        base.pose = pose
        base.filtered = code != 0
        return base

    def _dead_band_reference(self, v: float, w: float, ref_v: float, ref_w: float
                             ) -> Command:
        """The observer's reference for the command (v, w) sent: with a dead band
        (min_wheel_speed), less what the wheels commanded below it will not do, so that a
        robot standing still under a command too small to move it is not taken for a
        disturbance holding it back. Both wheels in the band: the motors are idle (nothing is
        learnt from that period, as when stopped).
        """
        cfg = self.config
        self.idle = False
        if cfg.min_wheel_speed <= 0.0 or cfg.limits.wheel_base <= 0.0:
            return ref_v, ref_w
        left, right = wheel_speeds(v, w, cfg.limits.wheel_base)
        still_right = abs(right) < cfg.min_wheel_speed
        still_left = abs(left) < cfg.min_wheel_speed
        self.idle = still_right and still_left
        moved_v, moved_w = body_from_wheels(0.0 if still_left else left,
                                        0.0 if still_right else right, cfg.limits.wheel_base)
        return ref_v + moved_v - v, ref_w + moved_w - w

    def _acting(self, at: float) -> Sent | None:
        """The command acting on the robot at `at` (s, this controller's clock): the last
        sent a command latency or more before; None if none is known.
        """
        acting = None
        for sent in self.sent:
            if sent.at > at - self.latency + 1e-9:
                break
            acting = sent
        return acting

    def _observe(self) -> None:
        """Observer law: move dhat towards (motion measured since the last tick - command) / k2.

        The motion is the constant (v, w) that carries the previous tick's pose to the current
        one over the difference of their stamps; the command is the one sent at the previous
        tick, or with a command latency, a motor time constant or a motion that began before
        the previous tick (a pose older than the time between poses) what the commands
        realised over that motion (_realised); nothing is learnt while the motors were off.
        With a command latency, or a pose taken before the previous tick (a camera's frame
        older than a period), the observer waits for a motion made wholly under commands sent
        after its last update (their `estimate`), and blends over the time since that update:
        no delay enters the estimate's loop (docs/control-laws.md). The motion's part before
        the safety filter (the motion minus what the filter changed) is scaled along its ray
        when saturated (control.ray_growth); without a newer pose nothing is updated.
        """
        if (self.anchor is None or self.pose is None or self.pose_stamp is None
                or self.pose_received is None):
            return
        (x0, y0, th0), stamp0, ticked = self.anchor
        elapsed = self.pose_stamp - stamp0
        if elapsed <= 0.0:
            return
        ended = self._taken_at(self.pose_stamp, self.pose_received)   # the motion's end
        # A pose taken before the last tick cannot show that tick's command: waiting for one
        # that can keeps the pose's age out of the estimate's loop as it keeps the latency.
        waits = self.latency > 0.0 or ended < ticked
        acting = self._commanded(elapsed, ended, ticked, waits)
        if acting is None or not acting.driven:
            return
        if waits and acting.estimate < self.updates:
            # the motion does not answer the current estimate yet: its part from the first
            # pose that can, if one is held
            later = self._answering_start(ended - elapsed, ended)
            if later is None:
                return
            (x0, y0, th0), stamp0 = later
            elapsed = self.pose_stamp - stamp0
            acting = self._commanded(elapsed, ended, ticked, waits)
            if acting is None or not acting.driven or acting.estimate < self.updates:
                return
        measured_v, measured_w = measured_velocity(x0, y0, th0, *self.pose, elapsed)
        self.estimated_at = ended - elapsed / 2.0
        if waits and self.observed_until is not None:   # blended over the time since the last
            elapsed = max(elapsed, ended - self.observed_until)
        self.observed_until = ended
        blend = 1.0 - math.exp(-self.config.gains.observer_rate * elapsed)
        second = self.config.observer_order == 2
        rate_v, rate_w = self.dhat_rate
        before = ((self.dhat[0] + rate_v * elapsed, self.dhat[1] + rate_w * elapsed) if second
                  else (self.dhat[0], self.dhat[1]))
        dhat_v, dhat_w, *ray = observe(*before, *self.ray, measured_v,
                                       measured_w, *acting.reference, *acting.shift,
                                       acting.limited, self.config.law, self.config.limits, blend)
        if second:
            searching = acting.limited or ray[0] != 1.0
            self.dhat_rate = _rate_update(self.dhat_rate, before, (dhat_v, dhat_w), blend,
                                          elapsed, searching)
            self.tracking = 0 if searching else self.tracking + 1
        self.dhat[:] = (dhat_v, dhat_w)
        self.ray = (ray[0], ray[1], ray[2])
        self.updates += 1

    def _commanded(self, elapsed: float, ended: float, ticked: float, waits: bool
                   ) -> Sent | None:
        """What was commanded over the motion of `elapsed` s ending at `ended` (s, this
        controller's clock) that the observer measures at the tick after `ticked`.
        """
        # A motion that began before the last tick (its first pose older than that tick) was
        # partly made under the command before: the commands are weighed by how long each
        # acted in it, and whether the limits cut is the last tick's command's, as when the
        # motion is wholly its own (the search along its ray is that command's).
        mixed = ended - elapsed < ticked - 1e-9
        if self.config.motor_time_constant > 0.0 or waits:
            return self._realised(elapsed)
        if mixed:
            acting, last = self._realised(elapsed), self._acting(ticked)
            if acting is not None and last is not None:
                acting = acting._replace(limited=last.limited)
            return acting
        return self._acting(ticked)

    def _answering_start(self, begins: float, ends: float) -> tuple[Pose, float] | None:
        """A later start (pose, stamp) for a motion from `begins` to `ends` (s, this
        controller's clock) that began before the first command sent after the observer's
        last update acted: the first pose taken from then on, at least MIN_OBSERVED before
        the end; None if the motion needs none or no such pose is held.
        """
        answering = next((sent.at + self.latency for sent in self.sent
                          if sent.estimate >= self.updates), None)
        if answering is None or begins >= answering - 1e-9:
            return None
        for stamp, taken, pose in self.recent_poses:
            if taken >= answering - 1e-9:
                return (pose, stamp) if taken <= ends - MIN_OBSERVED else None
        return None

    def _realised(self, elapsed: float) -> Sent | None:
        """What the wheels did on average over the `elapsed` s up to the current pose: the
        commands sent, each acting from its sending plus command_latency, through the motors'
        first-order lag (motor_time_constant), as a Sent (reference and shift averaged;
        limited if any was; driven only if all were); None if the commands sent do not reach
        back that far.

        The interval ends when the pose was taken, on this controller's clock: its stamp
        where the pose source shares the clock (an age within MAX_PREDICTION), else when it
        was received.
        """
        assert self.pose_stamp is not None and self.pose_received is not None
        cfg = self.config
        tau, delay = cfg.motor_time_constant, self.latency
        end = self._taken_at(self.pose_stamp, self.pose_received)
        begin = end - elapsed
        sent = list(self.sent)
        if not sent or sent[0].at + delay > begin:
            return None
        lag = np.array([*sent[0].reference, *sent[0].shift])   # the wheels' state
        total = np.zeros(4)
        limited, driven, estimate = False, True, self.updates
        for k, command in enumerate(sent):
            start = command.at + delay
            if start >= end:
                break
            stop = min(sent[k + 1].at + delay, end) if k + 1 < len(sent) else end
            target = np.array([*command.reference, *command.shift])
            before = min(max(begin, start), stop)   # the part before the interval
            span = stop - before
            if tau > 0.0:
                lag = target + (lag - target) * math.exp(-(before - start) / tau)
            if span <= 0.0:
                continue
            if tau > 0.0:
                decay = math.exp(-span / tau)
                total += target * span + (lag - target) * tau * (1.0 - decay)
                lag = target + (lag - target) * decay
            else:   # no lag: each command for the time it acts
                total += target * span
            limited = limited or command.limited
            driven = driven and command.driven
            estimate = min(estimate, command.estimate)
        mean = total / elapsed
        return Sent(end, 0.0, 0.0, (float(mean[0]), float(mean[1])),
                    (float(mean[2]), float(mean[3])), limited, driven, estimate)

    def _stop(self, reason: str, base: Tick | None = None) -> Tick:
        tick = base or Tick()
        self.anchor = None
        self.observed_until = None
        self.reference = self.shift = (0.0, 0.0)
        self.limited = False
        self.ray = (1.0, 0.0, 0.0)
        tick.v, tick.w, tick.stopped = 0.0, 0.0, reason
        tick.dhat = (self.dhat[0], self.dhat[1])
        self.last_command = (0.0, 0.0)
        return tick
