"""The batch simulator's compiled stepping loop: n unicycles, each agent's control step the
controller's own (controller.step.agent_step, its observer controller.observer.
observer_update), at a zero-order hold or continuously.

- zero-order hold (Clock.control_every > 0): each agent ticks at its own offset in the
  control period from the latest poses; the observer first updates its estimate from the
  motion over the period just ended (exact here: the held motion is what the pose
  difference would measure), then the command is held while the robots are integrated
  exactly over each fine step dt, which is what the ROS controller nodes do;
- continuous: the law at every RK4 stage, its estimator integrated with the robots (the
  paper's setting; the observer as its continuous-time filter).

Poses in the arena frame (m, rad); commands in m/s and rad/s; times in s. Its cost is linear
in agents plus edges.
"""

import math
from typing import NamedTuple

import numba
import numpy as np

from curve_formation.core.base.jit import compiled
from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.controller import driving, observer, step
from curve_formation.core.controller.driving import REVERSE_HYSTERESIS
from curve_formation.core.controller.gains import Law, OBSERVER
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.safety import Avoidance
from curve_formation.core.formation import dynamics
from curve_formation.core.world import bodies


_agent_step = compiled(step.agent_step)
_target_error = compiled(step.target_error)
_observer_update = compiled(observer.observer_update)
_carried_estimate = compiled(observer.carried_estimate)
_arc = compiled(dynamics.arc_step)
_drive_direction = compiled(driving.drive_direction)
_touch = compiled(bodies.touch)

# Largest heading change (rad) of one RK4 substep in continuous mode.
MAX_TURN_PER_SUBSTEP = 0.05


class Clock(NamedTuple):
    """Fine steps of a simulation: dt (s); a control tick every control_every steps (0:
    continuous control), a record every record_every steps.
    """

    dt: float
    control_every: int
    record_every: int


# The graph as the kernels take it: each agent's in-edges as rows starts[i]:starts[i + 1]
# of (sources, weights), 0-based, in the graph's order; and each agent's own weight (pins).
EdgeArrays = tuple[IntArray, IntArray, FloatArray, FloatArray]
# (poses (n, 3), dhat, motion, cmd (n, 2), ref (n, 5), fronts (n,), rays (n, 3), rates
# (n, 2), counts (n, 2)), advanced in place; ref: the observer's reference (v, w), what the
# safety filter changed (v, w) and 1 where the wheel limits cut the command by more than
# observer.RAY_CLIPPED (0 otherwise); rays: observer.ray_growth's state (factor, last right,
# last left); rates: the second-order observer's rate of the estimate (per s); counts: its
# updates since the limits last cut a command, and 1 once the agent has sent a command.
SimState = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                 FloatArray, FloatArray, IntArray]


def edge_arrays(targets: IntArray, sources: IntArray, weights: FloatArray, pins: FloatArray
                ) -> EdgeArrays:
    """EdgeArrays from the graph's edges (targets, sources, weights; 0-based) and pins (n,)."""
    order = np.argsort(targets, kind='stable')
    starts = np.searchsorted(targets[order], np.arange(len(pins) + 1)).astype(np.int64)
    return (starts, np.ascontiguousarray(sources[order]),
            np.ascontiguousarray(weights[order]), np.ascontiguousarray(pins, dtype=float))


