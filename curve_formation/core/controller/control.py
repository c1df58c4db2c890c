"""The paper's leader/follower law, disturbance estimator and wheel limits.

Frames and units: poses (x, y, theta) in the arena frame (metres, radians); the offset point
xb = (x + l cos theta, y + l sin theta) with offset l (metres, l != 0); commands u = (v, w) in the
robot frame (m/s, rad/s); the disturbance estimate dhat is in the same units as u.

The per-agent functions below use only scalar math so that the same source runs in the ROS
controller node (plain Python) and inside the batch simulator's compiled kernel (numba).
"""

from collections.abc import Sequence
import dataclasses
from dataclasses import dataclass
import math
from typing import NamedTuple

import numpy as np

from curve_formation.core.base.shapes import Command, FloatArray, Point
from curve_formation.core.controller.safety import (
    ADJUSTED,
    Avoidance,
    safe_command,
    shaped_feedback,
)
from curve_formation.core.formation.dynamics import chord_ratio


# Disturbance estimators, by name in the experiment YAML (`controller.law`) and by code in the
# compiled simulator.
LAWS = {'paper': 0, 'adaptive': 1, 'observer': 2}
OBSERVER = LAWS['observer']
# Share of the wheel and turn-rate limits the observer law's feedback may use (observer_input)
# where the disturbance is added on the PC, before the limits, so that once d is learnt the
# command it adds up to is not clipped (a clipped command moves the robot alike for a whole
# ray of estimates); with it on the robot the feedback may use the whole limits. 0.98: the
# observer's search (ray_growth) starts only where the limits cut the command (by more than
# RAY_CLIPPED), which the pipeline knows when it computes it (docs/control-laws.md).
FEEDBACK_HEADROOM = 0.98
# The observer's search along a saturated motion's ray (ray_growth) starts on a command the
# wheel limits cut by more than the factor RAY_CLIPPED: a d not yet learnt goes far past
# them (20x in the paper's arena), while camera noise in the estimate of a learnt d takes a
# command at FEEDBACK_HEADROOM only a few % past them (mona_arena seed 3 through the fake
# camera: with any cut counted, 43.3 s against 22.2 s simulated). Two clipped motions lie
# along one ray when their wheel speeds point within acos(RAY_ALIGNED) (18 degrees) of each
# other; each such motion doubles the growth (RAY_GROWTH), a reversal shrinks it by
# RAY_SHRINK.
RAY_CLIPPED = 1.05
RAY_ALIGNED = 0.95
RAY_SHRINK = 0.25
RAY_GROWTH = 2.0


@dataclass(frozen=True)
class Gains:
    """The law and its gains.

    k1 (1/s) on the target error, k2 on the estimate, offset l (m) of the control point.
    law: 'paper' (dhat' = k2 R^T e), 'adaptive' (the same with per-channel gains
    `adaptation` = (gamma_v, gamma_w) multiplying each channel's rate) or 'observer' (dhat
    tracks the measured body velocity minus the command, over k2, at `observer_rate` (1/s)).
    sampled_heading: under a zero-order hold, turn as the continuous law would over one
    period (sampled_feedback) instead of holding its instantaneous turn rate.
    tail_radius (m; 0: off), tail_gain: the finite-time tail (tail_feedback).
    reverse: a robot may drive backwards, steering the point behind its axle
    (core.controller.driving), when that reaches its target sooner.
    observer_growth: law observer with the disturbance added on the PC: the largest factor
    of ray_growth's search along a saturated motion (1: off).
    """

    k1: float
    k2: float
    offset: float
    law: str = 'paper'
    adaptation: tuple[float, float] = (1.0, 1.0)
    observer_rate: float = 5.0
    sampled_heading: bool = False
    tail_radius: float = 0.0
    tail_gain: float = 1.0
    reverse: bool = False
    observer_growth: float = 1.0

    @property
    def law_code(self) -> int:
        return LAWS[self.law]

    def paper_law(self) -> 'Gains':
        """These gains with the paper's reference law (its estimator, its heading command)."""
        return dataclasses.replace(self, law='paper', sampled_heading=False)

    def hold_period(self, rate_hz: float | None) -> float:
        """The `period` argument of agent_input at this rate (Hz; None = continuous): the
        control period with the sampled heading under a zero-order hold, else 0.
        """
        return 1.0 / rate_hz if self.sampled_heading and rate_hz else 0.0

    def estimator_gains(self) -> tuple[float, float]:
        """(gamma_v, gamma_w): per-channel multipliers of the paper's estimator rate."""
        return self.adaptation if self.law == 'adaptive' else (1.0, 1.0)

    def tick_law(self, rate_hz: float | None, on_pc: bool = False) -> 'Law':
        """The Law of one control tick at rate_hz (None: continuous control)."""
        gamma_v, gamma_w = self.estimator_gains()
        return Law(self.law_code, self.k1, self.k2, self.offset, gamma_v, gamma_w,
                   self.hold_period(rate_hz), 1.0 / rate_hz if rate_hz else 0.0,
                   self.observer_rate, on_pc, self.tail_radius, self.tail_gain, self.reverse,
                   self.observer_growth)


