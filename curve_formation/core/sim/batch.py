"""Batch simulator: n unicycles with constant or varying input disturbance under the
formation law, its curves switched and re-assigned as the curve server does
(schedule.curve_schedule), stepped by the compiled kernel (sim.kernel), whose control step
is the ROS controller's own (controller.step.agent_step).

Two control modes: continuous (the paper's setting) or a zero-order hold at `rate_hz`, which
is what the ROS controller nodes do. Laws (core.controller.gains.LAWS): paper, adaptive
(per-channel estimator gains), observer (first or second order).
"""

import dataclasses
from dataclasses import dataclass
import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.jit import one_compiler_at_a_time
from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.experiment import (
    ANNOUNCE_AHEAD,
    Experiment,
    phase_index,
    whole_steps,
)
from curve_formation.core.controller import driving
from curve_formation.core.controller.curve_targets import moving_share
from curve_formation.core.controller.disturbance import disturbance_at
from curve_formation.core.controller.gains import Gains, Law
from curve_formation.core.controller.inputs import shared_clock
from curve_formation.core.controller.limits import timed_by, WheelLimits
from curve_formation.core.controller.others import OTHERS_KEPT
from curve_formation.core.controller.robot_model import commands_kept
from curve_formation.core.controller.safety import Avoidance, with_latency
from curve_formation.core.formation import dynamics
from curve_formation.core.formation.motion import CurveMotion
from curve_formation.core.record import metrics
from curve_formation.core.schedule.curve_schedule import CurveSchedule
from curve_formation.core.sim.estimate_replay import (
    check_replayable,
    EstimateTakenError,
    held_estimates,
)
from curve_formation.core.sim.kernel import (
    Clock,
    Delay,
    edge_arrays,
    initial_state,
    NO_DELAY,
    run,
    SimState,
)
from curve_formation.core.world import bodies


# How often (s) a moving curve's targets are renewed under continuous control.
MOVING_STEP = 0.01


def _choose_directions(state: SimState, targets: FloatArray, law: Law,
                       limits: WheelLimits) -> None:
    """Each robot's drive direction (state's fronts) as a curve's first pose sets it in the
    node (driving.drive_direction with no hysteresis), towards targets (n, 2; m).
    """
    poses, dhat, fronts = state.poses, state.dhat, state.fronts
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
    # each controller's motors' lag at the end (s), as told or estimated online
    # (controller.estimate_motors); None where not estimated
    motor_lags: list[float] | None = None
    # each controller's (left, right) wheel gains as estimated online (estimate_motors; None
    # for one that told none), where estimated
    wheel_gains: list[tuple[float, float] | None] | None = None
    # each controller's motors' dead band (m/s of wheel speed) as told or estimated online
    # (estimate_motors; None for one that took none), where estimated
    dead_bands: list[float | None] | None = None
    # each controller's robot as it held it at the end, each value with its bound and
    # source (RobotModel.estimates), where the nodes' pipeline ran
    estimates: list[dict[str, object]] | None = None

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


def _announced(schedule: CurveSchedule, k: int, reach: float, dt: float
               ) -> tuple[CurveMotion, int] | None:
    """Phase k's motion and the first step (dt s each) whose commands hold past its start
    where the curve server announces it ahead (it only sets the current curve moving:
    Experiment.announce_lead) and a command holds until `reach` s after it is sent (its
    latency, if the controllers aim where the targets are when it acts, plus a period);
    else None.
    """
    phases = schedule.experiment.phases
    motion = phases[k].motion if 0 < k < len(phases) else None
    lead = schedule.lead(k, ANNOUNCE_AHEAD) if reach > 0.0 and motion is not None else 0.0
    if motion is None or lead <= 0.0:
        return None
    return motion, int(math.ceil((phases[k].start - min(reach, lead)) / dt - 1e-9))


