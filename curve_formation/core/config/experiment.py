"""Load an experiment YAML into checked, ready-to-run objects.

Every problem is raised as :class:`ConfigError` naming the file, the key and what was expected.
"""

from collections.abc import Sequence
import copy
import dataclasses
from dataclasses import dataclass
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pydantic import TypeAdapter, ValidationError

from curve_formation.core.base.shapes import FloatArray, Point
from curve_formation.core.config import safe_yaml
from curve_formation.core.config.marker_ids import MARKER_IDS
from curve_formation.core.config.schema import (
    ControllerSpec,
    CurveSpec,
    ExperimentSpec,
    LimitsSpec,
    MotionSpec,
    RobotsSpec,
    VariationSpec,
)
from curve_formation.core.controller.disturbance import disturbance_at, Variation
from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.limits import NO_LIMITS, timed_by, WheelLimits
from curve_formation.core.controller.safety import Avoidance, AVOIDANCE_OFF
from curve_formation.core.formation import curve_sources
from curve_formation.core.formation.assignment import (
    AssignmentError,
    nearest_order,
    phase_parameters,
)
from curve_formation.core.formation.curve_codec import CurveClock
from curve_formation.core.formation.curves import Curve, CurveError, Fit, fit_curve, make_basis
from curve_formation.core.formation.dynamics import offset_points
from curve_formation.core.formation.expressions import ExpressionError
from curve_formation.core.formation.graph import DirectedGraph, Edge, GraphError
from curve_formation.core.formation.motion import CurveMotion
from curve_formation.core.record.metrics import MAX_STAMP_GAP


# How long (s) before its start a curve that only begins to move where it is gets published
# (Experiment.announce_lead; the curve server's announce_ahead default).
ANNOUNCE_AHEAD = 0.2


class ConfigError(ValueError):
    """An experiment file that cannot be used; the message names file, key and expectation."""

    def __init__(self, source: object, key: str, message: str) -> None:
        self.source, self.key = str(source), key
        super().__init__(f'{source}: {key}: {message}' if key else f'{source}: {message}')


@dataclass(frozen=True)
class Phase:
    """One curve of the schedule: active from `start` (s), fitted, with its agents' targets."""

    index: int
    start: float
    fit: Fit
    s: FloatArray        # (n,) agent parameters
    targets: FloatArray  # (n, 2) G(s_i) xi, arena frame (m)
    g_bar: FloatArray    # (2n, 2H)
    # Re-assignments while the phase was followed: ((t (s), s (n,), targets (n, 2)), ...)
    changes: tuple[tuple[float, FloatArray, FloatArray], ...] = ()
    motion: CurveMotion | None = None   # the curve moves from `start` on

    @property
    def curve(self) -> Curve:
        return self.fit.curve

    def curve_at(self, t: float) -> Curve:
        """The curve at time t (s, experiment time): moved, for a moving phase."""
        return self.curve if self.motion is None else self.motion.curve(self.curve,
                                                                         t - self.start)

    def assigned_from(self, points: FloatArray) -> 'Phase':
        """The phase with its targets permuted among the agents so that the agents headed for
        `points` (n, 2; arena frame, m) take the nearest of them (assignment.nearest_order):
        at a switch after the previous curve's targets were re-assigned, the agents are not
        where the assignment made at load time assumed.
        """
        order = nearest_order(points, self.targets)
        if np.array_equal(order, np.arange(len(order))):
            return self
        s = self.s[order]
        return dataclasses.replace(self, s=s, targets=self.targets[order],
                                   g_bar=self.fit.curve.basis.stacked(s))


