"""Curve parameters s_i of the agents and the paper's Assumptions 1 and 2."""

import numpy as np

from curve_formation.core.curves import CurveError


SPACINGS = ('uniform_s', 'arc_length')


class AssignmentError(ValueError):
    """Agent parameters the controller's proof does not cover."""


def uniform_parameters(n, closed):
    """The paper's s_i = (i-1)/n on closed curves; (i-1)/(n-1) on open ones (both ends)."""
    if n == 1:
        return np.zeros(1)
    return np.arange(n) / (n if closed else n - 1)


def arc_length_parameters(curve, n):
    """s_i that split the curve into equal arc lengths (closed: n gaps incl. the closing one)."""
    s_table, length = curve.arc_length_table()
    total = length[-1]
    if total <= 0:
        raise CurveError('the curve has zero length; arc-length spacing is undefined')
    fractions = uniform_parameters(n, curve.basis.closed)
    return np.interp(fractions * total, length, s_table)


def agent_parameters(curve, n, spacing='uniform_s'):
    """s (n,) for n agents on `curve` with spacing 'uniform_s' (paper) or 'arc_length'."""
    if spacing == 'uniform_s':
        return uniform_parameters(n, curve.basis.closed)
    if spacing == 'arc_length':
        return arc_length_parameters(curve, n)
    raise AssignmentError(f'unknown spacing {spacing!r}; expected one of {SPACINGS}')


def check_assumptions(basis, s):
    """Refuse s that break Assumption 1 (rank G_bar = min(2n, 2H)) or 2 (n <= H).

    Also refuses duplicate s_i (two agents sent to one point; on closed curves s and s+1 are
    the same point). Returns G_bar (2n, 2H).
    """
    s = np.asarray(s, dtype=float)
    n = len(s)
    if n > basis.H:
        raise AssignmentError(f'Assumption 2 fails: n = {n} agents but only H = {basis.H} basis '
                              f'functions ({basis.describe()}); use at least {n} basis functions')
    if np.any((s < 0) | (s > 1)):
        raise AssignmentError(f'agent parameters must lie in [0, 1], got {s.tolist()}')
    key = np.mod(s, 1.0) if basis.closed else s
    order = np.sort(key)
    gaps = np.diff(np.append(order, order[0] + 1.0) if basis.closed else order)
    if np.any(gaps < 1e-9):
        first = order[np.argmin(gaps)]
        raise AssignmentError(f'two agents share the curve parameter s = {first:.6g}')
    g_bar = basis.G(s).reshape(2 * n, 2 * basis.H)
    rank = np.linalg.matrix_rank(g_bar)
    if rank != min(2 * n, 2 * basis.H):
        raise AssignmentError(f'Assumption 1 fails: rank of stacked G is {rank}, expected '
                              f'{min(2 * n, 2 * basis.H)} ({basis.describe()}, s = {s.tolist()})')
    return g_bar
