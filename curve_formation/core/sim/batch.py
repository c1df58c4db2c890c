"""Batch simulator: n unicycles with constant input disturbance under the formation law.

Two control modes:
- continuous: the law is evaluated at every RK4 stage and the estimator is integrated with the
  robots (the paper's setting);
- zero-order hold at `rate_hz`: the law is evaluated once per control period from the latest
  poses, its estimator advanced by one Euler step (the observer: by one filter step from the
  motion over the period just ended), and the command held while the robots are integrated
  exactly over each fine step dt, which is what the ROS controller nodes do.

Laws (core.controller.gains.LAWS): paper, adaptive (per-channel estimator gains), observer.

The stepping loop is compiled with numba; it calls the same per-agent functions as the ROS
controller (core.controller.law), and its cost is linear in agents plus edges.
"""

from collections.abc import Callable
import dataclasses
from dataclasses import dataclass
import math
from typing import Any, Literal, NamedTuple

import numba
import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.jit import compiled
from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.experiment import Experiment, phase_index, whole_steps
from curve_formation.core.controller import driving, observer
from curve_formation.core.controller import law as control_law
from curve_formation.core.controller.disturbance import disturbance_at
from curve_formation.core.controller.driving import REVERSE_HYSTERESIS
from curve_formation.core.controller.gains import Gains, Law, OBSERVER
from curve_formation.core.controller.limits import timed_by, WheelLimits
from curve_formation.core.controller.safety import Avoidance
from curve_formation.core.formation import dynamics
from curve_formation.core.record import metrics
from curve_formation.core.schedule.curve_schedule import CurveSchedule
from curve_formation.core.sim.estimate_replay import check_replayable, held_estimates
from curve_formation.core.world import bodies


_agent_command = compiled(control_law.agent_command)
_arc = compiled(dynamics.arc_step)
_observe = compiled(observer.observe)
_offset_point = compiled(dynamics.offset_point)
_drive_direction = compiled(driving.drive_direction)
_steered_law = compiled(driving.steered_law)
_touch = compiled(bodies.touch)

# How often (s) a moving curve's targets are renewed under continuous control.
MOVING_STEP = 0.01
# Largest heading change (rad) of one RK4 substep in continuous mode.
MAX_TURN_PER_SUBSTEP = 0.05


class Clock(NamedTuple):
    """Fine steps of a simulation: dt (s); a control tick every control_every steps (0:
    continuous control), a record every record_every steps.
    """

    dt: float
    control_every: int
    record_every: int


# The graph as the kernels take it: (targets, sources, weights) edge arrays and the pins.
EdgeArrays = tuple[IntArray, IntArray, FloatArray, FloatArray]
# (poses (n, 3), dhat, motion, cmd (n, 2), ref (n, 5), fronts (n,), rays (n, 3)), advanced in
# place; ref: the observer's reference (v, w), what the safety filter changed (v, w) and 1
# where the wheel limits cut the command by more than observer.RAY_CLIPPED (0 otherwise);
# rays: the observer's observer.ray_growth state (factor, last right, last left).
SimState = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                 FloatArray]


