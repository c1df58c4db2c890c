"""The batch simulator's compiled stepping loop: n unicycles, each agent's control tick the
controller's own (controller.step.agent_step, with motion_observer's observer memory and
command_log's commands sent, the functions AgentController calls), at a zero-order hold or
continuously.

- zero-order hold (Clock.control_every > 0): each agent ticks at its own offset in the
  control period from its pose then, as a node whose pose has just come: the pose carried
  to when the command acts (predict_pose), the observer's update from the motion measured
  since its last tick, the step, and the command logged; each robot moves by the command
  that has reached it (Delay.latency after it was sent), integrated exactly over each fine
  step dt, which is what the ROS controller nodes and their robots do;
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
from curve_formation.core.controller import (
    command_log,
    driving,
    motion_observer,
    others,
    step,
)
from curve_formation.core.controller.driving import REVERSE_HYSTERESIS
from curve_formation.core.controller.gains import Law, OBSERVER
from curve_formation.core.controller.inputs import MAX_PREDICTION
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.others import OTHERS_KEPT
from curve_formation.core.controller.safety import Avoidance, STOPPED
from curve_formation.core.formation import dynamics
from curve_formation.core.world import bodies


_agent_step = compiled(step.agent_step)
_target_error = compiled(step.target_error)
_observe_motion = compiled(motion_observer.observe_motion)
_observer_commanded = compiled(motion_observer.observer_commanded)
_observer_stopped = compiled(motion_observer.observer_stopped)
_estimate_used = compiled(motion_observer.estimate_used)
_pose_append = compiled(motion_observer.pose_append)
_log_sent = compiled(motion_observer.log_sent)
_make_room = compiled(command_log.make_room)
_log_acting = compiled(command_log.log_acting)
_log_predicted = compiled(command_log.log_predicted)
_carried_ahead = compiled(others.carried_ahead)
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


class Delay(NamedTuple):
    """How late commands act: latency (s from sending to the wheels,
    controller.command_latency); predict: each controller carries its pose forward to when
    its command acts (controller.predict_pose), a pose at most `longest` s old; history: the
    room for the snapshots of every robot's pose kept for the others' velocities
    (others.carried_ahead), one per control period over others.OTHERS_KEPT (1: none used).
    """

    latency: float
    predict: bool
    longest: float
    history: int


NO_DELAY = Delay(0.0, False, 0.0, 1)


class SimState(NamedTuple):
    """The batch run's state, advanced in place: poses (n, 3), dhat (n, 2), the motion
    acting (n, 2; with the disturbance), each agent's last command (n, 2), fronts (n,); per
    agent the controller's memory as the nodes hold it: the observer's (n, MEMORY;
    motion_observer), the commands sent (n, K, command_log.FIELDS) and their counts (n,),
    the recent poses (n, RECENT_POSES, POSE_FIELDS) and their counts (n,); history
    (Delay.history, n, 3): every robot's pose at the last control periods (oldest first),
    taken at history_times (Delay.history,; s), history_count (1,) of them held.
    """

    poses: FloatArray
    dhat: FloatArray
    motion: FloatArray
    cmd: FloatArray
    fronts: FloatArray
    memory: FloatArray
    log: FloatArray
    log_count: IntArray
    recent: FloatArray
    recent_count: IntArray
    history: FloatArray
    history_times: FloatArray
    history_count: IntArray


def initial_state(poses: FloatArray, commands_kept: int, delay: Delay) -> SimState:
    """A run's SimState from the robots' poses (n, 3; used in place), before any command;
    commands_kept: the rows of each agent's command log.
    """
    n = len(poses)
    return SimState(poses, np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2)), np.ones(n),
                    np.tile(motion_observer.fresh_memory(), (n, 1)),
                    np.zeros((n, commands_kept, command_log.FIELDS)),
                    np.zeros(n, dtype=np.int64),
                    np.zeros((n, motion_observer.RECENT_POSES, motion_observer.POSE_FIELDS)),
                    np.zeros(n, dtype=np.int64), np.zeros((delay.history, n, 3)),
                    np.zeros(delay.history), np.zeros(1, dtype=np.int64))


def edge_arrays(targets: IntArray, sources: IntArray, weights: FloatArray, pins: FloatArray
                ) -> EdgeArrays:
    """EdgeArrays from the graph's edges (targets, sources, weights; 0-based) and pins (n,)."""
    order = np.argsort(targets, kind='stable')
    starts = np.searchsorted(targets[order], np.arange(len(pins) + 1)).astype(np.int64)
    return (starts, np.ascontiguousarray(sources[order]),
            np.ascontiguousarray(weights[order]), np.ascontiguousarray(pins, dtype=float))