@dataclass(frozen=True)
class Experiment:
    """A checked experiment: graph, gains, limits, curve schedule, start poses."""

    spec: ExperimentSpec
    source: str
    graph: DirectedGraph
    gains: Gains
    limits: WheelLimits
    disturbance: FloatArray    # (n, 2) [d_v, d_w]
    initial_poses: FloatArray  # (n, 3)
    phases: tuple[Phase, ...]
    radius: float = 0.0        # bodies (m); 0: points
    avoidance: Avoidance = AVOIDANCE_OFF
    warnings: tuple[str, ...] = ()   # what `check` warns of: possible but questionable
    variations: tuple[Variation, ...] = ()   # the disturbance's changes over time

    def disturbance_at(self, t: ArrayLike) -> FloatArray:
        """(*t.shape, n, 2) the disturbance [d_v, d_w] at times t (s since the first curve)."""
        return disturbance_at(self.disturbance, self.variations, t)

    @property
    def n(self) -> int:
        return self.graph.n

    def tolerance(self, k: int = 0) -> float:
        """Phase k's settling tolerance (m): metrics.tolerance times its curve's size."""
        return self.spec.metrics.tolerance * self.phases[k].curve.size()

    @property
    def name(self) -> str:
        return self.spec.name

    def switched_to(self, phase: Phase, reassigned: bool, targets: FloatArray) -> Phase:
        """The phase a scheduled switch starts: as assigned at load time, or, with `nearest`
        assignment after the previous curve's targets were re-assigned on the way, assigned
        from those targets (n, 2; arena frame, m) as last sent (Phase.assigned_from). The
        curve server and the simulator both switch through here.
        """
        if reassigned and self.spec.agents.assignment == 'nearest':
            return phase.assigned_from(targets)
        return phase

    def announce_lead(self, k: int, current: tuple[Curve, FloatArray] | None, moving: bool,
                      reassigned: bool, targets: FloatArray,
                      ahead: float = ANNOUNCE_AHEAD) -> float:
        """How long (s) before its start phase k is published: `ahead` if it only sets the
        current curve moving (its switched curve and s those of `current`, the (curve, s)
        last published, nothing moving now), so that every controller has it before it
        begins to move; else 0. The curve server and the nodes' pipeline both ask here.
        """
        phase = self.phases[k]
        if ahead <= 0 or phase.motion is None or current is None or moving:
            return 0.0
        switched = self.switched_to(phase, reassigned, targets)
        curve, s = current
        same = (curve.matches(switched.curve)
                and np.allclose(s, switched.s, rtol=0.0, atol=1e-9))
        return ahead if same else 0.0

    def report(self) -> dict[str, Any]:
        """What was checked, as a JSON-ready dict: graph, Theorem 1, Assumptions 1-2, fits."""
        cert = self.graph.certificate()
        return {
            'experiment': self.name, 'source': self.source, 'agents': self.n,
            'leader': self.graph.leader,
            'edges': [[e.source, e.target, e.weight] for e in self.graph.edges],
            'rooted_spanning_tree': True,
            'theorem1': {'P_diagonal': np.diag(cert.P).tolist(),
                         'min_eig_P': cert.min_eig_P, 'min_eig_Q': cert.min_eig_Q},
            'slowest_mode_of_L_plus_B': float(np.linalg.eigvals(
                self.graph.feedback_matrix).real.min()),
            'gains': {'law': self.gains.law, 'k1': self.gains.k1, 'k2': self.gains.k2,
                      'offset': self.gains.offset},
            'curves': [{'start': p.start, 'basis': p.curve.basis.describe(),
                        'fit_rms_residual': p.fit.rms_residual,
                        'fit_max_residual': p.fit.max_residual, 'samples': p.fit.samples,
                        # full, as checked at load (assignment.check_assumptions)
                        'size': p.curve.size(), 'rank_G_bar': min(2 * self.n,
                                                                  2 * p.curve.basis.H),
                        'n_le_H': self.n <= p.curve.basis.H,
                        's': p.s.tolist()} for p in self.phases],
            'bodies': {'radius': self.radius, 'avoidance': self.avoidance.on,
                       'margin': self.avoidance.margin if self.avoidance.on else None},
            'warnings': list(self.warnings),
        }


# What a simulation may ask for: fine steps (compute time), and recorded values (memory:
# samples x agents; 7 float64 each, so 1.8e7 is 1 GB).
MAX_STEPS = 100_000_000
MAX_RECORDED = 18_000_000


def phase_index(starts: ArrayLike, t: ArrayLike) -> np.ndarray:
    """The phase followed at each time t (R,) s: the index of the last phase begun by then,
    from the phases' start times `starts` (s, ascending, on t's clock); 0 before the first.
    The one rule of the simulators, the live run and the analysis of its bag.
    """
    starts = np.asarray(starts, dtype=float)
    return np.clip(np.searchsorted(starts, t, side='right') - 1, 0, max(len(starts) - 1, 0))


def whole_steps(interval: float, dt: float, what: str) -> int:
    """interval (s) as a whole number (>= 1) of steps dt (s); ValueError naming `what`."""
    steps = interval / dt
    if not math.isfinite(steps) or abs(steps - round(steps)) > 1e-6 * max(1.0, steps) \
            or round(steps) < 1:
        raise ValueError(f'{what} ({interval:g} s) must be a whole multiple of dt ({dt:g} s)')
    return int(round(steps))


# Control rate (Hz) of the ROS controllers when the experiment gives none (continuous).
DEFAULT_RATE_HZ = 10.0


def control_rate(experiment: Experiment, rate_hz: float | None = None) -> float:
    """The ROS controllers' rate (Hz): the override (ConfigError where the file's controller
    section refuses it: check_rate_override), else the file's, else DEFAULT_RATE_HZ.
    """
    if rate_hz:
        check_rate_override(experiment, rate_hz)
    return float(rate_hz or experiment.spec.controller.rate_hz or DEFAULT_RATE_HZ)


def wheel_radius(experiment: Experiment) -> float:
    """The wheel radius (m): limits.wheel_radius, or the schema's default without limits."""
    limits = experiment.spec.limits
    return float(limits.wheel_radius if limits is not None
                 else LimitsSpec.model_fields['wheel_radius'].default)


