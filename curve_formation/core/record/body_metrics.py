"""Metrics of the robots' bodies over a run: the closest approach, the longest standstill
away from a target, the smallest surface gaps, markers a body covers, and the contact tally.

Poses (R, n, 3) in the arena frame (m, rad); times in s.
"""

from collections.abc import Sequence
import math
from typing import Any

import numpy as np

from curve_formation.core.base.shapes import BoolArray, FloatArray
from curve_formation.core.formation.dynamics import marker_centres


def nearest_pairs(poses: FloatArray, batch: int = 1 << 18) -> FloatArray:
    """(R,) the smallest distance (m) between two robots' axle centres at each sample; robots
    not seen yet (NaN) count as infinitely far (inf with fewer than two robots). Worked out a
    few samples at a time (about `batch` pairs): never the whole R x n x n array.
    """
    xy = np.asarray(poses, float)[:, :, :2]
    n = xy.shape[1]
    out = np.full(len(xy), np.inf)
    if n < 2:
        return out
    first, second = np.triu_indices(n, 1)
    rows = max(1, batch // len(first))
    for a in range(0, len(xy), rows):
        chunk = xy[a:a + rows]
        dx = chunk[:, first, 0] - chunk[:, second, 0]
        dy = chunk[:, first, 1] - chunk[:, second, 1]
        squares = dx * dx + dy * dy
        out[a:a + rows] = np.fmin.reduce(squares, axis=1, initial=np.inf)   # NaN skipped
    return np.sqrt(out)


def closest_approach(poses: FloatArray) -> tuple[float, int]:
    """Smallest distance (m) between two robots' axle centres over a run, with when (index).

    The law has no collision avoidance: compare with the robots' size.
    """
    if poses.shape[1] < 2:
        return float('inf'), 0
    per_row = nearest_pairs(poses)
    k = int(np.argmin(per_row))
    return float(per_row[k]), k


def longest_standstill(t: FloatArray, poses: FloatArray, errors: FloatArray, away: float = 0.03,
                       still: float = 1e-3) -> tuple[float, int, float]:
    """The longest time (s) one robot stood still (axle centre slower than `still`, m/s)
    while more than `away` (m) from its target, with which robot (index) and when it ended
    (s): waiting to give way, or a deadlock. t (R,), poses (R, n, 3), errors (R, n): each
    robot's distance to its target (m). (0.0, -1, nan) if none ever did.
    """
    t = np.asarray(t, float)
    if len(t) < 2:
        return 0.0, -1, math.nan
    speed = np.linalg.norm(np.diff(poses[:, :, :2], axis=0), axis=2) / np.diff(t)[:, None]
    standing = (speed < still) & (np.asarray(errors)[1:] > away)
    best = (0.0, -1, math.nan)
    for i in range(standing.shape[1]):
        # runs of True: starts and ends as indices into the R - 1 intervals
        edges = np.diff(np.concatenate([[0], standing[:, i].astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            if t[b] - t[a] > best[0]:
                best = (float(t[b] - t[a]), i, float(t[b]))
    return best


def surface_gaps(poses: FloatArray, radius: float) -> FloatArray:
    """(R,) smallest distance (m) between two bodies' surfaces at each sample (inf: fewer than
    two robots seen).
    """
    return nearest_pairs(poses) - 2 * radius


def markers_covered(poses: FloatArray, radius: float, marker_offset: Sequence[float],
                    marker_size: float) -> BoolArray:
    """(R,) whether some robot's body covers part of another robot's marker (a square of
    marker_size at marker_offset, robot frame): its centre is within radius plus the marker's
    half-diagonal of the marker's centre.
    """
    centres = marker_centres(poses, marker_offset)
    reach = radius + marker_size / np.sqrt(2)
    near = np.linalg.norm(centres[:, :, None, :] - poses[:, None, :, :2], axis=3) < reach
    n = poses.shape[1]
    near[:, np.arange(n), np.arange(n)] = False
    return near.any(axis=(1, 2))


def body_metrics(experiment: Any, t: FloatArray, poses: FloatArray,
                 contacts: dict[str, Any] | None = None, unseen: BoolArray | None = None
                 ) -> dict[str, Any]:
    """Bodies in the arena: contacts (count and total time, counted where the bodies are
    simulated: `contacts`), the smallest gap between two surfaces (exact from `contacts`,
    else from the samples), and how long some robot's marker was hidden: from `unseen`
    (R, n), the robots a camera did not see, else where a body covered another's marker.
    """
    radius = experiment.radius
    gaps = surface_gaps(poses, radius)
    sampled = float(np.nanmin(gaps)) if len(gaps) else None
    out = {'radius': radius, 'smallest_gap_sampled': sampled,
           'contacts': None if contacts is None else {
               key: contacts[key] for key in ('count', 'time', 'walls', 'largest_push')
               if key in contacts},
           'smallest_gap': (contacts.get('smallest_gap') if contacts is not None
                            and contacts.get('smallest_gap') is not None else sampled)}
    if unseen is not None and len(unseen) == len(t):
        hidden = np.asarray(unseen).any(axis=1)
    elif experiment.spec.camera is not None:
        camera = experiment.spec.camera
        hidden = markers_covered(poses, radius, camera.marker_offset, camera.marker_size)
    else:
        hidden = None
    if hidden is not None:
        period = np.diff(t, append=t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.0))
        out['marker_hidden_time'] = float(period[hidden].sum())
    return out