class Law(NamedTuple):
    """Gains as agent_command takes them (one argument, also inside the compiled simulator).

    code: LAWS; k1 (1/s), k2, offset l (m), per-channel estimator gains, hold: the period of
    the sampled heading (s; 0: the paper's heading), period: the control period (s; 0:
    continuous), observer_rate (1/s), on_pc: the disturbance is added on the PC,
    tail_radius (m), tail_gain: tail_feedback's, reverse: driving.drive_direction may
    choose to drive backwards, max_growth: ray_growth's largest factor (1: off).
    """

    code: int
    k1: float
    k2: float
    offset: float
    gamma_v: float
    gamma_w: float
    hold: float
    period: float
    observer_rate: float
    on_pc: bool
    tail_radius: float
    tail_gain: float
    reverse: bool
    max_growth: float


class WheelLimits(NamedTuple):
    """Differential drive: wheel base (m), max wheel speed (m/s), optional max turn rate
    (rad/s) and acceleration limits (m/s^2, rad/s^2). 0 or infinity means unlimited.
    """

    wheel_base: float = 0.0
    max_wheel_speed: float = math.inf
    max_angular_rate: float = math.inf
    max_linear_accel: float = math.inf
    max_angular_accel: float = math.inf


NO_LIMITS = WheelLimits()


def timed_by(limits: WheelLimits) -> bool:
    """True when the wheel limits time a trip and can saturate a command (a wheel base and a
    finite wheel speed limit): driving.drive_direction needs them to choose between forwards
    and backwards, ray_growth to tell a saturated motion.
    """
    return limits.wheel_base > 0.0 and 0.0 < limits.max_wheel_speed < math.inf