def wheel_base(experiment: Experiment) -> float:
    """Distance between the wheels (m): limits.wheel_base, or a Mona's without limits."""
    from curve_formation.wire import MONA_WHEEL_BASE
    return float(experiment.limits.wheel_base or MONA_WHEEL_BASE)


def check_rate_override(experiment: Experiment, rate_hz: float, option: str = '--rate'
                        ) -> None:
    """ConfigError unless the file's controller section passes its checks at rate_hz (Hz), as
    it would with that rate in the file (e.g. the finite-time tail's gain below the rate): a
    command-line override is held to the file's rules.
    """
    controller = experiment.spec.controller
    try:
        ControllerSpec.model_validate({**controller.model_dump(exclude_unset=True),
                                       'rate_hz': rate_hz})
    except ValidationError as exc:
        key, problem = validation_problem(exc)
        where = 'controller' if key == '(top level)' else f'controller.{key}'
        raise ConfigError(experiment.source, where,
                          f'with {option} {rate_hz:g}: {problem}') from None


def _format_location(loc: Sequence[int | str]) -> str:
    parts = []
    for item in loc:
        if isinstance(item, int):
            parts.append(f'[{item}]')
        else:
            parts.append(('.' if parts else '') + str(item))
    return ''.join(parts) or '(top level)'


def load_experiment(path: str | Path) -> Experiment:
    """Read, validate and build an experiment from a YAML file path."""
    path = Path(path)
    try:
        with open(path, 'rb') as stream:
            data = stream.read(safe_yaml.MAX_BYTES + 1)
    except OSError as exc:
        raise ConfigError(path, '', f'cannot read the file ({exc.strerror})') from None
    return build_experiment(parse_experiment_text(data, str(path)), str(path))


def parse_experiment_text(data: str | bytes, source: str) -> Any:
    """The mapping of an experiment file's bytes or text (core.config.safe_yaml); ConfigError."""
    try:
        return safe_yaml.load(data)
    except safe_yaml.InputError as exc:
        raise ConfigError(source, '', str(exc)) from None


def build_experiment(data: Any, source: str = '<experiment>') -> Experiment:
    """Validate a parsed YAML mapping and build the experiment; `source` names it in errors."""
    if not isinstance(data, dict):
        raise ConfigError(source, '', f'expected a mapping of keys at the top level, got '
                          f'{type(data).__name__}')
    try:
        spec = ExperimentSpec.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(source, *validation_problem(exc)) from None
    return _build(spec, str(source))


def as_in_the_paper(data: dict[str, Any]) -> dict[str, Any]:
    """A copy of an experiment's parsed YAML mapping with the paper's agents, graph and law:
    fixed assignment, no re-assignment, no follower pinning, edge weights 1, no finite-time
    tail, forwards only, no observer growth, point robots (no bodies, no safety filter). The
    reference against which the arena files' additions are measured (tests,
    benchmarks/convergence.py).
    """
    data = copy.deepcopy(data)
    data['agents']['assignment'] = 'fixed'
    data['agents'].pop('reassign_every', None)
    data.pop('robots', None)
    data.pop('avoidance', None)
    data['graph']['pinning'] = 0.0
    for edge in data['graph']['edges']:
        edge.pop('weight', None)
    data['controller'].pop('tail', None)
    data['controller'].pop('reverse', None)
    data['controller'].pop('observer_growth', None)
    return data


def validation_problem(exc: ValidationError) -> tuple[str, str]:
    """(key path, what was wrong and what was given) of a pydantic error's first problem."""
    err = exc.errors()[0]
    more = f' (and {exc.error_count() - 1} more problems)' if exc.error_count() > 1 else ''
    got = (f' (got {safe_yaml.shorten(repr(err["input"]), 80)})'
           if err['type'] != 'missing' and not isinstance(err['input'], dict) else '')
    return _format_location(err['loc']), err['msg'] + got + more


def beside_experiment(experiment: Experiment, value: str | None) -> Path | None:
    """A file an experiment key names: as given when absolute, else relative to the file."""
    if not value:
        return None
    path = Path(value)
    return path if path.is_absolute() else Path(experiment.source).parent / path


