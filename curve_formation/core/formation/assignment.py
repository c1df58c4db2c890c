"""Curve parameters s_i of the agents and the paper's Assumptions 1 and 2."""

import numpy as np

from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.formation.curves import Basis, Curve, CurveError


SPACINGS = ('uniform_s', 'arc_length')
ASSIGNMENTS = ('fixed', 'nearest')


class AssignmentError(ValueError):
    """Agent parameters the controller's proof does not cover."""


def uniform_parameters(n: int, closed: bool) -> FloatArray:
    """The paper's s_i = (i-1)/n on closed curves; (i-1)/(n-1) on open ones (both ends)."""
    if n == 1:
        return np.zeros(1)
    return np.arange(n) / (n if closed else n - 1)


def arc_length_parameters(curve: Curve, n: int) -> FloatArray:
    """s_i that split the curve into equal arc lengths (closed: n gaps incl. the closing one)."""
    s_table, length = curve.arc_length_table()
    total = length[-1]
    if total <= 0:
        raise CurveError('the curve has zero length; arc-length spacing is undefined')
    fractions = uniform_parameters(n, curve.basis.closed)
    return np.interp(fractions * total, length, s_table)


def agent_parameters(curve: Curve, n: int, spacing: str = 'uniform_s') -> FloatArray:
    """s (n,) for n agents on `curve` with spacing 'uniform_s' (paper) or 'arc_length'."""
    if spacing == 'uniform_s':
        return uniform_parameters(n, curve.basis.closed)
    if spacing == 'arc_length':
        return arc_length_parameters(curve, n)
    raise AssignmentError(f'unknown spacing {spacing!r}; expected one of {SPACINGS}')


def nearest_order(points: FloatArray, targets: FloatArray,
                  speeds: FloatArray | None = None) -> IntArray:
    """perm (n,): agent i goes to targets[perm[i]], minimising the longest trip: its
    distance (m), or, where the agents' top `speeds` (n,; m/s) are given, its time (distance
    over speed).

    Among the orders with the shortest longest trip (a bottleneck assignment, found by
    bisection over the trips), the one with the shortest distance in total. points and
    targets (n, 2), arena frame.
    """
    dist = _distances(points, targets)
    return _bottleneck(dist, dist if speeds is None else _times(dist, speeds))


def _distances(points: FloatArray, targets: FloatArray) -> FloatArray:
    """(n, n) m from each agent at `points` to each of `targets` (n, 2); AssignmentError where
    they overflow.
    """
    points, targets = np.asarray(points, float), np.asarray(targets, float)
    with np.errstate(over='ignore', invalid='ignore'):
        dist = np.linalg.norm(points[:, None, :] - targets[None, :, :], axis=2)
    if not np.isfinite(dist).all():
        raise AssignmentError('the distances from the agents to their targets are not finite '
                              f'(agents up to {np.abs(points).max():.3g} m from the origin)')
    return dist


def _times(dist: FloatArray, speeds: FloatArray) -> FloatArray:
    """(n, n) s: each agent's distances (m) over its top speed (n,; m/s)."""
    return dist / np.asarray(speeds, float)[:, None]


def _bottleneck(dist: FloatArray, trip: FloatArray) -> IntArray:
    """nearest_order's perm for the distances `dist` (n, n) and trips `trip` (n, n)."""
    # Imported here: scipy.optimize is 60 % of a node process's start-up imports (0.35 s),
    # and only experiment loading (nearest assignment) needs it.
    from scipy.optimize import linear_sum_assignment
    values = np.unique(trip)
    low, high = 0, len(values) - 1
    while low < high:   # smallest threshold that still admits a full assignment
        mid = (low + high) // 2
        too_far = (trip > values[mid]).astype(float)
        rows, cols = linear_sum_assignment(too_far)
        if too_far[rows, cols].sum() == 0:
            high = mid
        else:
            low = mid + 1
    cost = np.where(trip <= values[low], dist, np.inf)
    rows, cols = linear_sum_assignment(cost)
    return cols[np.argsort(rows)]


# The order by trip time is taken only where it shortens the longest trip's time by this
# share against the order by distance: distance over top speed leaves out the turns, the
# approach and the other robots. Measured (checked imperfect MuJoCo robots, 20 starts of each
# arena file): taken wherever it changed the order (then the shortest total time among the
# orders of the shortest longest trip), 6 starts of arena_demo's first curve
# changed, 5 sooner (seed 18 1.21x -> 1.12x the perfect robots' time) and 1 later (seed 10,
# 1.03x -> 1.07x, a predicted 6 % shorter), but 4 of mona_arena's first curve, 3 later (to
# 1.04x), and 2 of its second curve, both later (1.03x -> 1.17x), each predicted under 2 %
# shorter or no shorter (a different order of the trips that do not set the longest).
TIMED_GAIN = 0.03


