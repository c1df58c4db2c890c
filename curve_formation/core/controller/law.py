"""The paper's leader/follower law: one agent's command from its feedback, pose and
estimate (agent_command), the one tick the ROS controller and the batch simulator run.

Frames and units: poses (x, y, theta) in the arena frame (metres, radians); the offset point
xb = (x + l cos theta, y + l sin theta) with offset l (metres, l != 0); commands u = (v, w) in
the robot frame (m/s, rad/s); the disturbance estimate dhat is in the same units as u.

The per-agent functions use only scalar math so that the same source runs in the ROS
controller node (plain Python) and inside the batch simulator's compiled kernel (numba).
"""

import math

from curve_formation.core.base.shapes import Command, FloatArray, IntArray, Point
from curve_formation.core.controller.gains import Law, OBSERVER
from curve_formation.core.controller.limits import (
    clipped,
    limit_acceleration,
    saturate,
    saturate_drifting,
    saturate_turning,
    WheelLimits,
)
from curve_formation.core.controller.observer import RAY_CLIPPED
from curve_formation.core.controller.safety import (
    ADJUSTED,
    Avoidance,
    safe_command,
    shaped_feedback,
)


# Share of the wheel and turn-rate limits the observer law's feedback may use (observer_input)
# where the disturbance is added on the PC, before the limits, so that once d is learnt the
# command it adds up to is not clipped (a clipped command moves the robot alike for a whole
# ray of estimates); with it on the robot the feedback may use the whole limits. 0.98: the
# observer's search (ray_growth) starts only where the limits cut the command (by more than
# RAY_CLIPPED), which the pipeline knows when it computes it (docs/control-laws.md).
FEEDBACK_HEADROOM = 0.98


def agent_command(fx: float, fy: float, ahead_x: float, ahead_y: float, ex: float,
                  ey: float, x: float, y: float,
                  theta: float, dhat_v: float, dhat_w: float, prev_v: float, prev_w: float,
                  pc_v: float, pc_w: float, law: 'Law', limits: 'WheelLimits',
                  others: FloatArray, me: int, avoidance: Avoidance
                  ) -> tuple[float, float, float, float, float, float, int, float, float, bool]:
    """One control tick of one agent, from its inputs to the command sent: the one pipeline
    the ROS controller (core.controller.agent) and the batch simulator both run.

    fx, fy: feedback (m; consensus_feedback); ahead: the target's velocity
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


def with_feed_forward(fx: float, fy: float, ahead_x: float, ahead_y: float,
                      k1: float) -> Point:
    """The feedback (m) that makes the law's control-point velocity -k1 f + G(s_i) xi-dot:
    f - (target velocity) / k1, with the target's velocity (m/s, arena frame) on a moving
    curve. Every agent adding its own target's velocity cancels the curve's motion in the
    error dynamics, so the paper's exponential convergence holds on a moving curve (within
    the wheel limits).
    """
    return fx - ahead_x / k1, fy - ahead_y / k1


def consensus_feedback(ex: float, ey: float, errors: FloatArray, sources: IntArray,
                       weights: FloatArray, pin: float) -> Point:
    """An agent's feedback b e_i + sum_k a_k (e_i - e_sources[k]) (m) from its own error,
    the errors (m, 2) its in-neighbours sources (k,) sent, their weights a (k,) and its own
    weight b: 1 for the leader (no in-neighbours: its own error), the graph's pinning for a
    follower (0 in the paper).
    """
    fx = pin * ex
    fy = pin * ey
    for k in range(len(sources)):
        j = sources[k]
        fx += weights[k] * (ex - errors[j, 0])
        fy += weights[k] * (ey - errors[j, 1])
    return fx, fy