def _build(spec: ExperimentSpec, source: str) -> Experiment:
    n = spec.agents.count
    try:
        graph = DirectedGraph(n, [Edge(e.source, e.target, e.weight) for e in spec.graph.edges],
                              leader=spec.graph.leader, follower_pinning=spec.graph.pinning)
    except GraphError as exc:
        raise ConfigError(source, 'graph', str(exc)) from None
    if spec.graph.leader != 1:
        raise ConfigError(source, 'graph.leader', "the leader must be agent 1 (the paper's "
                          f'numbering), got {spec.graph.leader}')
    for k, curve_spec in enumerate(spec.curves):
        key = f'curves[{k}]'
        if k == 0 and curve_spec.start != 0:
            raise ConfigError(source, f'{key}.start', 'the first curve must start at 0')
        if k > 0 and curve_spec.start <= spec.curves[k - 1].start:
            raise ConfigError(source, f'{key}.start', f'switch times must increase, got '
                              f'{curve_spec.start} after {spec.curves[k - 1].start}')
    _check_camera(spec, source)
    _check_time(spec, source)
    gains = _gains(spec.controller)
    limits = _limits(spec)
    if gains.reverse and not timed_by(limits):
        raise ConfigError(source, 'controller.reverse', 'needs limits.wheel_base and '
                          'limits.max_wheel_speed (> 0) to time a trip forwards and backwards')
    if gains.observer_growth > 1 and not timed_by(limits):
        raise ConfigError(source, 'controller.observer_growth', 'needs limits.wheel_base and '
                          'limits.max_wheel_speed (> 0): it acts while the wheel limits '
                          'saturate the command')
    initial = _initial_poses(spec, source)
    phases = tuple(_build_phases(spec, source, offset_points(initial, gains.offset)))
    avoidance = _avoidance(spec, source)
    _check_bodies(spec, source, initial, phases)
    try:   # Theorem 1's certificate, O(n^3): after the cheap checks
        graph.certificate()
    except GraphError as exc:
        raise ConfigError(source, 'graph', str(exc)) from None
    return Experiment(spec=spec, source=source, graph=graph, gains=gains,
                      limits=limits, disturbance=_disturbance(spec, source),
                      initial_poses=initial, phases=phases, radius=spec.robots.radius,
                      avoidance=avoidance,
                      warnings=tuple(_body_warnings(spec, phases, avoidance, gains.offset)),
                      variations=_variations(spec, source))


def with_start(experiment: Experiment, poses: ArrayLike) -> Experiment:
    """The experiment started from `poses` (n, 3): with `assignment: nearest` its agents'
    curve parameters are assigned again from there.
    """
    poses = np.array(poses, dtype=float)
    phases = _assign_phases(experiment.spec, experiment.source,
                            [(p.index, p.start, p.fit) for p in experiment.phases],
                            offset_points(poses, experiment.gains.offset))
    return dataclasses.replace(experiment, initial_poses=poses, phases=tuple(phases))


def point_robots(experiment: Experiment) -> Experiment:
    """The experiment with the formation law alone, as the paper has it: robots are points
    that pass through each other (no bodies), no safety filter, no re-assignment, no online
    estimate of the link's latency.
    """
    spec = experiment.spec
    agents = spec.agents.model_copy(update={'reassign_every': None})
    controller = spec.controller.model_copy(update={'estimate_latency': False})
    spec = spec.model_copy(update={'agents': agents, 'avoidance': None,
                                   'robots': RobotsSpec(), 'controller': controller})
    return dataclasses.replace(experiment, spec=spec, radius=0.0, avoidance=AVOIDANCE_OFF,
                               warnings=())


def received_phases(experiment: Experiment,
                    curves: Sequence[tuple[float, int, Curve, ArrayLike, CurveClock | None]]
                    ) -> tuple[Phase, ...]:
    """The phases a run followed, from the curve messages it received, in order: curves is a
    list of (t, curve id, curve, s, clock) (see ReceivedPhases.add).
    """
    followed = ReceivedPhases(experiment)
    for when, curve_id, curve, given, clock in curves:
        followed.add(when, curve_id, curve, given, clock)
    return followed.phases


