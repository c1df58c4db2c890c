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