def agent_command(fx: float, fy: float, ahead_x: float, ahead_y: float, ex: float,
                  ey: float, x: float, y: float,
                  theta: float, dhat_v: float, dhat_w: float, prev_v: float, prev_w: float,
                  pc_v: float, pc_w: float, law: 'Law', limits: 'WheelLimits',
                  others: FloatArray, me: int, avoidance: Avoidance
                  ) -> tuple[float, float, float, float, float, float, int, float, float, bool]:
    """One control tick of one agent, from its inputs to the command sent: the one pipeline
    the ROS controller (core.controller.agent) and the batch simulator both run.

    fx, fy: feedback (m; follower_feedback or leader_feedback); ahead: the target's velocity
    on a moving curve (m/s; the feed-forward, with_feed_forward; 0 otherwise); ex, ey: own
    target error (m); x, y, theta: own pose; dhat: estimate; prev: the previous command sent
    (for the acceleration limits); pc: disturbance added on the PC (the paper's arena
    experiment); law: Law; limits: WheelLimits; others (n, 3), me, avoidance:
    safety.safe_command's. The finite-time tail, the feed-forward, the feedback shaped
    around robots and walls nearby, the law, then PC disturbance, acceleration and wheel
    limits, then the safety filter.
    Returns (v, w, ref_v, ref_w, ddhat_v, ddhat_w, code, shift_v, shift_w, limited): the
    command, what the observer compares the measured motion with (the law's command where
    the disturbance enters, plus what the filter changed), the continuous-time estimator
    rate (paper and adaptive laws), the filter's outcome (safety.UNCHANGED, ADJUSTED,
    STOPPED), what the filter changed (m/s, rad/s: the measured motion minus it is the
    motion before the filter, which ray_growth searches along) and, with the disturbance
    added on the PC, whether the wheel limits cut the command before the filter by more
    than RAY_CLIPPED (ray_growth searches only then; False otherwise).
    """
    fx, fy = tail_feedback(fx, fy, law.tail_radius, law.tail_gain)
    fx, fy = with_feed_forward(fx, fy, ahead_x, ahead_y, law.k1)
    free_x, free_y = fx, fy
    fx, fy = shaped_feedback(fx, fy, x, y, others, me, law.k1, limits.max_wheel_speed,
                             avoidance)
    # Saturated, the law turns in place first (the fastest way to a point), unless the
    # shaped feedback turns it back to give way: a robot that turned round in place each
    # time it gave way and each time it headed on again would stand still (head-on meeting);
    # there it keeps the law's curvature and slides past while turning. With the
    # disturbance added on the PC, only while the command it adds up to is not clipped (d
    # learnt): a turn in place clipped at the limits is a saturated ray along which the
    # observer's search (ray_growth) winds its turn channel up.
    turn_first = fx * free_x + fy * free_y > 0.0
    # The robot drifts by the estimated disturbance unless it is added on the PC (then the
    # command already carries it).
    drift_v = 0.0 if law.on_pc else law.k2 * dhat_v
    drift_w = 0.0 if law.on_pc else law.k2 * dhat_w
    if law.code == OBSERVER:
        room = FEEDBACK_HEADROOM if law.on_pc else 1.0
        u_v, u_w = observer_input(fx, fy, theta, dhat_v, dhat_w, law.k1, law.k2, law.offset,
                                  law.hold, limits.wheel_base, room * limits.max_wheel_speed,
                                  room * limits.max_angular_rate, drift_v, drift_w,
                                  turn_first)
        if turn_first and law.on_pc and clipped(u_v + pc_v, u_w + pc_w, limits):
            u_v, u_w = observer_input(fx, fy, theta, dhat_v, dhat_w, law.k1, law.k2,
                                      law.offset, law.hold, limits.wheel_base,
                                      room * limits.max_wheel_speed,
                                      room * limits.max_angular_rate, drift_v, drift_w, False)
        ddhat_v = 0.0
        ddhat_w = 0.0
    else:
        u_v, u_w, ddhat_v, ddhat_w = agent_input(fx, fy, ex, ey, theta, dhat_v, dhat_w, law.k1,
                                                 law.k2, law.offset, law.gamma_v, law.gamma_w,
                                                 law.hold)
    v, w = limit_acceleration(u_v + pc_v, u_w + pc_w, prev_v, prev_w, law.period,
                              limits.max_linear_accel, limits.max_angular_accel)
    # The wheel limits come last: whatever the ramp, no wheel exceeds its speed limit.
    limited = law.on_pc and clipped(v, w, limits, RAY_CLIPPED)   # ray_growth's only use
    v, w = saturate(v, w, limits.wheel_base, limits.max_wheel_speed, limits.max_angular_rate)
    safe_v, safe_w, code = safe_command(v, w, x, y, theta, drift_v, drift_w, others, me,
                                        law.offset, law.period, avoidance, limits.wheel_base,
                                        limits.max_wheel_speed, limits.max_angular_rate)
    if code == ADJUSTED:   # within the limits already, up to round-off
        safe_v, safe_w = saturate(safe_v, safe_w, limits.wheel_base, limits.max_wheel_speed,
                                  limits.max_angular_rate)
    ref_v = (u_v if law.on_pc else v) + (safe_v - v)
    ref_w = (u_w if law.on_pc else w) + (safe_w - w)
    return safe_v, safe_w, ref_v, ref_w, ddhat_v, ddhat_w, code, safe_v - v, safe_w - w, limited


