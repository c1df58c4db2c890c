"""Random starts: robots placed uniformly in a box with random headings, from a seed.

Poses (x, y, theta) in the arena frame (m, rad).
"""

import math

import numpy as np

from curve_formation.core.base.shapes import FloatArray, Point
from curve_formation.core.config.experiment import Experiment


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