class ReceivedPhases:
    """The phases a run followed, folded from its curve messages one at a time (a run of hours
    receives a curve every second or faster: only the phases are kept, not the messages).
    """

    def __init__(self, experiment: Experiment):
        self.experiment = experiment
        self._phases: list[Phase] = []
        self._ids: list[int] = []

    @property
    def phases(self) -> tuple[Phase, ...]:
        return tuple(self._phases)

    def add(self, when: float, curve_id: int, curve: Curve, given: ArrayLike,
            clock: CurveClock | None = None) -> None:
        """One curve message received at `when` (s since the first curve) with its id, the
        agents' parameters s (n,) it carried and its clock (CurveClock on the same time scale
        as `when`, or None). The first message of an id starts a phase; a later one with the
        same id re-assigns its targets (Phase.changes) or, for a moving curve, only renews
        it. A curve equal to the schedule's curve of the same index (moved on as its clock
        says) keeps that phase's fit (residuals) and motion; any other (an observed curve) has
        no fit residual (NaN). A moving phase starts when its clock says it began to move
        (where that is within MAX_STAMP_GAP of the message's arrival); without a clock, from
        its first message on or from earlier, where its renewals show the first came late
        (_moving_since).
        """
        phases = self._phases
        s = np.asarray(given, dtype=float)
        dated = clock is not None and abs(clock.valid_at - when) <= MAX_STAMP_GAP
        if self._ids and curve_id == self._ids[-1]:
            last = phases[-1]
            if last.motion is not None:
                last = phases[-1] = (
                    dataclasses.replace(last, start=clock.motion_began)
                    if dated and clock is not None
                    else _moving_since(last, last.motion, when, curve))
            if not np.array_equal(s, last.changes[-1][1] if last.changes else last.s):
                phases[-1] = dataclasses.replace(   # targets on the curve as it started
                    last, changes=last.changes + ((float(when), s, last.curve.points(s)),))
            return
        k = len(phases)
        scheduled = self.experiment.phases[k] if k < len(self.experiment.phases) else None
        moved = 0.0 if clock is None or not dated else clock.moving_for
        expected = (None if scheduled is None else scheduled.curve if scheduled.motion is None
                    else scheduled.motion.curve(scheduled.curve, moved))
        same = scheduled is not None and expected is not None and expected.matches(curve)
        start = float(when)
        if same and scheduled is not None:
            fit, motion, curve = scheduled.fit, scheduled.motion, scheduled.curve
            if motion is not None and dated and clock is not None:
                start = clock.motion_began
        else:
            fit, motion = Fit(curve, math.nan, math.nan, 0), None
        phases.append(Phase(k, start, fit, s, curve.points(s), curve.basis.stacked(s),
                            motion=motion))
        self._ids.append(curve_id)


def _moving_since(phase: Phase, motion: CurveMotion, when: float, renewal: Curve) -> Phase:
    """A phase moving by `motion` started no later than a renewal received at `when`
    (s) tells: the renewal is the curve `elapsed` s into its motion, so the phase began at
    most `when - elapsed` (the earliest over the renewals: a message only arrives late). A
    reader that joined late gets the first message when the curve has already moved (as a
    latched message, 0.3 s late was seen), and would judge the robots against a curve left
    behind.
    """
    elapsed = motion.elapsed(phase.curve, renewal, when - phase.start)
    if elapsed is None or when - elapsed >= phase.start:
        return phase
    return dataclasses.replace(phase, start=when - elapsed)


def _build_phases(spec: ExperimentSpec, source: str, start_points: FloatArray
                  ) -> list[Phase]:
    fits = [(k, curve_spec.start, _fit_phase_curve(curve_spec, source, f'curves[{k}]'))
            for k, curve_spec in enumerate(spec.curves)]
    motions = [None if curve_spec.motion is None else _motion(curve_spec.motion, fit.curve)
               for (_, _, fit), curve_spec in zip(fits, spec.curves, strict=True)]
    return _assign_phases(spec, source, fits, start_points, motions)


def _motion(spec: MotionSpec, curve: Curve) -> CurveMotion:
    about = spec.about
    if about is None:
        centre = curve.sample(400)[1].mean(axis=0)
        about = (float(centre[0]), float(centre[1]))
    return CurveMotion((spec.velocity[0], spec.velocity[1]), spec.rotation_rate,
                       spec.scale_rate, (about[0], about[1]))


def _assign_phases(spec: ExperimentSpec, source: str,
                   fits: Sequence[tuple[int, float, Fit]], start_points: FloatArray,
                   motions: Sequence[CurveMotion | None] | None = None) -> list[Phase]:
    """Phases (index, start, fit) with their agents' parameters (assignment.phase_parameters),
    each assigned from where the previous one left the agents: the start, then its targets
    (moved with their curve until the next phase starts).
    """
    out: list[Phase] = []
    points = start_points
    motions = motions or [None] * len(fits)
    for k, ((index, start, fit), motion) in enumerate(zip(fits, motions, strict=True)):
        if k and out[-1].motion is not None:
            points = out[-1].motion.points(points, start - out[-1].start)
        try:
            s = phase_parameters(fit.curve, spec.agents.count, spec.agents.spacing,
                                 spec.agents.assignment, points)
        except (AssignmentError, CurveError) as exc:
            raise ConfigError(source, f'curves[{index}]', str(exc)) from None
        points = fit.curve.points(s)   # the next curve is assigned from these
        out.append(Phase(index, start, fit, s, points, fit.curve.basis.stacked(s),
                         motion=motion))
    return out