@numba.njit(cache=True)
def _controls(poses: FloatArray, dhat: FloatArray, rates: FloatArray, counts: IntArray,
              targets: FloatArray, ahead: FloatArray, graph: EdgeArrays, law: Law,
              limits: WheelLimits, avoidance: Avoidance, d_pc: FloatArray,
              d_robot: FloatArray, fronts: FloatArray, err: FloatArray, motion: FloatArray,
              cmd: FloatArray, ref: FloatArray, next_dhat: FloatArray, ddhat: FloatArray,
              codes: IntArray) -> None:
    """Every agent's control step (step.agent_step) from the poses, targets and estimates:
    fills cmd (sent), motion (actual), ref (n, 5), next_dhat (the estimate after the step),
    ddhat (its continuous-time rate) and codes (the safety filter's outcome); cmd on entry
    holds each agent's previous command.

    d_pc (n, 2) is added to the command before the limits (injected on the PC), d_robot
    (n, 2) after them (physical). ahead (n, 2): each target's velocity (m/s, a moving curve's
    feed-forward; zeros otherwise). fronts (n,): the offset point each agent steers.
    """
    starts, sources, weights, pins = graph
    n = poses.shape[0]
    for i in range(n):   # every agent's error, as its out-neighbours receive it
        err[i, 0], err[i, 1] = _target_error(poses[i, 0], poses[i, 1], poses[i, 2], fronts[i],
                                             targets[i, 0], targets[i, 1], law.offset)
    for i in range(n):
        a, b = starts[i], starts[i + 1]
        # the estimate carried from the middle of the period just measured to the middle of
        # the coming one: a period ahead (the node's rule with exact, fresh poses)
        used_v, used_w = _carried_estimate(dhat[i, 0], dhat[i, 1], rates[i, 0], rates[i, 1],
                                           counts[i, 0], law.period, law)
        (v, w, ref_v, ref_w, shift_v, shift_w, dhat_v, dhat_w, ddv, ddw, code, limited, _, _,
         _, _) = _agent_step(poses[i, 0], poses[i, 1], poses[i, 2], fronts[i], targets[i, 0],
                             targets[i, 1], err, sources[a:b], weights[a:b], pins[i],
                             ahead[i, 0], ahead[i, 1], dhat[i, 0], dhat[i, 1], used_v, used_w,
                             cmd[i, 0], cmd[i, 1], d_pc[i, 0], d_pc[i, 1], law, limits, poses,
                             i, avoidance)
        motion[i, 0] = v + d_robot[i, 0]
        motion[i, 1] = w + d_robot[i, 1]
        cmd[i, 0] = v
        cmd[i, 1] = w
        ref[i, 0] = ref_v
        ref[i, 1] = ref_w
        ref[i, 2] = shift_v
        ref[i, 3] = shift_w
        ref[i, 4] = 1.0 if limited else 0.0
        codes[i] = code
        next_dhat[i, 0] = dhat_v
        next_dhat[i, 1] = dhat_w
        if law.code == OBSERVER and law.k2 != 0.0:   # continuous-time filter (k2 = 0: off)
            ddv = law.observer_rate * ((motion[i, 0] - ref[i, 0]) / law.k2 - dhat[i, 0])
            ddw = law.observer_rate * ((motion[i, 1] - ref[i, 1]) / law.k2 - dhat[i, 1])
        ddhat[i, 0] = ddv
        ddhat[i, 1] = ddw


@numba.njit(cache=True)
def _arc_step(poses: FloatArray, motion: FloatArray, dt: float) -> None:
    """Exact unicycle motion over dt with constant (v, w) per agent."""
    for i in range(poses.shape[0]):
        poses[i, 0], poses[i, 1], poses[i, 2] = _arc(poses[i, 0], poses[i, 1], poses[i, 2],
                                                     motion[i, 0], motion[i, 1], dt)


@numba.njit(cache=True)
def _observe(i: int, state: SimState, law: Law, limits: WheelLimits, elapsed: float) -> None:
    """Agent i's observer update from the motion held over the `elapsed` s since its last
    command (none before its first), as the node makes it (observer.observer_update).
    """
    dhat, motion, ref, rays, rates, counts = (state[1], state[2], state[4], state[6], state[7],
                                              state[8])
    if counts[i, 1] == 0:
        return
    (dhat[i, 0], dhat[i, 1], rates[i, 0], rates[i, 1], rays[i, 0], rays[i, 1], rays[i, 2],
     counts[i, 0]) = _observer_update(dhat[i, 0], dhat[i, 1], rates[i, 0], rates[i, 1],
                                      rays[i, 0], rays[i, 1], rays[i, 2], counts[i, 0],
                                      motion[i, 0], motion[i, 1], ref[i, 0], ref[i, 1],
                                      ref[i, 2], ref[i, 3], ref[i, 4] != 0.0, law, limits,
                                      elapsed)