def clipped(v: float, w: float, limits: WheelLimits, by: float = 1.0) -> bool:
    """True when the command (v, w) (m/s, rad/s) goes past the wheel limits by more than the
    factor `by` (1: the limits change it at all).
    """
    v, w = v / by, w / by
    sv, sw = saturate(v, w, limits.wheel_base, limits.max_wheel_speed, limits.max_angular_rate)
    return sv != v or sw != w


def tail_feedback(fx: float, fy: float, radius: float, gain: float) -> Point:
    """The feedback (m) scaled up near the target, so the approach ends in finite time.

    Within `radius` (m) of zero the feedback f is multiplied by sqrt(radius / |f|), capped
    at `gain`: the law's speed k1 |f| becomes k1 sqrt(radius |f|) (the finite-time shape
    |f|^1/2 of Bhat and Bernstein) down to |f| = radius / gain^2, then linear again at
    gain k1, so a sampled command cannot chatter (k1 gain period < 1, config_schema).
    Outside radius, or with radius 0, f is returned unchanged (the paper's exponential
    approach, rate k1).
    """
    size = math.hypot(fx, fy)
    if radius <= 0.0 or size >= radius or size == 0.0:
        return fx, fy
    scale = min(gain, math.sqrt(radius / size))
    return scale * fx, scale * fy


def offset_point(x: float, y: float, theta: float, offset: float) -> Point:
    """Offset control point xb (m) ahead of the axle centre by `offset` along the heading."""
    return x + offset * math.cos(theta), y + offset * math.sin(theta)


def agent_input(fx: float, fy: float, ex: float, ey: float, theta: float, dhat_v: float,
                dhat_w: float, k1: float, k2: float, offset: float, gamma_v: float = 1.0,
                gamma_w: float = 1.0, period: float = 0.0
                ) -> tuple[float, float, float, float]:
    """One agent's command and adaptive estimator rate.

    Args:
        fx, fy: feedback term: e_i for the leader, sum_j a_ij (e_i - e_j) for a follower (m).
        ex, ey: own target error e_i = xb_i - G(s_i) xi (m), arena frame.
        theta: heading (rad).
        dhat_v, dhat_w: disturbance estimate.
        gamma_v, gamma_w: per-channel adaptation gains (1, 1 is the paper's estimator).
        period: control period (s) of a zero-order hold for the sampled heading (see
            sampled_feedback); 0 gives the paper's continuous-time u = R^-1 ub.
    Returns:
        (v, w, ddhat_v, ddhat_w): u = R^-1 ub with ub = -k1 f - k2 R dhat, and the estimator
        rate dhat' = k2 Gamma R^T e.
    """
    c = math.cos(theta)
    s = math.sin(theta)
    if period > 0.0:
        v, w = sampled_feedback(-k1 * (c * fx + s * fy), -k1 * (-s * fx + c * fy), offset,
                                period)
    else:
        v = -k1 * (c * fx + s * fy)
        w = -k1 * (-s * fx + c * fy) / offset
    v -= k2 * dhat_v
    w -= k2 * dhat_w
    return (v, w, gamma_v * k2 * (c * ex + s * ey),
            gamma_w * k2 * offset * (-s * ex + c * ey))