def _check_time(spec: ExperimentSpec, source: str) -> None:
    """Refuse a simulation that cannot run: periods that are not whole steps, more steps or
    recorded samples than a run can hold.
    """
    sim = spec.simulation
    periods = [('simulation.record_dt', sim.record_dt, 'record_dt')]
    if spec.controller.rate_hz is not None:
        periods.append(('controller.rate_hz', 1.0 / spec.controller.rate_hz, 'the control '
                        'period'))
    if spec.agents.reassign_every is not None:
        periods.append(('agents.reassign_every', spec.agents.reassign_every, 'reassign_every'))
    for key, interval, what in periods:
        try:
            whole_steps(interval, sim.dt, what)
        except ValueError as exc:
            raise ConfigError(source, key, str(exc)) from None
    steps = sim.duration / sim.dt
    if steps > MAX_STEPS:
        raise ConfigError(source, 'simulation', f'duration / dt = {steps:.3g} steps; at most '
                          f'{MAX_STEPS:.0e} (raise dt or shorten the run)')
    recorded = (sim.duration / sim.record_dt + 1) * spec.agents.count
    if recorded > MAX_RECORDED:
        raise ConfigError(source, 'simulation.record_dt', f'{recorded:.3g} recorded agent '
                          f'samples (duration / record_dt x agents); at most '
                          f'{MAX_RECORDED:.1e} (1 GB): raise record_dt')


def _check_camera(spec: ExperimentSpec, source: str) -> None:
    camera = spec.camera
    if camera is None:
        return
    if spec.arena is None:
        raise ConfigError(source, 'camera', 'a camera needs `arena` (its size frames the view)')
    if len(camera.robot_ids) != spec.agents.count:
        raise ConfigError(source, 'camera.robot_ids', f'expected {spec.agents.count} marker '
                          f'ids (one per agent), got {len(camera.robot_ids)}')
    if camera.dictionary not in MARKER_IDS:
        raise ConfigError(source, 'camera.dictionary', f'unknown ArUco dictionary '
                          f'{safe_yaml.shorten(camera.dictionary)!r}; one of '
                          f'{", ".join(sorted(MARKER_IDS))}')
    if (camera.marker_height != camera.corner_height and camera.intrinsics is None
            and camera.intrinsics_file is None):
        raise ConfigError(source, 'camera.marker_height', f'markers '
                          f'{camera.marker_height - camera.corner_height:g} m above the corner '
                          'markers are mapped through the lens: give `intrinsics_file` (from '
                          '`curve-formation calibrate-camera`) or `intrinsics`, or put the '
                          'corner markers at the same height (`corner_height`)')
    size = MARKER_IDS[camera.dictionary]
    too_big = [i for i in camera.robot_ids + [c.id for c in camera.corners] if i >= size]
    if too_big:
        raise ConfigError(source, 'camera', f'marker ids {too_big} do not exist in '
                          f'{camera.dictionary} (ids 0..{size - 1})')


def _fit_phase_curve(curve_spec: CurveSpec, source: str, key: str) -> Fit:
    """The fitted curve (curves.Fit) of one entry of `curves`."""
    try:
        basis = make_basis(curve_spec.basis, curve_spec.size)
        closed = basis.closed
        if curve_spec.x is not None:
            s, pts = curve_sources.expression_samples(curve_spec.x, curve_spec.y,
                                                      curve_spec.samples, closed)
        elif curve_spec.bezier is not None:
            s, pts = curve_sources.bezier_samples(curve_spec.bezier, curve_spec.samples)
        else:
            s, pts = curve_sources.point_samples(curve_spec.points, closed)
        fit = fit_curve(basis, s, pts)
    except (CurveError, ExpressionError) as exc:
        raise ConfigError(source, key, str(exc)) from None
    if not fit.curve.size() > 1e-9:
        raise ConfigError(source, key, 'the curve has zero size (all its points coincide): '
                          'the agents would all share one target')
    return fit


def _limits(spec: ExperimentSpec) -> WheelLimits:
    if spec.limits is None:
        return NO_LIMITS
    limits = spec.limits

    def given(value: float | None) -> float:
        return math.inf if value is None else value
    return WheelLimits(limits.wheel_base, limits.max_wheel_speed,
                       given(limits.max_angular_rate), given(limits.max_linear_accel),
                       given(limits.max_angular_accel))


def _avoidance(spec: ExperimentSpec, source: str) -> Avoidance:
    """The safety filter's settings (safety.AVOIDANCE_OFF without `avoidance`)."""
    av = spec.avoidance
    if av is None:
        return AVOIDANCE_OFF
    rate = spec.controller.rate_hz
    if rate is not None and av.rate > rate:
        raise ConfigError(source, 'avoidance.rate', f'the barrier rate must not exceed the '
                          f'control rate ({rate:g} Hz), got {av.rate:g} /s: a robot could '
                          'close more than the whole distance to the safe one in one tick')
    radius = spec.robots.radius
    width, height = spec.arena.size if spec.arena is not None else (0.0, 0.0)
    passing_range = av.passing_range if av.passing_range is not None else 2.0 * radius
    return Avoidance(True, radius, av.margin, av.rate, av.passing, passing_range,
                     float(width), float(height), av.drift)


