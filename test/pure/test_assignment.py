import itertools

import numpy as np
import pytest

from curve_formation.core.formation.assignment import (
    agent_parameters,
    assigned_parameters,
    AssignmentError,
    check_assumptions,
    nearest_order,
    REASSIGN_LONGEST,
    reassigned,
    TIMED_GAIN,
    timed_order,
    top_speeds,
    uniform_parameters,
)
from curve_formation.core.formation.curve_sources import expression_samples
from curve_formation.core.formation.curves import fit_curve, FourierBasis, PolynomialBasis


def ellipse():
    s, pts = expression_samples('4*cos(2*pi*s)', 'sin(2*pi*s)', 200, closed=True)
    return fit_curve(FourierBasis(3), s, pts).curve


def test_uniform_parameters_closed_and_open():
    np.testing.assert_allclose(uniform_parameters(4, closed=True), [0, .25, .5, .75])
    np.testing.assert_allclose(uniform_parameters(3, closed=False), [0, .5, 1])


def test_arc_length_spacing_gives_equal_arc_gaps():
    curve = ellipse()
    s = agent_parameters(curve, 5, 'arc_length')
    table_s, length = curve.arc_length_table()
    arc = np.interp(s, table_s, length)
    gaps = np.diff(np.append(arc, length[-1]))
    np.testing.assert_allclose(gaps, length[-1] / 5, rtol=1e-3)
    # Uniform in s is not uniform in arc length on an ellipse.
    arc_s = np.interp(uniform_parameters(5, True), table_s, length)
    assert np.ptp(np.diff(np.append(arc_s, length[-1]))) > 0.1


def test_more_agents_than_basis_functions_is_refused():
    with pytest.raises(AssignmentError, match='Assumption 2 .* n = 8 .* H = 7'):
        check_assumptions(FourierBasis(3), uniform_parameters(8, True))


def test_duplicate_parameters_are_refused():
    with pytest.raises(AssignmentError, match='share the curve parameter'):
        check_assumptions(PolynomialBasis(6), np.array([0.0, 0.5, 0.5]))
    # On a closed curve s = 0 and s = 1 are the same point.
    with pytest.raises(AssignmentError, match='share the curve parameter'):
        check_assumptions(FourierBasis(3), np.array([0.0, 0.5, 1.0]))


class DegenerateBasis(PolynomialBasis):
    """A basis whose last function repeats the first: G_bar can never have full rank."""

    def phi(self, s):
        out = super().phi(s)
        out[..., -1] = out[..., 0]
        return out


def test_rank_deficient_stacked_basis_is_refused():
    with pytest.raises(AssignmentError, match='Assumption 1 .* rank'):
        check_assumptions(DegenerateBasis(3), np.array([0.0, 0.3, 0.6, 1.0]))


def test_a_check_kept_for_the_next_controller_answers_as_a_new_one():
    """The s that passed are kept (a group's controllers check the same curve message): the
    same s on a new basis object returns the same read-only G_bar, and a basis of another
    kind with the same size and s is checked for itself.
    """
    s = np.array([0.0, 0.3, 0.6, 1.0])
    first = check_assumptions(PolynomialBasis(3), s)
    again = check_assumptions(PolynomialBasis(3), s.copy())
    np.testing.assert_array_equal(again, PolynomialBasis(3).stacked(s))
    assert again is first and not again.flags.writeable
    with pytest.raises(AssignmentError, match='Assumption 1 .* rank'):
        check_assumptions(DegenerateBasis(3), s)


def test_valid_parameters_return_the_stacked_basis():
    g_bar = check_assumptions(FourierBasis(6), uniform_parameters(6, True))
    assert g_bar.shape == (12, 26)
    np.testing.assert_allclose(g_bar @ np.linalg.pinv(g_bar), np.eye(12), atol=1e-10)


@pytest.mark.parametrize('weighed', [False, True], ids=['distances', 'times'])
@pytest.mark.parametrize('seed', range(12))
def test_nearest_order_is_the_bottleneck_optimum_then_the_shortest(seed, weighed):
    """Against every permutation of 6 agents: no order has a shorter longest trip, and none
    with the same longest trip is shorter in total distance; a trip its distance, or its
    time (distance over the agent's speed) where speeds (0.8 to 1.2) are given.
    """
    rng = np.random.default_rng(seed)
    points, targets = rng.uniform(-1, 1, (6, 2)), rng.uniform(-1, 1, (6, 2))
    speeds = rng.uniform(0.8, 1.2, 6) if weighed else None
    trip = np.linalg.norm(points[:, None] - targets[None], axis=2)
    if weighed:
        trip = trip / speeds[:, None]
    perm = nearest_order(points, targets, speeds)
    assert sorted(perm) == list(range(6))
    chosen = trip[np.arange(6), perm]
    best = min(max(trip[np.arange(6), p]) for p in itertools.permutations(range(6)))
    assert chosen.max() == pytest.approx(best)
    dist = np.linalg.norm(points[:, None] - targets[None], axis=2)
    shortest = min(dist[np.arange(6), p].sum() for p in itertools.permutations(range(6))
                   if max(trip[np.arange(6), p]) <= best + 1e-12)
    assert dist[np.arange(6), perm].sum() == pytest.approx(shortest)