def sampled_feedback(along: float, across: float, offset: float, period: float) -> Command:
    """The feedback part of u = R^-1 ub for a command held over `period` (s).

    along, across: ub (m/s) in the body frame. In continuous time the paper's law turns the
    heading so that the angle a between heading and ub obeys a' = -(|ub| / l) sin a. With
    l = 0.01 and a 0.1 s hold that loop overshoots (|ub| T / l >> 2). Here w is the turn that
    the continuous law would make over the period, from the closed form
    tan(a(T) / 2) = tan(a(0) / 2) exp(-|ub| T / l), so it never overshoots, and v = |ub| cos a
    at the mid-period heading. As period -> 0 both tend to the paper's (along, across / l).
    Returns (v, w) (m/s, rad/s).
    """
    speed = math.hypot(along, across)
    if speed == 0.0:
        return 0.0, 0.0
    angle = math.atan2(across, along)
    if offset < 0.0:   # a negative offset faces the robot away from ub
        angle = math.atan2(math.sin(angle + math.pi), math.cos(angle + math.pi))
    decay = math.exp(-speed * period / abs(offset))
    end = 2.0 * math.atan2(math.sin(0.5 * angle) * decay, math.cos(0.5 * angle))
    turned = angle - end
    v = speed * math.cos(angle - 0.5 * turned)
    if offset < 0.0:
        v = -v
    return v, turned / period


def observer_input(fx: float, fy: float, theta: float, dhat_v: float, dhat_w: float,
                   k1: float, k2: float, offset: float, period: float, wheel_base: float,
                   max_wheel_speed: float, max_angular_rate: float, drift_v: float = 0.0,
                   drift_w: float = 0.0, turn_first: bool = True) -> Command:
    """The observer law's command (m/s, rad/s): feedback within the limits given, minus k2 dhat.

    The feedback part of agent_input (fx, fy, period as there) is saturated before the
    compensation is subtracted, so that a command saturated by the limits is never mistaken
    for a disturbance: at dhat = d / k2 the robot moves exactly as the saturated feedback asks.
    The feedback is the robot's motion; the limits bound the command, which is that motion
    minus the drift (drift_v, drift_w: k2 dhat where the disturbance acts on the robot, so a
    robot drifting forwards may move forwards faster than its wheels alone; 0 where it is
    added on the PC, which cancels the compensation). Saturated, it turns first
    (saturate_turning) or, with turn_first False, keeps its curvature (saturate).
    agent_command passes FEEDBACK_HEADROOM of the wheel limits where the disturbance is added
    before them (on the PC): a feedback on the limit would then move the robot the same for a
    whole ray of estimates, along which the estimate drifts. With the disturbance on the robot
    the observer compares the motion with the command actually sent, and the feedback may use
    the whole limits.
    """
    v, w, _, _ = agent_input(fx, fy, 0.0, 0.0, theta, 0.0, 0.0, k1, k2, offset, 1.0, 1.0,
                             period)
    if turn_first:
        v, w = saturate_turning(v, w, drift_v, drift_w, wheel_base, max_wheel_speed,
                                max_angular_rate)
    else:
        v, w = saturate_drifting(v, w, drift_v, drift_w, wheel_base, max_wheel_speed,
                                 max_angular_rate)
    return v - k2 * dhat_v, w - k2 * dhat_w


def saturate_drifting(v: float, w: float, drift_v: float, drift_w: float, wheel_base: float,
                      max_wheel_speed: float, max_angular_rate: float) -> Command:
    """The motion (v, w) (m/s, rad/s) whose command, the motion minus the drift (drift_v,
    drift_w), is scaled down into the limits (saturate): the curvature of the command kept.
    """
    cv, cw = saturate(v - drift_v, w - drift_w, wheel_base, max_wheel_speed, max_angular_rate)
    return cv + drift_v, cw + drift_w


# Share of the law's turn saturate_turning keeps (at least): the sampled heading asks for
# most of the heading error in one tick, which a command 2 ticks late would overshoot.
TURN_SHARE = 0.25