def _check_bodies(spec: ExperimentSpec, source: str, poses: FloatArray,
                  phases: Sequence[Phase]) -> None:
    """Refuse bodies that start overlapping or through a wall, and curves outside the arena."""
    from scipy.spatial.distance import pdist  # scipy.spatial: 0.4 s to import
    radius = spec.robots.radius
    if radius > 0 and len(poses) > 1:
        gaps = pdist(poses[:, :2])
        pairs = [(i, j) for i in range(len(poses)) for j in range(i + 1, len(poses))]
        k = int(np.argmin(gaps))
        if gaps[k] < 2 * radius:
            i, j = pairs[k]
            raise ConfigError(source, 'agents.initial', f'agents {i + 1} and {j + 1} start '
                              f'{gaps[k]:.3f} m apart: their bodies (robots.radius {radius:g} '
                              'm) overlap')
    if spec.arena is None:
        return
    width, height = spec.arena.size
    if radius > 0:
        out = np.flatnonzero((poses[:, 0] < radius) | (poses[:, 0] > width - radius)
                             | (poses[:, 1] < radius) | (poses[:, 1] > height - radius))
        if out.size:
            raise ConfigError(source, 'agents.initial', f'agent {out[0] + 1} starts at '
                              f'{poses[out[0], :2].tolist()}: its body (robots.radius '
                              f'{radius:g} m) crosses the arena wall')
    ends = [p.start for p in phases[1:]] + [spec.simulation.duration]
    for phase, end in zip(phases, ends, strict=True):
        _, points = phase.curve.sample(2000)
        moving = ''
        if phase.motion is not None:   # wherever it moves to before the next curve
            taus = np.linspace(0.0, max(end - phase.start, 0.0), 51)
            points = np.concatenate([phase.motion.points(points, tau) for tau in taus])
            moving = f' by t = {end:g} s, moving'
        problem = points_outside_arena(points, width, height, radius)
        if problem is not None:
            raise ConfigError(source, f'curves[{phase.index}]', f'the curve leaves the arena'
                              f'{moving} {problem}')


def points_outside_arena(points: FloatArray, width: float, height: float,
                         radius: float = 0.0) -> str | None:
    """Why points (m, 2; arena frame) do not all lie in the arena [0, width] x [0, height] m
    with a body's radius to spare (e.g. a curve's samples), or None when they do.
    """
    low, high = points.min(axis=0), points.max(axis=0)
    if (low < radius).any() or high[0] > width - radius or high[1] > height - radius:
        return (f'[0, {width:g}] x [0, {height:g}] m (it spans x {low[0]:.4g}..{high[0]:.4g}, '
                f'y {low[1]:.4g}..{high[1]:.4g}'
                + (f', robots.radius {radius:g} m' if radius else '') + ')')
    return None


def _body_warnings(spec: ExperimentSpec, phases: Sequence[Phase], avoidance: Avoidance,
                   offset: float) -> list[str]:
    """Targets closer than the bodies allow: to each other, and to the walls."""
    from scipy.spatial.distance import pdist  # scipy.spatial: 0.4 s to import
    if not avoidance.on and spec.robots.radius <= 0:
        return []
    out = []
    radius = spec.robots.radius
    margin = avoidance.margin if avoidance.on else 0.0
    apart = 2 * radius + 2 * abs(offset) + margin
    for phase in phases:
        if len(phase.targets) > 1:
            gaps = pdist(phase.targets)
            if gaps.min() < apart:
                out.append(f'curves[{phase.index}]: two targets are {gaps.min():.3f} m apart, '
                           f'less than bodies allow ({apart:.3f} m: 2 robots.radius + 2 |l| + '
                           'avoidance.margin); those robots cannot both settle (try spacing: '
                           'arc_length)')
        if spec.arena is not None:
            width, height = spec.arena.size
            wall = radius + abs(offset) + 0.5 * margin
            t = phase.targets
            near = np.minimum.reduce([t[:, 0], width - t[:, 0], t[:, 1], height - t[:, 1]])
            if near.min() < wall:
                out.append(f'curves[{phase.index}]: a target is {near.min():.3f} m from a '
                           f'wall, less than a body allows ({wall:.3f} m)')
    return out


def _disturbance(spec: ExperimentSpec, source: str) -> FloatArray:
    n = spec.agents.count
    dist = spec.disturbance
    if dist.per_agent is not None:
        if len(dist.per_agent) != n:
            raise ConfigError(source, 'disturbance.per_agent', f'expected {n} [d_v, d_w] pairs '
                              f'(one per agent), got {len(dist.per_agent)}')
        return np.array(dist.per_agent, dtype=float)
    return np.tile(np.array(dist.value if dist.value is not None else (0.0, 0.0)), (n, 1))


def _variations(spec: ExperimentSpec, source: str) -> tuple[Variation, ...]:
    return _checked_variations(spec.disturbance.varies, spec.agents.count, source,
                               'disturbance.varies')