@numba.njit(cache=True)
def _controls(poses: FloatArray, dhat: FloatArray, targets: FloatArray, ahead: FloatArray,
              graph: EdgeArrays, law: Law, limits: WheelLimits, avoidance: Avoidance,
              d_pc: FloatArray, d_robot: FloatArray, fronts: FloatArray, err: FloatArray,
              fb: FloatArray, motion: FloatArray, cmd: FloatArray, ref: FloatArray,
              ddhat: FloatArray, codes: IntArray) -> None:
    """Evaluate every agent's tick (law.agent_command): fills err, fb, cmd (sent), motion
    (actual), ref (n, 5: the observer's reference, what the safety filter changed, 1 where
    the wheel limits cut the command by more than observer.RAY_CLIPPED), ddhat
    (continuous-time estimator rate) and codes (the safety filter's outcome); cmd on entry
    holds each agent's previous command.

    graph: (tgt, src, weights, pins) edge arrays. d_pc (n, 2) is added to the command before
    the limits (injected on the PC), d_robot (n, 2) after them (physical). ahead (n, 2): each
    target's velocity (m/s, a moving curve's feed-forward; zeros otherwise). fronts (n,):
    the offset point each agent steers (driving.drive_direction).
    """
    tgt, src, wts, pins = graph
    n = poses.shape[0]
    for i in range(n):
        bx, by = _offset_point(poses[i, 0], poses[i, 1], poses[i, 2], fronts[i] * law.offset)
        err[i, 0] = bx - targets[i, 0]
        err[i, 1] = by - targets[i, 1]
        fb[i, 0] = pins[i] * err[i, 0]
        fb[i, 1] = pins[i] * err[i, 1]
    for k in range(tgt.shape[0]):
        i = tgt[k]
        j = src[k]
        fb[i, 0] += wts[k] * (err[i, 0] - err[j, 0])
        fb[i, 1] += wts[k] * (err[i, 1] - err[j, 1])
    for i in range(n):
        v, w, ref_v, ref_w, ddv, ddw, code, shift_v, shift_w, limited = _agent_command(
            fb[i, 0], fb[i, 1], ahead[i, 0], ahead[i, 1], err[i, 0], err[i, 1], poses[i, 0],
            poses[i, 1], poses[i, 2], dhat[i, 0], dhat[i, 1], cmd[i, 0], cmd[i, 1], d_pc[i, 0],
            d_pc[i, 1], _steered_law(law, fronts[i]), limits, poses, i, avoidance)
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
        if law.code == OBSERVER and law.k2 != 0.0:   # k2 = 0: estimator off
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
def _run(state: SimState, targets: FloatArray, ahead: FloatArray, graph: EdgeArrays, law: Law,
         limits: WheelLimits, avoidance: Avoidance, d_pc: FloatArray, d_robot: FloatArray,
         clock: Clock, step0: int, steps: int, schedule: tuple[IntArray, IntArray],
         contacts: bodies.Contacts, record: tuple[FloatArray, FloatArray, FloatArray]) -> None:
    """Advance the state (poses (n, 3), dhat (n, 2), the held motion, cmd, ref (n, 5), the
    steered points' fronts (n,) and the observer's rays (n, 3)) in place by `steps` fine
    steps from `step0`.

    schedule: (tick_offsets, start_steps): agent i ticks at the steps where
    (step - tick_offsets[i]) % control_every == 0, from step start_steps[i] on. With the
    observer, a tick first updates dhat from the motion over the period just ended (exact
    here: the held motion is what the pose difference would measure; its part before the
    safety filter scaled along its ray by observer.ray_growth); before that it chooses the
    point it steers (driving.drive_direction, as the node does when a pose comes; under
    continuous control at every fine step).
    record: (poses, dhat, cmd) arrays filled every record_every steps.
    """
    poses, dhat, motion, cmd, ref, fronts, rays = state
    tick_offsets, start_steps = schedule
    rec_poses, rec_dhat, rec_cmd = record
    n = poses.shape[0]
    err = np.zeros((n, 2))
    fb = np.zeros((n, 2))
    ddhat = np.zeros((n, 2))
    codes = np.zeros(n, dtype=np.int64)
    dt = clock.dt
    control_every = clock.control_every
    if control_every > 0:
        dt_control = control_every * dt
        blend = 1.0 - math.exp(-law.observer_rate * dt_control)
        new_motion = np.zeros((n, 2))
        new_cmd = np.zeros((n, 2))
        new_ref = np.zeros((n, 5))
        for step in range(step0, step0 + steps):
            ticking = False
            for i in range(n):
                if (step - tick_offsets[i]) % control_every == 0:
                    ticking = True
                    if step >= start_steps[i]:
                        fronts[i] = _drive_direction(fronts[i], poses[i, 0], poses[i, 1],
                                                     poses[i, 2], targets[i, 0], targets[i, 1],
                                                     dhat[i, 0], dhat[i, 1], law, limits,
                                                     REVERSE_HYSTERESIS)
                    if law.code == OBSERVER and step >= start_steps[i]:
                        (dhat[i, 0], dhat[i, 1], rays[i, 0], rays[i, 1],
                         rays[i, 2]) = _observe(dhat[i, 0], dhat[i, 1], rays[i, 0], rays[i, 1],
                                                rays[i, 2], motion[i, 0], motion[i, 1],
                                                ref[i, 0], ref[i, 1], ref[i, 2], ref[i, 3],
                                                ref[i, 4] != 0.0, law,
                                                limits, blend)
            if ticking:
                new_cmd[:] = cmd   # each agent's previous command
                _controls(poses, dhat, targets, ahead, graph, law, limits, avoidance, d_pc,
                          d_robot, fronts, err, fb, new_motion, new_cmd, new_ref, ddhat, codes)
                for i in range(n):
                    if step < start_steps[i]:
                        continue   # not started yet: motors off, estimator idle
                    if (step - tick_offsets[i]) % control_every == 0:
                        motion[i, 0] = new_motion[i, 0]
                        motion[i, 1] = new_motion[i, 1]
                        cmd[i, 0] = new_cmd[i, 0]
                        cmd[i, 1] = new_cmd[i, 1]
                        ref[i] = new_ref[i]
                        if law.code != OBSERVER:
                            dhat[i, 0] += dt_control * ddhat[i, 0]
                            dhat[i, 1] += dt_control * ddhat[i, 1]
            if step % clock.record_every == 0:
                r = step // clock.record_every
                rec_poses[r] = poses
                rec_dhat[r] = dhat
                rec_cmd[r] = cmd
            _arc_step(poses, motion, dt)
            _touch(poses, contacts, dt)
        return
    # Continuous control: RK4 on (poses, dhat) with the law evaluated at every stage. The
    # heading turns at up to k1 |e| / l (1000 rad/s at the paper's start), so each step is
    # split into substeps that turn at most MAX_TURN_PER_SUBSTEP.
    kp = np.zeros((4, n, 3))
    kd = np.zeros((4, n, 2))
    p_stage = np.zeros((n, 3))
    d_stage = np.zeros((n, 2))
    for step in range(step0, step0 + steps):
        for i in range(n):
            fronts[i] = _drive_direction(fronts[i], poses[i, 0], poses[i, 1], poses[i, 2],
                                         targets[i, 0], targets[i, 1], dhat[i, 0], dhat[i, 1],
                                         law, limits, REVERSE_HYSTERESIS)
        _controls(poses, dhat, targets, ahead, graph, law, limits, avoidance, d_pc, d_robot,
                  fronts, err, fb, motion, cmd, ref, ddhat, codes)
        if step % clock.record_every == 0:
            r = step // clock.record_every
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
                _controls(p_stage, d_stage, targets, ahead, graph, law, limits, avoidance, d_pc,
                          d_robot, fronts, err, fb, motion, cmd, ref, ddhat, codes)
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