def timed_order(points: FloatArray, targets: FloatArray, speeds: FloatArray | None
                ) -> IntArray:
    """nearest_order by trip time (agents' top `speeds` (n,; m/s) given) where that shortens
    the longest trip's time by TIMED_GAIN against the order by distance; else by distance.
    points and targets (n, 2), arena frame.
    """
    dist = _distances(points, targets)
    by_distance = _bottleneck(dist, dist)
    if speeds is None:
        return by_distance
    trip = _times(dist, speeds)
    by_time = _bottleneck(dist, trip)
    rows = np.arange(len(trip))
    if trip[rows, by_time].max() <= (1.0 - TIMED_GAIN) * trip[rows, by_distance].max():
        return by_time
    return by_distance


def top_speeds(speeds: FloatArray | None, nominal: float) -> FloatArray | None:
    """Robots' top speeds (n,; m/s, NaN where unknown) as timed_order weighs trips by:
    an unknown one `nominal` (m/s, the wheels' limit); None where none is known or all are
    alike (trips weighed as distances).
    """
    if speeds is None or not 0.0 < nominal < np.inf:
        return None
    speeds = np.asarray(speeds, float)
    speeds = np.where(np.isfinite(speeds) & (speeds > 0.0), speeds, nominal)
    return None if np.all(speeds == speeds[0]) else speeds


def assigned_parameters(curve: Curve, s: FloatArray, points: FloatArray | None,
                        assignment: str) -> FloatArray:
    """The agents' parameters: s (n,) as given ('fixed') or permuted so that each agent at
    `points` (n, 2, arena frame) gets the nearest of the curve's points at s ('nearest').
    """
    s = np.asarray(s, float)
    if assignment == 'fixed':
        return s
    if assignment == 'nearest':
        if points is None:
            raise AssignmentError("nearest assignment needs the agents' points")
        return s[nearest_order(points, curve.points(s))]
    raise AssignmentError(f'unknown assignment {assignment!r}; expected one of {ASSIGNMENTS}')


# Re-assignment takes a new order only if it shortens the squared trips by this share.
REASSIGN_IMPROVEMENT = 0.1
# ... and only if no trip becomes longer than this many times the longest one now (mona_arena
# seed 27: a 7-robot rotation cut the squared sum by 10.5 % and lengthened the longest trip
# 49 -> 64 cm, 1.51x the straight-trip bound instead of 1.25x; arena_demo seed 18: a swap
# that lengthened it 33 -> 39 cm (1.18x) untangled a jam, 1.27x instead of 1.55x;
# docs/collision-avoidance.md).
REASSIGN_LONGEST = 1.2


def reassigned(curve: Curve, s: FloatArray, points: FloatArray,
               improvement: float = REASSIGN_IMPROVEMENT,
               longest: float = REASSIGN_LONGEST) -> FloatArray:
    """The agents' parameters s (n,) permuted among them so that the agents at `points` (n, 2;
    their control points, arena frame, m) go to the same n curve points with the smallest sum
    of squared distances, no trip longer than `longest` times the longest one now, if that
    sum is smaller than the current one by more than `improvement` (a share); else s as it is.

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
    # at least the longest trip now, so that the order as it is is always allowed
    cap = max(longest, 1.0) ** 2 * np.diag(cost).max()
    allowed = np.where(cost <= cap, cost, np.inf)
    rows, cols = linear_sum_assignment(allowed)
    if cost[rows, cols].sum() < (1.0 - improvement) * np.trace(cost):
        return s[cols[np.argsort(rows)]]
    return s


def phase_parameters(curve: Curve, n: int, spacing: str, assignment: str,
                     from_points: FloatArray | None) -> FloatArray:
    """The agents' curve parameters s (n,) for one curve of the schedule: the one source of s_i.

    The spacing's n points (agent i the i-th with `fixed`), or with `nearest` those points
    assigned to the agents at `from_points` (n, 2; arena frame, m): the start's control
    points for the first curve, the previous curve's targets after a switch. Checked against
    Assumptions 1 and 2 (AssignmentError, or CurveError for a spacing the curve cannot have).
    """
    s = assigned_parameters(curve, agent_parameters(curve, n, spacing), from_points, assignment)
    check_assumptions(curve.basis, s)
    return s


_PASSED: dict[tuple[type, str, bytes], FloatArray] = {}   # G_bar of s that passed, by basis
_PASSED_KEPT = 16


def check_assumptions(basis: Basis, s: FloatArray) -> FloatArray:
    """Refuse s that break Assumption 1 (rank G_bar = min(2n, 2H)) or 2 (n <= H).

    Also refuses duplicate s_i (two agents sent to one point; on closed curves s and s+1 are
    the same point). Returns G_bar (2n, 2H), read-only: kept for s that passed.
    """
    s = np.asarray(s, dtype=float)
    asked = (type(basis), basis.describe(), s.tobytes())
    if asked in _PASSED:   # every controller of a group checks the same curve message
        return _PASSED[asked]
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
    if len(_PASSED) >= _PASSED_KEPT:
        _PASSED.clear()
    g_bar.flags.writeable = False
    _PASSED[asked] = g_bar
    return g_bar