def _checked_variations(specs: Sequence[VariationSpec], n: int | None, source: str, key: str
                        ) -> tuple[Variation, ...]:
    out = []
    for k, v in enumerate(specs):
        agents = v.agents or []
        wrong = [i for i in agents if not 1 <= i <= (n or i)]
        if wrong or len(set(agents)) != len(agents):
            raise ConfigError(source, f'{key}[{k}].agents', f'expected distinct agents among '
                              f'1..{n or "n"}, got {agents}')
        fields = {name: value for name, value in v.model_dump(exclude={'agents'}).items()
                  if value is not None}
        out.append(Variation(**fields, agents=tuple(i - 1 for i in agents)))
    return tuple(out)


def variations_text(experiment: Experiment) -> str:
    """The experiment's disturbance.varies as JSON ('' if constant), for a node parameter."""
    varies = experiment.spec.disturbance.varies
    return json.dumps([v.model_dump(exclude_none=True) for v in varies]) if varies else ''


def variations_from_text(text: str, n: int | None, source: str) -> tuple[Variation, ...]:
    """Variations from the JSON (or YAML) list a node parameter holds ('' = none), checked as
    the experiment's `disturbance.varies` for n agents (None: any number); ConfigError naming
    `source`.
    """
    if not text.strip():
        return ()
    try:
        specs = TypeAdapter(list[VariationSpec]).validate_python(safe_yaml.load(text))
    except ValidationError as exc:
        key, problem = validation_problem(exc)
        raise ConfigError(source, f'varies{key if key.startswith("[") else "." + key}',
                          problem) from None
    except ValueError as exc:   # not YAML
        raise ConfigError(source, 'varies', str(exc)) from None
    return _checked_variations(specs, n, source, 'varies')


MAX_DRAWS_PER_ROBOT = 1000


def random_poses(n: int, center: Point, half_width: Point, seed: int | None,
                 min_separation: float = 0.0) -> FloatArray:
    """(n, 3) poses uniform in the box center +- half_width (m), headings uniform (rad).

    With min_separation (m) > 0 each position is redrawn until it keeps that distance from
    the ones before; ValueError if the box cannot hold them.
    """
    rng = np.random.default_rng(seed)
    middle = np.asarray(center, float)
    half = np.asarray(half_width, float)
    if min_separation <= 0:
        return np.column_stack([rng.uniform(middle - half, middle + half, size=(n, 2)),
                                rng.uniform(-math.pi, math.pi, size=n)])
    points: list[FloatArray] = []
    for _ in range(n):
        for _ in range(MAX_DRAWS_PER_ROBOT):
            p = rng.uniform(middle - half, middle + half)
            if all(np.hypot(*(p - q)) >= min_separation for q in points):
                points.append(p)
                break
        else:
            raise ValueError(f'cannot place {n} robots {min_separation} m apart in the start '
                             f'box (placed {len(points)})')
    return np.column_stack([np.array(points), rng.uniform(-math.pi, math.pi, size=n)])


def seeded_start(experiment: Experiment, seed: int) -> FloatArray:
    """The experiment's random start box drawn with another seed (ValueError if it has none)."""
    box = experiment.spec.agents.initial.random
    if box is None:
        raise ValueError(f'{experiment.source}: agents.initial: no random start box to reseed')
    return random_poses(experiment.n, box.center, box.half_width, seed, box.min_separation)


def _initial_poses(spec: ExperimentSpec, source: str) -> FloatArray:
    n = spec.agents.count
    initial = spec.agents.initial
    if initial.poses is not None:
        if len(initial.poses) != n:
            raise ConfigError(source, 'agents.initial.poses', f'expected {n} [x, y, theta] '
                              f'poses (one per agent), got {len(initial.poses)}')
        poses = np.array(initial.poses, dtype=float)
    else:
        box = initial.random
        assert box is not None   # the schema asks for poses or a random box
        try:
            poses = random_poses(n, box.center, box.half_width, box.seed, box.min_separation)
        except ValueError as exc:
            raise ConfigError(source, 'agents.initial.random.min_separation', str(exc)) from None
    if spec.arena is not None:
        width, height = spec.arena.size
        outside = np.flatnonzero((poses[:, 0] < 0) | (poses[:, 0] > width)
                                 | (poses[:, 1] < 0) | (poses[:, 1] > height))
        if outside.size:
            raise ConfigError(source, 'agents.initial', f'agent {outside[0] + 1} starts at '
                              f'{poses[outside[0], :2].tolist()}, outside the arena '
                              f'[0, {width}] x [0, {height}] m')
    return poses


def _gains(controller: ControllerSpec) -> Gains:
    return Gains(controller.k1, controller.k2, controller.offset, law=controller.law,
                 adaptation=(controller.adaptation[0], controller.adaptation[1]),
                 observer_rate=controller.observer_rate,
                 sampled_heading=controller.heading == 'sampled',
                 tail_radius=controller.tail.radius if controller.tail else 0.0,
                 tail_gain=controller.tail.gain if controller.tail else 1.0,
                 reverse=controller.reverse, observer_growth=controller.observer_growth)