def saturate_turning(v: float, w: float, drift_v: float, drift_w: float, wheel_base: float,
                     max_wheel_speed: float, max_angular_rate: float) -> Command:
    """The motion (v, w) (m/s, rad/s) within the limits, turning first.

    The command is the motion minus the drift (drift_v, drift_w); the limits bound the
    command: |v_c| + |w_c| B / 2 <= max wheel speed and |w_c| <= max turn rate. A motion
    within them is returned as it is. Otherwise TURN_SHARE of the motion's turn (or what
    scaling down would keep, if more) is kept, its command at most the wheels' turn with no
    forward command, and the speed gets what the wheels have left: a robot far from facing
    its target turns in place (carried along only by drift_v) at the wheels' limit and then
    drives straight, the fastest way a differential drive with bounded wheel speeds has to a
    point (Balkcom and Mason, IJRR 2002), where scaling (v, w) down together (saturate) keeps
    the curvature and drives a wide arc. The share is of the motion's turn, not of the
    command's: a quarter of a command that also cancels a turn drift against the turn could
    leave no turn at all. A drift the wheels cannot cancel standing still: saturate.
    """
    fast = 0.0 < max_wheel_speed < math.inf
    turn = 0.0 < max_angular_rate < math.inf
    half = 0.5 * wheel_base
    cv, cw = v - drift_v, w - drift_w
    if ((not fast or abs(cv) + abs(cw) * half <= max_wheel_speed)
            and (not turn or abs(cw) <= max_angular_rate)):
        return v, w
    top = math.inf
    if fast:
        if abs(drift_v) >= max_wheel_speed or half <= 0.0:
            return saturate_drifting(v, w, drift_v, drift_w, wheel_base, max_wheel_speed,
                                     max_angular_rate)
        top = max_wheel_speed / half
    if turn:
        top = min(top, max_angular_rate)
    _, sw = saturate(cv, cw, wheel_base, max_wheel_speed, max_angular_rate)
    kept = TURN_SHARE * w   # of the motion's turn, not the command's (which cancels drift_w)
    if (sw + drift_w) * w > 0.0 and abs(sw + drift_w) > abs(kept):
        kept = sw + drift_w   # what scaling down would keep, if more
    cw = min(max(kept - drift_w, -top), top)
    if fast:
        room = max_wheel_speed - abs(cw) * half
        cv = min(max(cv, -room), room)
    return cv + drift_v, cw + drift_w


def observer_step(dhat_v: float, dhat_w: float, measured_v: float, measured_w: float,
                  ref_v: float, ref_w: float, k2: float, blend: float) -> tuple[float, float]:
    """One update of the disturbance observer: move dhat towards (measured - ref) / k2.

    measured: body velocity (m/s, rad/s) over the last control period; ref: the command the
    law sent for it (before any disturbance injected on the PC); blend in [0, 1]: the share
    of the way moved, 1 - exp(-observer_rate * period). k2 = 0 turns the estimator off, as
    with the other laws. Returns the new (dhat_v, dhat_w).
    """
    if k2 == 0.0:
        return dhat_v, dhat_w
    return (dhat_v + blend * ((measured_v - ref_v) / k2 - dhat_v),
            dhat_w + blend * ((measured_w - ref_w) / k2 - dhat_w))


def ray_growth(growth: float, last_right: float, last_left: float, measured_v: float,
               measured_w: float, limited: bool, law: 'Law', limits: 'WheelLimits'
               ) -> tuple[float, float, float]:
    """The factor by which the observer takes this tick's measured motion (observer_step),
    for a disturbance d added on the PC, before the wheel limits (law.on_pc).

    A command clipped by the wheel limits moves the robot at the limit in the direction of
    the law's command plus d: the motion shows d's direction, not its size (d lies on the ray
    s * measured - reference, s >= 1), and observer_step, taking s = 1, moves the estimate at
    most the limits' width a tick (in the paper's arena d is 20x the limit). While the
    commands stay clipped and their motions lie along one ray, the factor s grows by
    RAY_GROWTH each update (doubles) up to
    law.max_growth (a search along the ray); a reversal (the estimate overshot) divides it by
    1 / RAY_SHRINK; a command the limits did not cut by more than RAY_CLIPPED resets it to 1.
    Off (always 1) with
    law.max_growth <= 1, without law.on_pc, or without wheel limits that can saturate
    (timed_by).

    growth: last tick's factor; last_right, last_left: last tick's measured wheel speeds
    (m/s) when clipped, else 0; measured: body velocity (m/s, rad/s) under the command
    whose `limited` (agent_command: the wheel limits cut it by more than RAY_CLIPPED) is
    given. Whether a command was cut is known when it is computed; the measured motion's
    size is not a sure sign of it (a feedback at 98 % of the limits measured through a
    camera reaches 99 %). Returns (factor, right, left): this tick's factor and the values
    of last_right, last_left for the next.
    """
    if law.max_growth <= 1.0 or not law.on_pc or not timed_by(limits):
        return 1.0, 0.0, 0.0
    if not limited:
        return 1.0, 0.0, 0.0
    right, left = wheel_speeds(measured_v, measured_w, limits.wheel_base)
    if last_right != 0.0 or last_left != 0.0:
        cosine = ((right * last_right + left * last_left)
                  / math.sqrt((right * right + left * left)
                              * (last_right * last_right + last_left * last_left)))
        if cosine > RAY_ALIGNED:
            growth = min(law.max_growth, RAY_GROWTH * growth)
        elif cosine < 0.0:
            growth = max(1.0, RAY_SHRINK * growth)
    return growth, right, left