@numba.njit(cache=True)
def _controls(poses: FloatArray, dhat: FloatArray, targets: FloatArray, ahead: FloatArray,
              graph: EdgeArrays, law: Law, limits: WheelLimits, avoidance: Avoidance,
              d_pc: FloatArray, d_robot: FloatArray, fronts: FloatArray, err: FloatArray,
              motion: FloatArray, cmd: FloatArray, ref: FloatArray, next_dhat: FloatArray,
              ddhat: FloatArray, codes: IntArray) -> None:
    """Every agent's control step (step.agent_step) under continuous control, from the
    poses, targets and estimates:
    fills cmd (sent), motion (actual), ref (n, 5), next_dhat (the estimate after the step),
    ddhat (its continuous-time rate) and codes (the safety filter's outcome); cmd on entry
    holds each agent's previous command.

    d_pc (n, 2) is added to the command before the limits (injected on the PC), d_robot
    (n, 2) after them (physical). ahead (n, 2): each target's velocity (m/s, a moving curve's
    feed-forward; zeros otherwise). fronts (n,): the offset point each agent steers. The
    command compensates the estimate as it is (the continuous-time filter is first order).
    """
    starts, sources, weights, pins = graph
    n = poses.shape[0]
    for i in range(n):   # every agent's error, as its out-neighbours receive it
        err[i, 0], err[i, 1] = _target_error(poses[i, 0], poses[i, 1], poses[i, 2], fronts[i],
                                             targets[i, 0], targets[i, 1], law.offset)
    for i in range(n):
        a, b = starts[i], starts[i + 1]
        (v, w, ref_v, ref_w, shift_v, shift_w, dhat_v, dhat_w, ddv, ddw, code, limited, _, _,
         _, _) = _agent_step(poses[i, 0], poses[i, 1], poses[i, 2], fronts[i], targets[i, 0],
                             targets[i, 1], err, sources[a:b], weights[a:b], pins[i],
                             ahead[i, 0], ahead[i, 1], dhat[i, 0], dhat[i, 1], dhat[i, 0],
                             dhat[i, 1], cmd[i, 0], cmd[i, 1], d_pc[i, 0], d_pc[i, 1], law,
                             limits, poses, i, avoidance, 0.0)   # no band told (batch)
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
def _tick(i: int, now: float, state: SimState, err: FloatArray, aimed: FloatArray,
          ahead: FloatArray, graph: EdgeArrays, law: Law, limits: WheelLimits,
          avoidance: Avoidance, d_pc: FloatArray, delay: Delay, period: float) -> None:
    """Agent i's control tick at `now` (s) from its pose taken then, as the node makes it
    (AgentController._tick): the pose carried to when the command acts (predict_pose), the
    observer's update from the motion measured (motion_observer.observe_motion), the step
    (step.agent_step) towards its target where it is when the command acts (aimed, n, 2)
    from the in-neighbours' errors `err` (n, 2), and the command logged
    (command_log) for the world to act on after the latency. period: the control period
    (s).
    """
    poses, dhat, cmd, memory = state.poses, state.dhat, state.cmd, state.memory[i]
    log, count = state.log[i], state.log_count[i]
    x, y, theta = poses[i, 0], poses[i, 1], poses[i, 2]
    dhat_v, dhat_w = dhat[i, 0], dhat[i, 1]
    own_x, own_y, own_theta = x, y, theta
    if delay.predict:   # driven, the robot moves by its command plus the disturbance
        drift_v, drift_w = (0.0, 0.0) if law.on_pc else (law.k2 * dhat_v, law.k2 * dhat_w)
        own_x, own_y, own_theta = _log_predicted(log, count, x, y, theta, now, now, now,
                                                 delay.latency, delay.longest, drift_v,
                                                 drift_w)
    if law.code == OBSERVER:
        dhat_v, dhat_w = _observe_motion(memory, dhat_v, dhat_w, state.recent[i],
                                         state.recent_count[i], log, count, x, y, theta, now,
                                         now, delay.latency, 0.0, law, limits)
    used_v, used_w = _estimate_used(memory, dhat_v, dhat_w, now, delay.latency, period, law)
    robots = poses
    held = state.history_count[0]
    if delay.predict and delay.latency > 0.0 and avoidance.on and held >= 2:
        # the others' poses carried from the last kept to when the command acts
        first, last = state.history_times[0], state.history_times[held - 1]
        ahead_by = min(max(now + delay.latency - last, 0.0), MAX_PREDICTION + delay.latency)
        robots = _carried_ahead(poses, state.history[0], state.history[held - 1],
                                last - first, ahead_by, limits.max_wheel_speed)
    starts, sources, weights, pins = graph
    a, b = starts[i], starts[i + 1]
    (v, w, ref_v, ref_w, shift_v, shift_w, dhat_v, dhat_w, _, _, code, limited, _, _, _,
     _) = _agent_step(own_x, own_y, own_theta, state.fronts[i], aimed[i, 0], aimed[i, 1],
                      err, sources[a:b], weights[a:b], pins[i], ahead[i, 0], ahead[i, 1],
                      dhat_v, dhat_w, used_v, used_w, cmd[i, 0], cmd[i, 1], d_pc[i, 0],
                      d_pc[i, 1], law, limits, robots, i, avoidance, 0.0)   # no band told
    dhat[i, 0], dhat[i, 1] = dhat_v, dhat_w
    if code == STOPPED:
        _observer_stopped(memory)
        v, w = 0.0, 0.0
    else:
        _observer_commanded(memory, v, w, ref_v, ref_w, shift_v, shift_w, limited, x, y,
                            theta, now, now, 0.0, limits.wheel_base)
    cmd[i, 0], cmd[i, 1] = v, w
    state.log_count[i] = _log_sent(memory, log, count, now, v, w, code == STOPPED)


