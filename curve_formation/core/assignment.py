"""Curve parameters s_i of the agents and the paper's Assumptions 1 and 2."""

from dataclasses import dataclass
import math

import numpy as np

from curve_formation.core.curves import CurveError
from curve_formation.core.shapes import FloatArray


SPACINGS = ('uniform_s', 'arc_length')
ASSIGNMENTS = ('fixed', 'nearest')


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


def nearest_order(points, targets):
    """perm (n,): agent i goes to targets[perm[i]], minimising the longest distance (m).

    Among the orders with the smallest longest distance (a bottleneck assignment, found by
    bisection over the distances), the one with the smallest total distance. points and
    targets (n, 2), arena frame.
    """
    # Imported here: scipy.optimize is 60 % of a node process's start-up imports (0.35 s),
    # and only experiment loading (nearest assignment) needs it.
    from scipy.optimize import linear_sum_assignment
    points, targets = np.asarray(points, float), np.asarray(targets, float)
    dist = np.linalg.norm(points[:, None, :] - targets[None, :, :], axis=2)
    values = np.unique(dist)
    low, high = 0, len(values) - 1
    while low < high:   # smallest threshold that still admits a full assignment
        mid = (low + high) // 2
        too_far = (dist > values[mid]).astype(float)
        rows, cols = linear_sum_assignment(too_far)
        if too_far[rows, cols].sum() == 0:
            high = mid
        else:
            low = mid + 1
    cost = np.where(dist <= values[low], dist, np.inf)
    rows, cols = linear_sum_assignment(cost)
    return cols[np.argsort(rows)]


def assigned_parameters(curve, s, points, assignment):
    """The agents' parameters: s (n,) as given ('fixed') or permuted so that each agent at
    `points` (n, 2, arena frame) gets the nearest of the curve's points at s ('nearest').
    """
    s = np.asarray(s, float)
    if assignment == 'fixed':
        return s
    if assignment == 'nearest':
        return s[nearest_order(points, curve.points(s))]
    raise AssignmentError(f'unknown assignment {assignment!r}; expected one of {ASSIGNMENTS}')


# Re-assignment takes a new order only if it shortens the squared trips by this share.
REASSIGN_IMPROVEMENT = 0.1
# ... and only if no trip becomes longer than the longest one now, or, where the robots' ways
# as they are would meet (Meeting: bodies closer than they may come) and the new ones would
# not, no longer than this many times it (mona_arena seed 27: a 7-robot rotation cut the
# squared sum by 10.5 % and lengthened the longest trip 49 -> 64 cm, 1.51x the straight-trip
# bound instead of 1.25x; arena_demo seed 18: a swap that lengthened it 33 -> 39 cm (1.18x)
# took two robots out of each other's way, 1.22x instead of 1.36x;
# docs/collision-avoidance.md).
REASSIGN_LONGEST = 1.2


def reassigned(curve, s, points, improvement=REASSIGN_IMPROVEMENT, longest=REASSIGN_LONGEST,
               meets=None):
    """The agents' parameters s (n,) permuted among them so that the agents at `points` (n, 2;
    their control points, arena frame, m) go to the same n curve points with the smallest sum
    of squared distances, no trip longer than `longest` times the longest one now, if that
    sum is smaller than the current one by more than `improvement` (a share); else s as it is.
    With `meets` (targets (n, 2) -> bool: would the robots' ways to them bring two bodies too
    close; Meeting), a trip may become longer than the longest now only where the order as it
    is meets and the new one does not.

    The sum of squared trips is the assignment under which straight paths do not cross
    (Turpin, Michael, Kumar: CAPT, 2014): re-assigning while robots travel swaps the targets of
    robots whose ways have come to cross, as bodies push them off their straight paths. The
    cap keeps it from trading a shorter sum for a longer slowest trip, which sets the
    settling time: the first assignment (nearest_order) minimises the longest trip, not the
    sum, so without the cap the first check may undo it for no crossing at all.
    """
    from scipy.optimize import linear_sum_assignment
    s = np.asarray(s, float)
    points = np.asarray(points, float)
    targets = curve.points(s)
    cost = ((points[:, None, :] - targets[None, :, :]) ** 2).sum(axis=2)
    now = np.diag(cost).max()

    def cheapest(factor):   # at least the longest trip now: the order as it is qualifies
        rows, cols = linear_sum_assignment(np.where(cost <= max(factor, 1.0) ** 2 * now, cost,
                                                    np.inf))
        return cols[np.argsort(rows)]

    order = cheapest(longest)
    if meets is not None and longest > 1.0 and (not meets(targets) or meets(targets[order])):
        order = cheapest(1.0)
    if cost[np.arange(len(s)), order].sum() < (1.0 - improvement) * np.trace(cost):
        return s[order]
    return s