def observe(dhat_v: float, dhat_w: float, growth: float, last_right: float, last_left: float,
            measured_v: float, measured_w: float, ref_v: float, ref_w: float, shift_v: float,
            shift_w: float, limited: bool, law: 'Law', limits: 'WheelLimits', blend: float
            ) -> tuple[float, float, float, float, float]:
    """The observer's update at a tick, as the node and the simulator both make it: the
    measured motion's part before the safety filter (measured minus shift, what the filter
    changed in the last command) searched along its ray (ray_growth: growth, last_right,
    last_left; limited: the wheel limits cut the command the motion was measured under by
    more than RAY_CLIPPED), then observer_step towards that scaled motion plus the shift
    against the reference (agent_command's ref). Returns (dhat_v, dhat_w, growth,
    last_right, last_left).
    """
    pre_v = measured_v - shift_v
    pre_w = measured_w - shift_w
    growth, last_right, last_left = ray_growth(growth, last_right, last_left, pre_v, pre_w,
                                               limited, law, limits)
    dhat_v, dhat_w = observer_step(dhat_v, dhat_w, growth * pre_v + shift_v,
                                   growth * pre_w + shift_w, ref_v, ref_w, law.k2, blend)
    return dhat_v, dhat_w, growth, last_right, last_left


def body_velocity(x0: float, y0: float, theta0: float, x1: float, y1: float, theta1: float,
                  dt: float) -> Command:
    """Constant (v, w) (m/s, rad/s) that moves a unicycle from pose 0 to pose 1 in dt (s).

    Exact for an arc (the inverse of dynamics.arc_step); the heading change must be below
    pi over dt. The sign of v follows the chord's direction relative to the mean heading.
    """
    turn = math.atan2(math.sin(theta1 - theta0), math.cos(theta1 - theta0))
    mid = theta0 + 0.5 * turn
    along = (x1 - x0) * math.cos(mid) + (y1 - y0) * math.sin(mid)
    return along / (dt * chord_ratio(0.5 * turn)), turn / dt


def saturate(v: float, w: float, wheel_base: float, max_wheel_speed: float,
             max_angular_rate: float) -> Command:
    """Scale (v, w) down so both wheel speeds and |w| are within limits, keeping curvature w/v.

    Wheel speeds are v -+ w * wheel_base / 2 (m/s). Returns the scaled (v, w).
    """
    scale = 1.0
    if max_wheel_speed > 0.0 and max_wheel_speed < math.inf:
        fastest = abs(v) + abs(w) * 0.5 * wheel_base
        if fastest > max_wheel_speed:
            scale = max_wheel_speed / fastest
    if max_angular_rate > 0.0 and max_angular_rate < math.inf:
        if abs(w) * scale > max_angular_rate:
            scale = max_angular_rate / abs(w)
    return v * scale, w * scale


