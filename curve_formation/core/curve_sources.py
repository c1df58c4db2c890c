"""Where a desired curve comes from: expressions in s, Bezier control points, sampled points.

Each source yields samples (s, points) that :func:`curves.fit_curve` turns into coefficients.
"""

from math import comb

import numpy as np

from curve_formation.core.curves import CurveError
from curve_formation.core.expressions import Expression


def expression_samples(x_text, y_text, count, closed):
    """Sample c(s) = (x(s), y(s)) given as expressions at count values of s.

    Closed curves are sampled on [0, 1) (s = 1 repeats s = 0), open ones on [0, 1].
    Returns (s (count,), points (count, 2)).
    """
    s = np.linspace(0.0, 1.0, count, endpoint=not closed)
    return s, np.column_stack([Expression(x_text)(s), Expression(y_text)(s)])


def bezier_samples(control_points, count):
    """Sample the Bezier curve of the given control points ((m, 2), degree m - 1) on [0, 1]."""
    ctrl = np.asarray(control_points, dtype=float)
    if ctrl.ndim != 2 or ctrl.shape[1] != 2 or len(ctrl) < 2:
        raise CurveError(f'Bezier control points must be a list of at least two [x, y] pairs, '
                         f'got shape {ctrl.shape}')
    s = np.linspace(0.0, 1.0, count)
    degree = len(ctrl) - 1
    weights = np.column_stack([comb(degree, k) * s ** k * (1 - s) ** (degree - k)
                               for k in range(degree + 1)])
    return s, weights @ ctrl


def chord_length_parameters(points, closed):
    """Curve parameters for an ordered list of points, proportional to chord length.

    For a closed curve the closing chord (last -> first) counts, so s stays in [0, 1).
    Returns s (N,) in [0, 1].
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise CurveError(f'sampled points must be a list of [x, y] pairs, got shape {pts.shape}')
    if not np.all(np.isfinite(pts)):
        raise CurveError('sampled points contain NaN or infinity')
    chords = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]) if closed else pts, axis=0),
                            axis=1)
    if np.any(chords[: len(pts) - 1] == 0):
        raise CurveError('sampled points contain consecutive duplicates')
    total = chords.sum()
    return np.concatenate([[0.0], np.cumsum(chords)])[: len(pts)] / total


def point_samples(points, closed):
    """Samples (s, points) for an ordered list of observed points, parameterised by chord."""
    pts = np.asarray(points, dtype=float)
    return chord_length_parameters(pts, closed), pts
