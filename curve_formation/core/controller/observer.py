"""The disturbance observer: the estimate moved towards the measured motion minus the
command, and its search along a motion the wheel limits saturate (ray_growth).

Velocities in m/s and rad/s, robot frame. Plain scalar math: the batch simulator compiles
it with numba.
"""

import math

from curve_formation.core.controller.gains import Law
from curve_formation.core.controller.limits import timed_by, WheelLimits
from curve_formation.core.formation.dynamics import wheel_speeds


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
# observer_order 2 predicts the disturbance over the coming period only after this many
# updates in a row whose commands the wheel limits did not cut (its rate has settled)
TRACKING_TICKS = 10


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
    left, right = wheel_speeds(measured_v, measured_w, limits.wheel_base)
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


def rate_update(rate_v: float, rate_w: float, predicted_v: float, predicted_w: float,
                corrected_v: float, corrected_w: float, alpha: float, elapsed: float,
                searching: bool) -> tuple[float, float]:
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
        return rate_v, rate_w
    beta = (1.0 - math.sqrt(max(1.0 - alpha, 0.0))) ** 2
    gain = beta / alpha / elapsed
    return (rate_v + gain * (corrected_v - predicted_v),
            rate_w + gain * (corrected_w - predicted_w))


def observer_update(dhat_v: float, dhat_w: float, rate_v: float, rate_w: float,
                    growth: float, last_right: float, last_left: float, tracking: int,
                    measured_v: float, measured_w: float, ref_v: float, ref_w: float,
                    shift_v: float, shift_w: float, limited: bool, law: Law,
                    limits: WheelLimits, elapsed: float
                    ) -> tuple[float, float, float, float, float, float, float, int]:
    """One update of the observer from a motion measured over `elapsed` s (measured: its
    constant body velocity, m/s and rad/s) against what was commanded over it (ref, shift,
    limited: agent_command's), as the controller and the batch simulator both make it.

    The estimate moves by the blend 1 - exp(-observer_rate elapsed) (observe); with
    law.order 2 it is first carried over the motion at its rate (rate_v, rate_w per s),
    and the rate is corrected as an alpha-beta filter's (rate_update); tracking counts the
    updates since the wheel limits last cut a command (the search along a ray is no change
    of the disturbance). Returns (dhat_v, dhat_w, rate_v, rate_w, growth, last_right,
    last_left, tracking).
    """
    blend = 1.0 - math.exp(-law.observer_rate * elapsed)
    second = law.order == 2
    before_v = dhat_v + rate_v * elapsed if second else dhat_v
    before_w = dhat_w + rate_w * elapsed if second else dhat_w
    new_v, new_w, growth, last_right, last_left = observe(
        before_v, before_w, growth, last_right, last_left, measured_v, measured_w, ref_v,
        ref_w, shift_v, shift_w, limited, law, limits, blend)
    if second:
        searching = limited or growth != 1.0
        rate_v, rate_w = rate_update(rate_v, rate_w, before_v, before_w, new_v, new_w, blend,
                                     elapsed, searching)
        tracking = 0 if searching else tracking + 1
    return new_v, new_w, rate_v, rate_w, growth, last_right, last_left, tracking


def carried_estimate(dhat_v: float, dhat_w: float, rate_v: float, rate_w: float,
                     tracking: int, ahead_by: float, law: Law) -> tuple[float, float]:
    """The estimate a command uses: with law.order 2, once its rate has settled (tracking
    at least TRACKING_TICKS), carried ahead_by s at that rate (from the middle of the motion
    it was learnt from to the middle of the period the command holds for); else as it is.
    """
    if law.order == 2 and tracking >= TRACKING_TICKS:
        return dhat_v + rate_v * ahead_by, dhat_w + rate_w * ahead_by
    return dhat_v, dhat_w