def limit_acceleration(v: float, w: float, prev_v: float, prev_w: float, dt: float,
                       max_linear_accel: float, max_angular_accel: float) -> Command:
    """Clamp the change from the previous command to the acceleration limits over dt (s).

    Limits in m/s^2 and rad/s^2; 0 or infinity means unlimited. Returns (v, w).
    """
    if max_linear_accel > 0.0 and max_linear_accel < math.inf:
        step = max_linear_accel * dt
        v = min(max(v, prev_v - step), prev_v + step)
    if max_angular_accel > 0.0 and max_angular_accel < math.inf:
        step = max_angular_accel * dt
        w = min(max(w, prev_w - step), prev_w + step)
    return v, w


def inside_fence(x: float, y: float,
                 fence: tuple[float, float, float, float] | None) -> bool:
    """True when (x, y) lies in fence = (xmin, ymin, xmax, ymax), or when fence is None."""
    return fence is None or (fence[0] <= x <= fence[2] and fence[1] <= y <= fence[3])


def with_feed_forward(fx: float, fy: float, ahead_x: float, ahead_y: float,
                      k1: float) -> Point:
    """The feedback (m) that makes the law's control-point velocity -k1 f + G(s_i) xi-dot:
    f - (target velocity) / k1, with the target's velocity (m/s, arena frame) on a moving
    curve. Every agent adding its own target's velocity cancels the curve's motion in the
    error dynamics, so the paper's exponential convergence holds on a moving curve (within
    the wheel limits).
    """
    return fx - ahead_x / k1, fy - ahead_y / k1


def leader_feedback(ex: float, ey: float) -> Point:
    """The leader's feedback term: its own error (m)."""
    return ex, ey


def follower_feedback(ex: float, ey: float, neighbour_errors: Sequence[Point],
                      weights: Sequence[float], pinning: float = 0.0) -> Point:
    """A follower's feedback b e_i + sum_j a_ij (e_i - e_j) (m) from its own error, its
    in-neighbours' errors (k, 2) and its pinning weight b (0 in the paper).
    """
    fx = pinning * ex
    fy = pinning * ey
    for j in range(len(weights)):
        fx += weights[j] * (ex - neighbour_errors[j][0])
        fy += weights[j] * (ey - neighbour_errors[j][1])
    return fx, fy


def wheel_speeds(v: float, w: float, wheel_base: float) -> tuple[float, float]:
    """(right, left) wheel linear speeds (m/s) for body velocities (v, w)."""
    return v + 0.5 * wheel_base * w, v - 0.5 * wheel_base * w


def stacked_paper_input(poses: FloatArray, dhat: FloatArray, g_bar: FloatArray,
                        xi: FloatArray, laplacian: FloatArray, leader: int,
                        gains: Gains) -> FloatArray:
    """The paper's stacked law, with the pseudo-inverse, as a reference for tests.

    ub = -k1 (Lbar Gbar xi_e + Lambda_bar xb_e) - k2 R dhat with xi_e = Gbar^+ xb - xi.

    Args:
        poses: (n, 3) x, y, theta.  dhat: (n, 2).  g_bar: (2n, 2H).  xi: (2H,).
        laplacian: (n, n).  leader: 0-based index.  gains: Gains.
    Returns:
        ub (n, 2) in the arena frame.
    """
    n = len(poses)
    xb = poses[:, :2] + gains.offset * np.column_stack([np.cos(poses[:, 2]),
                                                        np.sin(poses[:, 2])])
    xb_e = xb.ravel() - g_bar @ xi
    xi_e = np.linalg.pinv(g_bar) @ xb.ravel() - xi
    lam = np.zeros((n, n))
    lam[leader, leader] = 1.0
    consensus = np.kron(laplacian, np.eye(2)) @ g_bar @ xi_e + np.kron(lam, np.eye(2)) @ xb_e
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    r_dhat = np.column_stack([c * dhat[:, 0] - gains.offset * s * dhat[:, 1],
                              s * dhat[:, 0] + gains.offset * c * dhat[:, 1]])
    return -gains.k1 * consensus.reshape(n, 2) - gains.k2 * r_dhat