@numba.njit(cache=True)
def _act(state: SimState, now: float, latency: float, d_robot: FloatArray) -> None:
    """The motion acting on each robot at `now` (s): the command that reached it (sent
    `latency` s or more before) plus its disturbance while driven; none before any or while
    stopped (motors off, as dynamics.DrivenUnicycle moves).
    """
    for i in range(state.poses.shape[0]):
        k = _log_acting(state.log[i], state.log_count[i], now, latency)
        v = w = 0.0
        if k >= 0:
            v, w = state.log[i, k, command_log.V], state.log[i, k, command_log.W]
        if v != 0.0 or w != 0.0:
            v, w = v + d_robot[i, 0], w + d_robot[i, 1]
        state.motion[i, 0], state.motion[i, 1] = v, w


@numba.njit(cache=True)
def _remember_poses(state: SimState, taken: float) -> None:
    """Every robot's pose, taken at `taken` (s), kept in the history with those of the last
    OTHERS_KEPT s before it, as others.OtherRobots keeps them.
    """
    history, times, held = state.history, state.history_times, state.history_count[0]
    _make_room(times, held)
    held = _make_room(history, held)
    history[held] = state.poses
    times[held] = taken
    held += 1
    while taken - times[0] > OTHERS_KEPT:   # the oldest out
        history[:held - 1] = history[1:held]
        times[:held - 1] = times[1:held]
        held -= 1
    state.history_count[0] = held