def _refuse_unmodelled(experiment: Experiment, rate_hz: float | None) -> None:
    """ConfigError naming a setting of the experiment that the batch simulator cannot run:
    told motors (its unicycles have none), or, under continuous control (rate_hz None), a
    command latency or the second-order observer (both act at ticks).
    """
    spec = experiment.spec
    told = [key for key in ('min_wheel_speed', 'motor_time_constant')
            if spec.limits is not None and getattr(spec.limits, key)]
    if told:
        raise ConfigError(experiment.source, f'limits.{told[0]}', "describes real motors the "
                          "batch simulator's unicycles do not have: simulate them in the "
                          'MuJoCo world (sim --physics mujoco)')
    if spec.controller.motor_check:
        raise EstimateTakenError(experiment.source, 'controller.motor_check',
                                 'each robot first turns in place while its motors are '
                                 "measured, which the batch simulator's unicycles do not do: "
                                 'simulate it with core.sim.pipeline.simulate_pipeline (as '
                                 'sim does)')
    if rate_hz is None and spec.controller.command_latency > 0.0:
        raise ConfigError(experiment.source, 'controller.command_latency',
                          'commands that act late are sent at ticks: it needs a control rate '
                          '(controller.rate_hz), not continuous control')
    if rate_hz is None and spec.controller.observer_order != 1:
        raise ConfigError(experiment.source, 'controller.observer_order',
                          'the second-order observer updates at ticks: it needs a control '
                          'rate (controller.rate_hz), not continuous control')


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
    rate_hz = spec.controller.rate_hz if rate_hz == 'config' else rate_hz
    _refuse_unmodelled(experiment, rate_hz)
    latency = spec.controller.command_latency
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
    delay = NO_DELAY
    if rate_hz is not None:
        delay = Delay(latency, spec.controller.predict_pose,
                      shared_clock(spec.safety.pose_timeout),
                      int(math.floor(OTHERS_KEPT * rate_hz)) + 2)
        avoidance = with_latency(avoidance, 1.0 / rate_hz, latency)
    state = initial_state(poses, commands_kept(rate_hz or 1.0, spec.safety.pose_timeout,
                                               latency), delay)
    width, height = spec.arena.size if spec.arena is not None else (0.0, 0.0)
    contacts = bodies.contacts_of(n, radius, width, height)
    law = gains.tick_law(rate_hz, on_pc)
    feed_forward = spec.controller.feed_forward
    graph = edge_arrays(*experiment.graph.edge_arrays(), experiment.graph.pins)
    clock = Clock(dt, control_every, record_every)
    if spec.controller.estimate_latency or spec.controller.estimate_motors:
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
        # commands that act after the start of a next curve announced ahead aim at it
        aim = latency if delay.predict else 0.0   # s from a tick to where it aims
        following = _announced(schedule, k + 1, aim + control_every * dt, dt)
        first = a if moving or varies else b if following is None else max(a, following[1])
        cuts = sorted((reassign | set(range(-(-first // hop) * hop, b, hop))) - {a})
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
            aimed = now
            if moving is not None:
                tau = begin * dt - phase.start
                now = aimed = moving.points(targets, tau)
                if aim > 0.0:   # where they are when commands act
                    aimed = moving.points(targets, tau + aim)
                if feed_forward:
                    ahead = moving.velocities(targets, tau)
            if (following is not None and begin >= following[1]
                    and schedule.lead(k + 1, ANNOUNCE_AHEAD) > 0.0):
                # as the controllers have it once announced: its targets where they are
                # when the command acts, its velocity over the part of the command's period
                # after its start (AgentController._tick)
                starts_moving = experiment.phases[k + 1].start
                tau = max(begin * dt + aim - starts_moving, 0.0)
                aimed = following[0].points(targets, tau)
                if feed_forward:
                    ahead = (following[0].velocities(targets, tau)
                             * moving_share(begin * dt + aim, control_every * dt,
                                            starts_moving))
            if varies:   # held over each control period (MOVING_STEP without a rate)
                d_pc, d_robot = _split(disturbance_at(dist, experiment.variations, begin * dt),
                                       on_pc)
            if begin == a:   # a curve's first pose: the sooner way outright
                _choose_directions(state, now, law, limits)
            # simulations started side by side on a cold cache share one compilation
            with one_compiler_at_a_time(run.py_func):
                run(state, np.ascontiguousarray(now), np.ascontiguousarray(aimed),
                    np.ascontiguousarray(ahead), graph, law,
                    limits, avoidance, d_pc, d_robot, clock, delay, begin, end - begin, ticks,
                    contacts, record)
    followed = schedule.close()
    t = np.arange(n_rec) * record_every * dt
    sample_phase = phase_index(np.array(starts[:-1]) * dt, t)
    latencies = None
    if spec.controller.estimate_latency or spec.controller.estimate_motors:
        assert rate_hz is not None   # check_replayable
        latencies = held_estimates(experiment, rate_hz, clock, t, record[0], record[2],
                                   (tick_offsets, start_steps))
    if varies:   # the disturbance at each recorded sample
        dist = disturbance_at(dist, experiment.variations, t)
    return SimResult(dataclasses.replace(experiment, phases=tuple(followed)
                                         + experiment.phases[len(followed):]),
                     rate_hz, gains, limits, dist, t, *record, sample_phase,
                     radius, bodies.contact_summary(contacts), latencies)