def _choose_directions(state: SimState, targets: FloatArray, law: Law,
                       limits: WheelLimits) -> None:
    """Each robot's drive direction (state's fronts) as a curve's first pose sets it in the
    node (driving.drive_direction with no hysteresis), towards targets (n, 2; m).
    """
    poses, dhat, fronts = state[0], state[1], state[5]
    for i in range(len(fronts)):
        fronts[i] = driving.drive_direction(fronts[i], poses[i, 0], poses[i, 1], poses[i, 2],
                                            targets[i, 0], targets[i, 1], dhat[i, 0],
                                            dhat[i, 1], law, limits, 0.0)


@dataclass
class SimResult:
    """Recorded time series.

    t: (R,) s.  poses: (R, n, 3) x, y, theta (arena frame).  dhat: (R, n, 2) estimates.
    commands: (R, n, 2) (v, w) sent to the robots (after limits; with an on_pc disturbance it
    includes d).  phase: (R,) index of the active curve.  gains, limits, disturbance (n, 2;
    (R, n, 2) at each sample where it varies):
    the settings the run used (the experiment's unless overridden). contacts: counted at every
    fine step (new contacts between two bodies, time with any, smallest surface gap).
    """

    experiment: Experiment
    rate_hz: float | None
    gains: Gains
    limits: WheelLimits
    disturbance: FloatArray
    t: FloatArray
    poses: FloatArray
    dhat: FloatArray
    commands: FloatArray
    phase: IntArray
    radius: float = 0.0      # bodies (m); 0: points
    # {'count', 'time' (s), 'smallest_gap' (m)} over every fine step
    contacts: dict[str, float | None] | None = None
    # each controller's command latency at the end (s), where estimated online
    # (controller.estimate_latency) or in the nodes' pipeline; None otherwise
    latencies: list[float] | None = None

    @property
    def errors(self) -> FloatArray:
        """(R, n, 2) target errors e_i = xb_i - G(s_i) xi of the active curve."""
        return metrics.target_errors(self.poses, self.phase, self.experiment, self.gains,
                                     self.t)

    @property
    def error_norm(self) -> FloatArray:
        """(R,) ||xb_e||, the norm of all agents' stacked errors."""
        return metrics.error_norm(self.errors)

    @property
    def lyapunov(self) -> FloatArray:
        """(R,) the paper's Lyapunov function V with the run's gains and disturbance."""
        return metrics.lyapunov(self.errors, self.dhat, self.experiment, self.disturbance,
                                self.gains)


