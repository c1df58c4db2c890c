"""Load an experiment YAML into a checked, ready-to-run Experiment: the schema first, then
the cheap checks (config.checks), then the curve fits and assignments.

Every problem is raised as ConfigError naming the file, the key and what was expected.
"""

from collections.abc import Sequence
import copy
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pydantic import ValidationError

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.config import safe_yaml
from curve_formation.core.config.checks import (
    body_warnings,
    check_bodies,
    check_camera,
    check_time,
)
from curve_formation.core.config.errors import ConfigError, validation_problem
from curve_formation.core.config.experiment import Experiment, Phase
from curve_formation.core.config.fleet import check_fleet
from curve_formation.core.config.schema import (
    ControllerSpec,
    CurveSpec,
    ExperimentSpec,
    MotionSpec,
)
from curve_formation.core.config.starts import random_poses
from curve_formation.core.config.variations import checked_variations
from curve_formation.core.controller.disturbance import Variation
from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.limits import NO_LIMITS, WheelLimits
from curve_formation.core.controller.safety import Avoidance, AVOIDANCE_OFF
from curve_formation.core.controller.settings import broken_rules, DEFAULT_RATE_HZ, SETTINGS
from curve_formation.core.formation import curve_sources
from curve_formation.core.formation.assignment import (
    AssignmentError,
    phase_parameters,
)
from curve_formation.core.formation.curves import Curve, CurveError, Fit, fit_curve, make_basis
from curve_formation.core.formation.dynamics import offset_points
from curve_formation.core.formation.expressions import ExpressionError
from curve_formation.core.formation.graph import DirectedGraph, Edge, GraphError
from curve_formation.core.formation.motion import CurveMotion


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


def setting_values(spec: ExperimentSpec) -> dict[str, Any]:
    """Every controller setting's value in the file (controller.settings.SETTINGS: its
    default where it or its section is left out), with 'controller.rate_hz' and
    'avoidance.on', as controller.settings.RULES read them.
    """
    values: dict[str, Any] = {}
    for key, declared in SETTINGS.items():
        node: Any = spec
        for part in key.split('.')[:-1]:
            node = None if node is None else getattr(node, part)
        values[key] = declared.default if node is None else getattr(node, declared.name)
    values['controller.rate_hz'] = spec.controller.rate_hz
    values['avoidance.on'] = spec.avoidance is not None
    return values


def check_rules(spec: ExperimentSpec, source: str, **override: Any) -> None:
    """ConfigError naming the key of the first rule between settings the file breaks
    (controller.settings.RULES); override: values to hold instead of the file's, by key.
    """
    for key, problem in broken_rules({**setting_values(spec), **override}):
        raise ConfigError(source, key, problem)


def _build(spec: ExperimentSpec, source: str) -> Experiment:
    n = spec.agents.count
    check_rules(spec, source)
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
    check_fleet(spec, source)
    check_camera(spec, source)
    check_time(spec, source)
    gains = _gains(spec.controller)
    limits = _limits(spec)
    initial = _initial_poses(spec, source)
    phases = tuple(_build_phases(spec, source, offset_points(initial, gains.offset)))
    avoidance = _avoidance(spec, source)
    check_bodies(spec, source, initial, phases)
    try:   # Theorem 1's certificate, O(n^3): after the cheap checks
        graph.certificate()
    except GraphError as exc:
        raise ConfigError(source, 'graph', str(exc)) from None
    return Experiment(spec=spec, source=source, graph=graph, gains=gains,
                      limits=limits, disturbance=_disturbance(spec, source),
                      initial_poses=initial, phases=phases, radius=spec.robots.radius,
                      avoidance=avoidance,
                      warnings=tuple(body_warnings(spec, phases, avoidance, gains.offset)),
                      variations=_variations(spec, source))


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


def _fit_phase_curve(curve_spec: CurveSpec, source: str, key: str) -> Fit:
    """The fitted curve (curves.Fit) of one entry of `curves`."""
    try:
        basis = make_basis(curve_spec.basis, curve_spec.size)
        closed = basis.closed
        if curve_spec.x is not None and curve_spec.y is not None:
            s, pts = curve_sources.expression_samples(curve_spec.x, curve_spec.y,
                                                      curve_spec.samples, closed)
        elif curve_spec.bezier is not None:
            s, pts = curve_sources.bezier_samples(curve_spec.bezier, curve_spec.samples)
        else:
            s, pts = curve_sources.point_samples(curve_spec.points or [], closed)
        fit = fit_curve(basis, s, pts)
    except (CurveError, ExpressionError) as exc:
        raise ConfigError(source, key, str(exc)) from None
    if not fit.curve.size() > 1e-9:
        raise ConfigError(source, key, 'the curve has zero size (all its points coincide): '
                          'the agents would all share one target')
    return fit


def _limits(spec: ExperimentSpec) -> WheelLimits:
    limits = spec.limits
    if limits is None:
        return NO_LIMITS
    return WheelLimits(limits.wheel_base, limits.max_wheel_speed, limits.max_angular_rate,
                       limits.max_linear_accel, limits.max_angular_accel)


def _avoidance(spec: ExperimentSpec, source: str) -> Avoidance:
    """The safety filter's settings (safety.AVOIDANCE_OFF without `avoidance`)."""
    av = spec.avoidance
    if av is None:
        return AVOIDANCE_OFF
    radius = spec.robots.radius
    width, height = spec.arena.size if spec.arena is not None else (0.0, 0.0)
    passing_range = av.passing_range or 2.0 * radius
    return Avoidance(True, radius, av.margin, av.rate, av.passing, passing_range,
                     float(width), float(height), av.drift)


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
    return checked_variations(spec.disturbance.varies, spec.agents.count, source,
                               'disturbance.varies')


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
                 reverse=controller.reverse, observer_growth=controller.observer_growth,
                 observer_order=controller.observer_order)


def check_rate_override(experiment: Experiment, rate_hz: float, option: str = '--rate'
                        ) -> None:
    """ConfigError unless the file's settings pass their rules at rate_hz (Hz), as they would
    with that rate in the file (e.g. the finite-time tail's gain below the rate): a
    command-line override is held to the file's rules.
    """
    for key, problem in broken_rules({**setting_values(experiment.spec),
                                      'controller.rate_hz': rate_hz}):
        raise ConfigError(experiment.source, key, f'with {option} {rate_hz:g}: {problem}')


def with_start(experiment: Experiment, poses: ArrayLike) -> Experiment:
    """The experiment started from `poses` (n, 3): with `assignment: nearest` its agents'
    curve parameters are assigned again from there.
    """
    poses = np.array(poses, dtype=float)
    phases = _assign_phases(experiment.spec, experiment.source,
                            [(p.index, p.start, p.fit) for p in experiment.phases],
                            offset_points(poses, experiment.gains.offset))
    return dataclasses.replace(experiment, initial_poses=poses, phases=tuple(phases))


def control_rate(experiment: Experiment, rate_hz: float | None = None) -> float:
    """The ROS controllers' rate (Hz): the override (ConfigError where the file's controller
    section refuses it: check_rate_override), else the file's, else DEFAULT_RATE_HZ.
    """
    if rate_hz:
        check_rate_override(experiment, rate_hz)
    return float(rate_hz or experiment.spec.controller.rate_hz or DEFAULT_RATE_HZ)
