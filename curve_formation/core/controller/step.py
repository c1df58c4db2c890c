"""One robot's control step, from its inputs to the command it sends: the one function the
ROS controller (core.controller.agent.AgentController) and the batch simulator's compiled
kernel (core.sim.kernel) both call, so that no feature of the law exists in one and not the
other.

Frames and units: poses (x, y, theta) and targets in the arena frame (m, rad); errors in m;
commands (v, w) in the robot frame (m/s, rad/s); the estimate dhat in the units of u.
Plain scalar math over plain arrays: numba compiles it as it is.
"""

from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.controller.driving import steered_law
from curve_formation.core.controller.gains import Law, OBSERVER
from curve_formation.core.controller.law import agent_command, consensus_feedback
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.safety import Avoidance
from curve_formation.core.formation.dynamics import offset_point, wheel_speeds


# agent_step's result: (v, w) to send; the observer's reference (ref_v, ref_w) and what the
# safety filter shifted (shift_v, shift_w); the estimate after the step (dhat_v, dhat_w) and
# its continuous-time rate (ddhat_v, ddhat_w); the filter's outcome code; whether the wheel
# limits cut the command (limited); the own error (ex, ey) and the feedback (fx, fy).
StepResult = tuple[float, float, float, float, float, float, float, float, float, float, int,
                   bool, float, float, float, float]


def target_error(x: float, y: float, theta: float, front: float, target_x: float,
                 target_y: float, offset: float) -> tuple[float, float]:
    """e_i = xb_i - G(s_i) xi (m): the point `front` * offset ahead of the axle (behind it
    when reversing, front -1) less the target.
    """
    bx, by = offset_point(x, y, theta, front * offset)
    return bx - target_x, by - target_y


def motors_idle(v: float, w: float, min_wheel_speed: float, wheel_base: float) -> bool:
    """Whether the command (v m/s, w rad/s) leaves both wheels within the motors' dead band
    (min_wheel_speed, m/s of wheel speed; 0: none), so that the robot stands.
    """
    if min_wheel_speed <= 0.0 or wheel_base <= 0.0:
        return False
    left, right = wheel_speeds(v, w, wheel_base)
    return abs(left) < min_wheel_speed and abs(right) < min_wheel_speed


def agent_step(x: float, y: float, theta: float, front: float, target_x: float,
               target_y: float, errors: FloatArray, sources: IntArray, weights: FloatArray,
               pin: float, ahead_x: float, ahead_y: float, dhat_v: float, dhat_w: float,
               used_v: float, used_w: float, prev_v: float, prev_w: float, pc_v: float,
               pc_w: float, law: Law, limits: WheelLimits, others: FloatArray, me: int,
               avoidance: Avoidance, min_wheel_speed: float) -> StepResult:
    """One control step of one agent.

    x, y, theta: its pose (as the law takes it: measured, or predicted to when the command
    acts); front: +1 steering the point ahead of the axle, -1 the one behind
    (driving.drive_direction); target: its point of the curve; errors (m, 2), sources (k,),
    weights (k,), pin: consensus_feedback's (the in-neighbours' errors); ahead: the target's
    velocity (m/s; the feed-forward, 0 on a still curve); dhat: the estimate; used: the
    estimate the command compensates (observer.carried_estimate: dhat, or with the
    second-order observer dhat carried ahead); prev: the previous command (the acceleration
    limits); pc: a disturbance added on the PC; law, limits, others (n, 3), me (0-based),
    avoidance: agent_command's; min_wheel_speed: the motors' dead band (m/s of wheel speed,
    as told or estimated; 0: none). The paper's and the adaptive laws' estimate advances one
    Euler step of the control period (law.period; 0 under continuous control, where the
    caller integrates ddhat), except while the command leaves the motors idle in the dead
    band (motors_idle): the robot stands whatever the estimate, and integrating the error it
    cannot act on would wind the estimate up without bound; the observer's is updated from
    the motion (observer.observer_update), not here. Returns StepResult.
    """
    ex, ey = target_error(x, y, theta, front, target_x, target_y, law.offset)
    fx, fy = consensus_feedback(ex, ey, errors, sources, weights, pin)
    v, w, ref_v, ref_w, ddv, ddw, code, shift_v, shift_w, limited = agent_command(
        fx, fy, ahead_x, ahead_y, ex, ey, x, y, theta, used_v, used_w, prev_v, prev_w, pc_v,
        pc_w, steered_law(law, front), limits, others, me, avoidance)
    if law.code != OBSERVER and not motors_idle(v, w, min_wheel_speed, limits.wheel_base):
        dhat_v += law.period * ddv
        dhat_w += law.period * ddw
    return (v, w, ref_v, ref_w, shift_v, shift_w, dhat_v, dhat_w, ddv, ddw, code, limited, ex,
            ey, fx, fy)