def test_a_slower_robot_is_sent_the_shorter_way():
    """On a line, A at 0 m and B at 0.1 m, targets at 0.5 and 1.0 m: by distance A takes the
    near target (longest trip 0.9 m, B's, against 1.0 m); B at half A's speed would take 1.8
    s to the far one, so by time B takes the near one (longest 1.0 s, A's).
    """
    points = np.array([[0.0, 0.0], [0.1, 0.0]])
    targets = np.array([[0.5, 0.0], [1.0, 0.0]])
    np.testing.assert_array_equal(nearest_order(points, targets), [0, 1])
    np.testing.assert_array_equal(nearest_order(points, targets, [1.0, 1.0]), [0, 1])
    np.testing.assert_array_equal(nearest_order(points, targets, [0.05, 0.025]), [1, 0])


@pytest.mark.parametrize('slower', [0.5, 0.88])
def test_the_order_by_time_is_taken_only_where_it_shortens_the_longest_trip_enough(slower):
    """A and B as above, B at `slower` times A's speed (1 m/s). By distance the longest trip
    is B's 0.9 m, 0.9 / slower s; by time B takes the near target and the longest is A's 1 s:
    1.8 s -> 1.0 s at half speed, taken; 1.023 s -> 1.0 s at 0.88, 2.2 % shorter, under
    TIMED_GAIN, and the order by distance is kept.
    """
    points = np.array([[0.0, 0.0], [0.1, 0.0]])
    targets = np.array([[0.5, 0.0], [1.0, 0.0]])
    speeds = [1.0, slower]
    np.testing.assert_array_equal(nearest_order(points, targets, speeds), [1, 0])
    gain = 1.0 - 1.0 / (0.9 / slower)
    assert (gain >= TIMED_GAIN) == (slower == 0.5)
    np.testing.assert_array_equal(timed_order(points, targets, speeds),
                                  [1, 0] if slower == 0.5 else [0, 1])
    np.testing.assert_array_equal(timed_order(points, targets, None), [0, 1])


def test_agents_beyond_any_distance_are_refused_not_assigned():
    """Points so far off that their distances overflow: refused with an AssignmentError (as
    loading turns into a ConfigError naming the curve), not a solver's infeasible matrix.
    """
    with pytest.raises(AssignmentError, match='not finite'):
        nearest_order(np.array([[1e200, 1e200], [0.0, 0.0]]), np.zeros((2, 2)))


def test_top_speeds_take_an_unknown_robot_as_nominal_and_alike_ones_as_none():
    """A robot not heard from drives at the wheels' limit; speeds all alike, or no finite
    limit, weigh nothing (None: trips are distances).
    """
    np.testing.assert_array_equal(top_speeds([0.04, np.nan, 0.06], 0.05), [0.04, 0.05, 0.06])
    assert top_speeds([0.05, np.nan, 0.05], 0.05) is None
    assert top_speeds(None, 0.05) is None
    assert top_speeds([0.04, 0.05], np.inf) is None
    assert top_speeds([0.04, 0.0], 0.05).tolist() == [0.04, 0.05]   # 0: not a speed


def test_nearest_assignment_keeps_the_set_of_parameters():
    curve = ellipse()
    s = agent_parameters(curve, 5, 'uniform_s')
    targets = curve.points(s)
    points = targets[[3, 0, 4, 1, 2]] + 0.01     # the agents sit next to shuffled targets
    got = assigned_parameters(curve, s, points, 'nearest')
    np.testing.assert_allclose(got, s[[3, 0, 4, 1, 2]])
    np.testing.assert_allclose(assigned_parameters(curve, s, points, 'fixed'), s)
    check_assumptions(curve.basis, got)          # a permutation keeps Assumption 1
    with pytest.raises(AssignmentError, match='nearest'):
        assigned_parameters(curve, s, points, 'closest')


class TwoPoints:
    """A 'curve' with two points: s = 0 at (0, 0), s = 1 at (1.3, 0) (m)."""

    def points(self, s):
        return np.where(np.asarray(s)[:, None] < 0.5, [[0.0, 0.0]], [[1.3, 0.0]])


@pytest.mark.parametrize('swapped_longest', [1.1, 1.3])
def test_a_re_assignment_may_not_lengthen_the_longest_trip_beyond_the_cap(swapped_longest):
    """Robot A 1 m from its target, B 1 m from its own and 0.3 m from A's: swapping cuts the
    squared sum (2 -> under 1.8, past the 10 % asked) but makes A's trip swapped_longest m.
    Taken within REASSIGN_LONGEST (1.2x the longest trip now), refused beyond it, and taken
    there again without the cap.
    """
    assert 1.1 < REASSIGN_LONGEST < 1.3
    # A on the unit circle round (0, 0) at distance swapped_longest from (1.3, 0)
    cos = (1.0 + 1.3 ** 2 - swapped_longest ** 2) / (2 * 1.3)
    a = [cos, np.sqrt(1.0 - cos ** 2)]
    points = np.array([a, [0.3, 0.0]])
    s = np.array([0.0, 1.0])
    trips = np.linalg.norm(points - TwoPoints().points(s), axis=1)
    np.testing.assert_allclose(trips, [1.0, 1.0])
    taken = reassigned(TwoPoints(), s, points)
    if swapped_longest < REASSIGN_LONGEST:
        np.testing.assert_array_equal(taken, [1.0, 0.0])
    else:
        np.testing.assert_array_equal(taken, s)
        np.testing.assert_array_equal(reassigned(TwoPoints(), s, points, longest=np.inf),
                                      [1.0, 0.0])