@numba.njit(cache=True)
def run(state: SimState, targets: FloatArray, ahead: FloatArray, graph: EdgeArrays, law: Law,
        limits: WheelLimits, avoidance: Avoidance, d_pc: FloatArray, d_robot: FloatArray,
        clock: Clock, step0: int, steps: int, schedule: tuple[IntArray, IntArray],
        contacts: bodies.Contacts, record: tuple[FloatArray, FloatArray, FloatArray]) -> None:
    """Advance the state (SimState) in place by `steps` fine steps from `step0`.

    schedule: (tick_offsets, start_steps): agent i ticks at the steps where
    (step - tick_offsets[i]) % control_every == 0, from step start_steps[i] on. A tick first
    chooses the point the agent steers (driving.drive_direction, as the node does when a
    pose comes; under continuous control at every fine step), then with the observer updates
    the estimate (_observe), then steps the law (_controls).
    record: (poses, dhat, cmd) arrays filled every record_every steps.
    """
    poses, dhat, motion, cmd, ref, fronts = (state[0], state[1], state[2], state[3], state[4],
                                             state[5])
    counts = state[8]
    tick_offsets, start_steps = schedule
    rec_poses, rec_dhat, rec_cmd = record
    n = poses.shape[0]
    err = np.zeros((n, 2))
    next_dhat = np.zeros((n, 2))
    ddhat = np.zeros((n, 2))
    codes = np.zeros(n, dtype=np.int64)
    dt = clock.dt
    control_every = clock.control_every
    if control_every > 0:
        dt_control = control_every * dt
        new_motion = np.zeros((n, 2))
        new_cmd = np.zeros((n, 2))
        new_ref = np.zeros((n, 5))
        for fine in range(step0, step0 + steps):
            ticking = False
            for i in range(n):
                if (fine - tick_offsets[i]) % control_every == 0:
                    ticking = True
                    if fine >= start_steps[i]:
                        fronts[i] = _drive_direction(fronts[i], poses[i, 0], poses[i, 1],
                                                     poses[i, 2], targets[i, 0], targets[i, 1],
                                                     dhat[i, 0], dhat[i, 1], law, limits,
                                                     REVERSE_HYSTERESIS)
                        if law.code == OBSERVER:
                            _observe(i, state, law, limits, dt_control)
            if ticking:
                new_cmd[:] = cmd   # each agent's previous command
                _controls(poses, dhat, state[7], counts, targets, ahead, graph, law, limits,
                          avoidance, d_pc, d_robot, fronts, err, new_motion, new_cmd, new_ref,
                          next_dhat, ddhat, codes)
                for i in range(n):
                    if fine < start_steps[i]:
                        continue   # not started yet: motors off, estimator idle
                    if (fine - tick_offsets[i]) % control_every == 0:
                        motion[i] = new_motion[i]
                        cmd[i] = new_cmd[i]
                        ref[i] = new_ref[i]
                        dhat[i] = next_dhat[i]
                        counts[i, 1] = 1
            if fine % clock.record_every == 0:
                r = fine // clock.record_every
                rec_poses[r] = poses
                rec_dhat[r] = dhat
                rec_cmd[r] = cmd
            _arc_step(poses, motion, dt)
            _touch(poses, contacts, dt)
        return
    # Continuous control: RK4 on (poses, dhat) with the law evaluated at every stage. The
    # heading turns at up to k1 |e| / l (1000 rad/s at the paper's start), so each step is
    # split into substeps that turn at most MAX_TURN_PER_SUBSTEP.
    rates = state[7]
    kp = np.zeros((4, n, 3))
    kd = np.zeros((4, n, 2))
    p_stage = np.zeros((n, 3))
    d_stage = np.zeros((n, 2))
    for fine in range(step0, step0 + steps):
        for i in range(n):
            fronts[i] = _drive_direction(fronts[i], poses[i, 0], poses[i, 1], poses[i, 2],
                                         targets[i, 0], targets[i, 1], dhat[i, 0], dhat[i, 1],
                                         law, limits, REVERSE_HYSTERESIS)
        _controls(poses, dhat, rates, counts, targets, ahead, graph, law, limits, avoidance,
                  d_pc, d_robot, fronts, err, motion, cmd, ref, next_dhat, ddhat, codes)
        if fine % clock.record_every == 0:
            r = fine // clock.record_every
            rec_poses[r] = poses
            rec_dhat[r] = dhat
            rec_cmd[r] = cmd
        fastest = 0.0
        for i in range(n):
            fastest = max(fastest, abs(motion[i, 1]))
        substeps = max(1, int(math.ceil(fastest * dt / MAX_TURN_PER_SUBSTEP)))
        h = dt / substeps
        for _ in range(substeps):
            for stage in range(4):
                frac = 0.0 if stage == 0 else (h if stage == 3 else 0.5 * h)
                for i in range(n):
                    for c in range(3):
                        p_stage[i, c] = poses[i, c] + frac * kp[stage - 1, i, c]
                    for c in range(2):
                        d_stage[i, c] = dhat[i, c] + frac * kd[stage - 1, i, c]
                _controls(p_stage, d_stage, rates, counts, targets, ahead, graph, law, limits,
                          avoidance, d_pc, d_robot, fronts, err, motion, cmd, ref, next_dhat,
                          ddhat, codes)
                for i in range(n):
                    kp[stage, i, 0] = motion[i, 0] * math.cos(p_stage[i, 2])
                    kp[stage, i, 1] = motion[i, 0] * math.sin(p_stage[i, 2])
                    kp[stage, i, 2] = motion[i, 1]
                    kd[stage, i, 0] = ddhat[i, 0]
                    kd[stage, i, 1] = ddhat[i, 1]
            for i in range(n):
                for c in range(3):
                    poses[i, c] += h / 6.0 * (kp[0, i, c] + 2.0 * kp[1, i, c]
                                              + 2.0 * kp[2, i, c] + kp[3, i, c])
                for c in range(2):
                    dhat[i, c] += h / 6.0 * (kd[0, i, c] + 2.0 * kd[1, i, c]
                                             + 2.0 * kd[2, i, c] + kd[3, i, c])
        _touch(poses, contacts, dt)