# The controller settings the batch simulator does not model, where set: (key, is it set,
# why and where to simulate it instead). sim and analyze --compare-sim run the nodes' tick
# pipeline (core.sim.pipeline) for them.
PIPELINE_ONLY: tuple[tuple[str, Callable[[Any], bool], str], ...] = (
    ('controller.command_latency', lambda c: c.command_latency > 0,
     "the batch simulator's robots act on each command at once: simulate a link that late "
     'with core.sim.pipeline.simulate_pipeline (as sim does)'),
    ('controller.observer_order', lambda c: c.observer_order != 1,
     "the batch simulator's observer is first-order: simulate the second-order one with "
     'core.sim.pipeline.simulate_pipeline (as sim does)'),
)


def pipeline_only(experiment: Experiment) -> list[tuple[str, str]]:
    """(key, why) of each controller setting of the experiment that the batch simulator
    does not model and the nodes' tick pipeline does (PIPELINE_ONLY); [] if none is set.
    """
    controller = experiment.spec.controller
    return [(key, why) for key, is_set, why in PIPELINE_ONLY if is_set(controller)]


def _split(dist: FloatArray, on_pc: bool) -> tuple[FloatArray, FloatArray]:
    """(d_pc, d_robot) (n, 2): the disturbance where it is injected, zeros elsewhere."""
    dist = np.ascontiguousarray(dist, dtype=float)
    return (dist, np.zeros_like(dist)) if on_pc else (np.zeros_like(dist), dist)


