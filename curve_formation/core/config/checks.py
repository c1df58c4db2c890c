"""Checks of an experiment beyond its schema, each refused as ConfigError naming the key:
times and steps, the camera's marker ids, bodies that overlap or leave the arena.
"""

from collections.abc import Sequence

import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.config import safe_yaml
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.experiment import MAX_RECORDED, MAX_STEPS, Phase, whole_steps
from curve_formation.core.config.marker_ids import MARKER_IDS
from curve_formation.core.config.schema import ExperimentSpec
from curve_formation.core.controller.safety import Avoidance


def check_time(spec: ExperimentSpec, source: str) -> None:
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


def check_camera(spec: ExperimentSpec, source: str) -> None:
    camera = spec.camera
    if camera is None:
        return
    if spec.arena is None:
        raise ConfigError(source, 'camera', 'a camera needs `arena` (its size frames the view)')
    if len(camera.robot_ids) != spec.agents.count:
        raise ConfigError(source, 'camera.robot_ids', f'expected {spec.agents.count} marker '
                          f'ids (one per agent, here or as robots.fleet[].marker), got '
                          f'{len(camera.robot_ids)}')
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


def check_bodies(spec: ExperimentSpec, source: str, poses: FloatArray,
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


def body_warnings(spec: ExperimentSpec, phases: Sequence[Phase], avoidance: Avoidance,
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