@dataclass(frozen=True)
class Meeting:
    """Would robots on their ways to targets (n, 2) come closer than `clearance` (m)?

    Each robot turns in place to face its target (forwards or, with `reverse`, backwards,
    whichever turn is smaller) at `turn_rate` (rad/s), then drives straight to it at `speed`
    (m/s) and waits there: the fastest way with bounded wheel speeds (Balkcom and Mason, IJRR
    2002). points (n, 2): control points (m), headings (n,) (rad), arena frame.
    """

    points: FloatArray
    headings: FloatArray
    speed: float
    turn_rate: float
    clearance: float
    reverse: bool = False

    def __call__(self, targets: FloatArray) -> bool:
        return meeting_distance(self.points, self.headings, targets, self.speed,
                                self.turn_rate, self.reverse) < self.clearance


def meeting_distance(points, headings, targets, speed, turn_rate, reverse=False, step=0.1):
    """The closest two robots come (m) on their ways to `targets` (Meeting's motion), sampled
    every `step` (s): at most 2 speed step below the true closest.
    """
    points = np.asarray(points, float)
    if len(points) < 2:
        return math.inf
    trips = np.asarray(targets, float) - points
    length = np.linalg.norm(trips, axis=1)
    ways = trips / np.maximum(length, 1e-12)[:, None]
    off = np.abs(np.remainder(np.arctan2(trips[:, 1], trips[:, 0]) - headings + np.pi,
                              2.0 * np.pi) - np.pi)
    if reverse:
        off = np.minimum(off, np.pi - off)
    turned = off / turn_rate
    t = np.arange(0.0, float((turned + length / speed).max()) + step, step)
    along = np.clip((t[None, :] - turned[:, None]) * speed, 0.0, length[:, None])   # (n, T)
    where = points[:, None, :] + along[..., None] * ways[:, None, :]
    gaps = np.linalg.norm(where[:, None] - where[None, :], axis=3).min(axis=2)
    gaps[np.diag_indices(len(points))] = np.inf
    return float(gaps.min())


def phase_parameters(curve, n, spacing, assignment, from_points):
    """The agents' curve parameters s (n,) for one curve of the schedule: the one source of s_i.

    The spacing's n points (agent i the i-th with `fixed`), or with `nearest` those points
    assigned to the agents at `from_points` (n, 2; arena frame, m): the start's control
    points for the first curve, the previous curve's targets after a switch. Checked against
    Assumptions 1 and 2 (AssignmentError, or CurveError for a spacing the curve cannot have).
    """
    s = assigned_parameters(curve, agent_parameters(curve, n, spacing), from_points, assignment)
    check_assumptions(curve.basis, s)
    return s


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
    g_bar = basis.stacked(s)
    rank = np.linalg.matrix_rank(g_bar)
    if rank != min(2 * n, 2 * basis.H):
        raise AssignmentError(f'Assumption 1 fails: rank of stacked G is {rank}, expected '
                              f'{min(2 * n, 2 * basis.H)} ({basis.describe()}, s = {s.tolist()})')
    return g_bar