def simulate(experiment: Experiment, rate_hz: float | None | Literal['config'] = 'config',
             duration: float | None = None, dt: float | None = None,
             record_dt: float | None = None, disturbance: ArrayLike | None = None,
             gains: Gains | None = None, limits: WheelLimits | None = None,
             initial_poses: ArrayLike | None = None, tick_phases: ArrayLike | None = None,
             start_delays: ArrayLike | None = None, avoidance: Avoidance | None = None,
             radius: float | None = None) -> SimResult:
    """Simulate an Experiment; keyword arguments override the file's settings.

    rate_hz: 'config' (the file's controller.rate_hz), None (continuous) or a rate (Hz).
    tick_phases: (n,) fractions in [0, 1) of a control period by which each agent's ticks lag
    (unsynchronised controllers, as the ROS nodes run); default all 0 (synchronous).
    start_delays: (n,) s before each agent's controller starts (zero-order hold only), as
    followers wait for news of the leader; default all 0.
    avoidance: a safety.Avoidance (default the experiment's); radius: the bodies' radius (m;
    default the experiment's robots.radius; 0: points that pass through each other).
    Returns a SimResult.
    """
    spec = experiment.spec
    told = [key for key in ('min_wheel_speed', 'motor_time_constant')
            if spec.limits is not None and getattr(spec.limits, key)]
    if told:
        raise ConfigError(experiment.source, f'limits.{told[0]}', "describes real motors the "
                          "batch simulator's unicycles do not have: simulate them in the "
                          'MuJoCo world (sim --physics mujoco)')
    needs = pipeline_only(experiment)
    if needs:
        raise ConfigError(experiment.source, *needs[0])
    rate_hz = spec.controller.rate_hz if rate_hz == 'config' else rate_hz
    duration = spec.simulation.duration if duration is None else duration
    dt = spec.simulation.dt if dt is None else dt
    record_dt = spec.simulation.record_dt if record_dt is None else record_dt
    gains = experiment.gains if gains is None else gains
    limits = experiment.limits if limits is None else limits
    if gains.reverse and not timed_by(limits):   # forwards only (drive_direction)
        gains = dataclasses.replace(gains, reverse=False)
    avoidance = experiment.avoidance if avoidance is None else avoidance
    radius = experiment.radius if radius is None else radius
    dist = experiment.disturbance if disturbance is None else np.asarray(disturbance, float)
    dist = np.broadcast_to(dist, (experiment.n, 2)).astype(float)
    on_pc = experiment.spec.disturbance.injected == 'on_pc'
    d_pc, d_robot = _split(dist, on_pc)
    varies = bool(experiment.variations)
    poses = np.array(experiment.initial_poses if initial_poses is None else initial_poses,
                     dtype=float)
    record_every = whole_steps(record_dt, dt, 'record_dt')
    control_every = 0 if rate_hz is None else whole_steps(1.0 / rate_hz, dt, 'control period')
    if rate_hz is None:   # an acceleration limit needs a control period
        limits = limits._replace(max_linear_accel=math.inf, max_angular_accel=math.inf)
    phases = np.zeros(experiment.n) if tick_phases is None else np.asarray(tick_phases, float)
    tick_offsets = np.floor(phases * max(control_every, 1)).astype(np.int64)
    delays = np.zeros(experiment.n) if start_delays is None else np.asarray(start_delays, float)
    start_steps = np.round(delays / dt).astype(np.int64)
    total = int(round(duration / dt))
    n_rec = (total - 1) // record_every + 1
    record = (np.zeros((n_rec, experiment.n, 3)), np.zeros((n_rec, experiment.n, 2)),
              np.zeros((n_rec, experiment.n, 2)))
    n = experiment.n
    state = (poses, np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 5)),
             np.ones(n), np.column_stack([np.ones(n), np.zeros((n, 2))]))
    width, height = spec.arena.size if spec.arena is not None else (0.0, 0.0)
    contacts = bodies.contacts_of(n, radius, width, height)
    law = gains.tick_law(rate_hz, on_pc)
    feed_forward = spec.controller.feed_forward
    graph = (*experiment.graph.edge_arrays(), experiment.graph.pins)
    clock = Clock(dt, control_every, record_every)
    if spec.controller.estimate_latency:
        check_replayable(experiment, control_every, record_every, dt)
    ticks = (tick_offsets, start_steps)
    every = experiment.spec.agents.reassign_every
    period = 0 if every is None else whole_steps(every, dt, 'agents.reassign_every')
    # A phase begins at the first step at or after its start (a recorded run's switch falls
    # between steps): no sample before a phase's start carries its targets.
    starts = [int(math.ceil(p.start / dt - 1e-9)) for p in experiment.phases] + [total]
    # The curve server's schedule (core.schedule.curve_schedule: switches, re-assignments, the
    # phases as
    # followed), stepped here; a moving curve is renewed where the schedule needs it (each
    # renewal is a fit): at a re-assignment, and at the phase's last cut (where the next
    # switch assigns from).
    schedule = CurveSchedule(experiment, announce_ahead=0.0)
    schedule.begin(0.0)
    for k, (a, b) in enumerate(zip(starts[:-1], starts[1:], strict=True)):
        if a >= total:
            break
        b = min(b, total)
        schedule.due(experiment.phases[k].start)   # phase k: switched to from step a on
        phase = schedule.phase
        assert phase is not None
        targets = phase.targets
        # The curve server's re-assignment instants, k * period from t = 0.
        reassign = set() if not period else set(range((a // period + 1) * period, b, period))
        # A moving curve's targets are taken afresh at every tick (every MOVING_STEP s
        # without a control rate), with their velocities as the feed-forward.
        moving = phase.motion
        hop = control_every or max(1, int(round(MOVING_STEP / dt)))
        cuts = sorted(reassign | (set(range((a // hop + 1) * hop, b, hop))
                                  if moving or varies else set()))
        still: FloatArray = np.zeros((n, 2))
        for begin, end in zip([a] + cuts, cuts + [b], strict=True):
            if moving is not None and (begin in reassign or end == b):
                schedule.renewal(begin * dt)
            if begin in reassign:
                points = dynamics.offset_points(poses, gains.offset)
                publication = schedule.reassign(points, begin * dt)
                if publication is not None:
                    targets = phase.curve.points(publication.s)
            now, ahead = targets, still
            if moving is not None:
                tau = begin * dt - phase.start
                now = moving.points(targets, tau)
                if feed_forward:
                    ahead = moving.velocities(targets, tau)
            if varies:   # held over each control period (MOVING_STEP without a rate)
                d_pc, d_robot = _split(disturbance_at(dist, experiment.variations, begin * dt),
                                       on_pc)
            if begin == a:   # a curve's first pose: the sooner way outright
                _choose_directions(state, now, law, limits)
            _run(state, np.ascontiguousarray(now), np.ascontiguousarray(ahead), graph, law,
                 limits, avoidance, d_pc, d_robot, clock, begin, end - begin, ticks,
                 contacts, record)
    followed = schedule.close()
    t = np.arange(n_rec) * record_every * dt
    sample_phase = phase_index(np.array(starts[:-1]) * dt, t)
    latencies = None
    if spec.controller.estimate_latency:
        assert rate_hz is not None   # check_replayable
        latencies = held_estimates(experiment, rate_hz, clock, t, record[0], record[2],
                                   (tick_offsets, start_steps))
    if varies:   # the disturbance at each recorded sample
        dist = disturbance_at(dist, experiment.variations, t)
    return SimResult(dataclasses.replace(experiment, phases=tuple(followed)
                                         + experiment.phases[len(followed):]),
                     rate_hz, gains, limits, dist, t, *record, sample_phase,
                     radius, bodies.contact_summary(contacts), latencies)