@numba.njit(cache=True)
def run(state: SimState, targets: FloatArray, aimed: FloatArray, ahead: FloatArray,
        graph: EdgeArrays, law: Law, limits: WheelLimits, avoidance: Avoidance,
        d_pc: FloatArray, d_robot: FloatArray, clock: Clock, delay: Delay, step0: int,
        steps: int, schedule: tuple[IntArray, IntArray], contacts: bodies.Contacts,
        record: tuple[FloatArray, FloatArray, FloatArray]) -> None:
    """Advance the state (SimState) in place by `steps` fine steps from `step0`.

    schedule: (tick_offsets, start_steps): agent i ticks at the steps where
    (step - tick_offsets[i]) % control_every == 0, from step start_steps[i] on. A tick first
    takes the agent's pose and chooses the point it steers (driving.drive_direction, as the
    node does when a pose comes; under continuous control at every fine step), then steps
    the controller (_tick); each robot moves by the command that has reached it (_act).
    targets (n, 2): each agent's now, its error's as sent to its out-neighbours; aimed: where
    they are when a command acts (a moving curve's ahead by the latency with predict_pose;
    else targets); ahead: their velocities (m/s; zeros on a still curve).
    record: (poses, dhat, cmd) arrays filled every record_every steps.
    """
    poses, dhat, cmd, fronts = state.poses, state.dhat, state.cmd, state.fronts
    tick_offsets, start_steps = schedule
    rec_poses, rec_dhat, rec_cmd = record
    n = poses.shape[0]
    err = np.zeros((n, 2))
    dt = clock.dt
    control_every = clock.control_every
    if control_every > 0:
        period = control_every * dt
        ticks = np.zeros(n, dtype=np.bool_)
        for fine in range(step0, step0 + steps):
            now = fine * dt
            if delay.history > 1 and fine % control_every == 0:   # at the control rate,
                _remember_poses(state, (fine // control_every) * period)   # from t = 0
            for i in range(n):
                ticks[i] = ((fine - tick_offsets[i]) % control_every == 0
                            and fine >= start_steps[i])
                if ticks[i]:
                    fronts[i] = _drive_direction(fronts[i], poses[i, 0], poses[i, 1],
                                                 poses[i, 2], targets[i, 0], targets[i, 1],
                                                 dhat[i, 0], dhat[i, 1], law, limits,
                                                 REVERSE_HYSTERESIS)
                    state.recent_count[i] = _pose_append(state.recent[i],
                                                         state.recent_count[i], now, now,
                                                         poses[i, 0], poses[i, 1],
                                                         poses[i, 2])
            if ticks.any():
                for i in range(n):   # every agent's error, as its out-neighbours receive it
                    err[i, 0], err[i, 1] = _target_error(poses[i, 0], poses[i, 1], poses[i, 2],
                                                         fronts[i], targets[i, 0],
                                                         targets[i, 1], law.offset)
                for i in range(n):
                    if ticks[i]:
                        _tick(i, now, state, err, aimed, ahead, graph, law, limits,
                              avoidance, d_pc, delay, period)
            _act(state, now, delay.latency, d_robot)
            if fine % clock.record_every == 0:
                r = fine // clock.record_every
                rec_poses[r] = poses
                rec_dhat[r] = dhat
                rec_cmd[r] = cmd
            _arc_step(poses, state.motion, dt)
            _touch(poses, contacts, dt)
        return
    # Continuous control: RK4 on (poses, dhat) with the law evaluated at every stage. The
    # heading turns at up to k1 |e| / l (1000 rad/s at the paper's start), so each step is
    # split into substeps that turn at most MAX_TURN_PER_SUBSTEP.
    motion = state.motion
    ref = np.zeros((n, 5))
    next_dhat = np.zeros((n, 2))
    ddhat = np.zeros((n, 2))
    codes = np.zeros(n, dtype=np.int64)
    kp = np.zeros((4, n, 3))
    kd = np.zeros((4, n, 2))
    p_stage = np.zeros((n, 3))
    d_stage = np.zeros((n, 2))
    for fine in range(step0, step0 + steps):
        for i in range(n):
            fronts[i] = _drive_direction(fronts[i], poses[i, 0], poses[i, 1], poses[i, 2],
                                         targets[i, 0], targets[i, 1], dhat[i, 0], dhat[i, 1],
                                         law, limits, REVERSE_HYSTERESIS)
        _controls(poses, dhat, targets, ahead, graph, law, limits, avoidance,
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
                _controls(p_stage, d_stage, targets, ahead, graph, law, limits,
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
