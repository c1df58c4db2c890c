"""Robots as bodies and the safety filter: contacts, barriers kept, wheel limits kept, no
deadlock in the encounters that block robots, and the arena cases settling without a contact.
"""

import math

from hypothesis import assume, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from scipy.optimize import minimize

from conftest import DATA_DIR
from curve_formation.core.config.experiment import point_robots
from curve_formation.core.config.loading import load_experiment, with_start
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.controller import safety
from curve_formation.core.formation.assignment import nearest_order
from curve_formation.core.record import body_metrics, metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.core.world.bodies import separate
from curve_formation.paths import resolve_config


def test_overlapping_bodies_are_pushed_apart_and_back_inside_the_walls():
    poses = np.array([[0.5, 0.5, 0.0], [0.55, 0.5, 1.0], [1.79, 0.02, 2.0]])
    touching = np.zeros((3, 3), bool)
    new, now, gap = separate(poses, 0.04, 1.8, 0.8, touching)
    assert new == 1 and now and gap == pytest.approx(0.05 - 0.08)
    assert np.hypot(*(poses[0, :2] - poses[1, :2])) == pytest.approx(0.08)
    np.testing.assert_allclose(poses[:2, 0], [0.485, 0.565])   # each gave way by half
    np.testing.assert_allclose(poses[2, :2], [1.76, 0.04])      # put back against the walls
    np.testing.assert_allclose(poses[:, 2], [0.0, 1.0, 2.0])    # headings untouched
    # Still touching: the same contact, not a new one; apart again: no contact.
    assert separate(poses, 0.04, 1.8, 0.8, touching)[:2] == (0, True)
    poses[1, 0] += 0.01
    assert separate(poses, 0.04, 1.8, 0.8, touching)[:2] == (0, False)


@given(st.integers(0, 2 ** 32 - 1))
@settings(max_examples=150, deadline=None)
def test_the_filter_finds_the_closest_point_of_the_polygon_exactly(seed):
    """safety._closest against a general QP solver, on random sets of half-planes."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(1, 12))
    angles = rng.uniform(0, 2 * np.pi, count)
    planes = np.column_stack([np.cos(angles), np.sin(angles), rng.uniform(-0.5, 1.5, count)])
    start = rng.uniform(-3, 3, 2)
    found, x, y = safety._closest(planes, count, *start)
    a, b = planes[:, :2], planes[:, 2]
    best = minimize(lambda m: ((m - start) ** 2).sum(), np.zeros(2), method='SLSQP',
                    jac=lambda m: 2 * (m - start), options={'ftol': 1e-12, 'maxiter': 500},
                    constraints=[{'type': 'ineq', 'fun': lambda m: b - a @ m,
                                  'jac': lambda m: -a}])
    if found:
        assert (a @ [x, y] <= b + 1e-9).all()
        if best.success:
            assert np.hypot(x - best.x[0], y - best.x[1]) < 1e-5
    else:   # empty: no point satisfies every half-plane
        from scipy.optimize import linprog
        assert linprog(np.zeros(2), A_ub=a, b_ub=b, bounds=[(None, None)] * 2).status == 2


@given(x=st.floats(0.3, 1.5), y=st.floats(0.3, 0.5), theta=st.floats(-math.pi, math.pi),
       v=st.floats(-0.02, 0.02), w=st.floats(-0.25, 0.25))
@settings(max_examples=100, deadline=None)
def test_with_nothing_near_the_filter_leaves_the_command_as_it_is(x, y, theta, v, w):
    """A command within the wheel limits, other robots and walls far: bit for bit unchanged."""
    assume(abs(v) + 0.04 * abs(w) <= 0.0225)
    arena = load_experiment(resolve_config('arena_demo'))
    others = np.array([[x, y, theta], [x + 0.5, y + 0.3, 0.0], [x - 0.5, y - 0.3, 1.0]])
    limits = arena.limits
    out = safety.safe_command(v, w, x, y, theta, 0.0, 0.0, others, 0, 0.01, 0.1,
                              arena.avoidance, limits.wheel_base, limits.max_wheel_speed,
                              limits.max_angular_rate)
    assert out == (v, w, safety.UNCHANGED)
    assert safety.shaped_feedback(0.3, -0.2, x, y, others, 0, 2 / 3, 0.0225,
                                  arena.avoidance) == (0.3, -0.2)


@pytest.mark.parametrize('bias', [0.0, 1.0])
def test_the_passing_rule_turns_a_head_on_meeting_to_the_right_only_when_asked(bias):
    """A robot heading +x at another one 2 cm beyond the safe distance: with the passing rule
    (bias > 0) its intended velocity gains a part to its right (-y); without it (the
    default) it keeps heading straight at it (the barriers then stop it, and the robot of
    lower priority gives way).
    """
    av = safety.Avoidance(True, radius=0.04, margin=0.02, passing=bias, passing_range=0.08)
    others = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, math.pi]])
    fx, fy = safety.shaped_feedback(-0.1, 0.0, 0.0, 0.0, others, 0, 2 / 3, 0.0225, av)
    # the law steers along -k1 f: heading right is f_y > 0
    assert fx < 0.0
    if bias > 0.0:
        assert fy > 0.1 * abs(fx)
    else:
        assert fy == 0.0


def barriers(result):
    """(pairs, walls) (R,): the smallest h over pairs, |c_i - c_j|^2 - D^2 (m^2), and over
    walls, the distance of a body to a wall minus radius and half the margin (m).
    """
    experiment = result.experiment
    av = experiment.avoidance
    safe = 2 * av.radius + av.margin
    gaps = body_metrics.surface_gaps(result.poses, 0.0)   # centre distances
    low = av.radius + 0.5 * av.margin
    x, y = result.poses[..., 0], result.poses[..., 1]
    walls = np.minimum.reduce([x - low, av.width - low - x, y - low, av.height - low - y])
    return gaps ** 2 - safe ** 2, walls.min(axis=1)


def assert_kept_apart(result):
    pairs, walls = barriers(result)
    # Up to what the straight-step model neglects: the cross term of two robots stepping the
    # same way (2 T^2 v_max^2) and a drift not yet estimated (the drift of one tick).
    assert pairs.min() > -3e-5 and walls.min() > -5e-4, (pairs.min(), walls.min())
    assert result.contacts['count'] == 0 and result.contacts['time'] == 0.0
    limits = result.limits
    cmd = result.commands
    assert (np.abs(cmd[..., 0]) + 0.5 * limits.wheel_base * np.abs(cmd[..., 1])
            <= limits.max_wheel_speed + 1e-12).all()


@pytest.mark.parametrize('name', ['head_on', 'four_swap', 'crossing_switch'])
def test_encounters_that_block_robots_resolve_without_a_contact(name):
    """Head-on, a four-way swap and a curve switch whose paths all cross (fixed assignment,
    so no re-assignment helps): the robots give way to each other and all settle. Without the
    filter their bodies run into each other.
    """
    experiment = load_experiment(DATA_DIR / f'{name}.yaml')
    result = simulate(experiment)
    data = metrics.result_metrics(result)
    assert data['all_settled'], [p['settle_time'] for p in data['phases'][1:]]
    assert_kept_apart(result)
    off = simulate(experiment, avoidance=safety.AVOIDANCE_OFF)
    assert off.contacts['count'] > 0


@pytest.mark.parametrize('name, seed', [('mona_arena', 0), ('mona_arena', 3),
                                        ('arena_demo', 1), ('arena_demo', 12)])
def test_the_arena_cases_settle_every_phase_without_a_contact(name, seed):
    """The shipped arena experiments from fixed random starts where the law alone would
    bring bodies into each other (mona_arena seed 5 and arena_demo seed 18, arena_demo's
    slowest of the benchmark's 20, were here until the law alone, turning in place first,
    passed 90 mm and 81 mm apart from them).
    """
    case = load_experiment(resolve_config(name))
    start = seeded_start(case, seed)
    result = simulate(with_start(case, start))
    data = metrics.result_metrics(result)
    assert data['all_settled'], [p['settle_time'] for p in data['phases']]
    assert_kept_apart(result)
    assert data['bodies']['smallest_gap'] > 0.95 * case.avoidance.margin
    # The law alone (point robots) from the same start: the bodies would overlap.
    alone = simulate(with_start(point_robots(case), start))
    assert body_metrics.closest_approach(alone.poses)[0] < 2 * case.radius


def test_the_drift_allowance_keeps_the_margin_while_the_drift_is_unlearnt():
    """arena_demo's robots drift forwards by 5 mm/s, which the observer learns at 1 /s: from
    seed 6 (the benchmark's closest start) two robots meet 0.9 s in, before it has. The
    barriers holding against the file's 5 mm/s allowance keep the margin; without it the
    gap falls inside it (19.59 mm measured), and settling is the same either way.
    """
    case = load_experiment(resolve_config('arena_demo'))
    assert case.avoidance.drift == 0.005
    experiment = with_start(case, seeded_start(case, 6))
    held = simulate(experiment)
    unheld = simulate(experiment, avoidance=case.avoidance._replace(drift=0.0))
    margin = case.avoidance.margin
    assert held.contacts['smallest_gap'] >= margin
    assert unheld.contacts['smallest_gap'] < margin
    times = [[p['settle_time'] for p in metrics.result_metrics(r)['phases']]
             for r in (held, unheld)]
    np.testing.assert_allclose(times[0], times[1], atol=0.1)


def test_a_switch_after_a_re_assignment_assigns_the_new_curve_from_where_robots_went():
    """mona_arena from seed 13 re-assigns the first curve's targets at 1 s. At the switch the
    robots are at the re-assigned targets, not where the assignment made at load time assumed
    them: the second curve is assigned from there (the curve server does the same), which
    here shortens the longest trip of the switch from 0.70 m to 0.47 m.
    """
    case = load_experiment(resolve_config('mona_arena'))
    experiment = with_start(case, seeded_start(case, 13))
    result = simulate(experiment, duration=90.0)
    first, second = result.experiment.phases[:2]
    assert first.changes
    there = first.changes[-1][2]
    loaded = experiment.phases[1]
    assert not np.array_equal(second.s, loaded.s)
    np.testing.assert_array_equal(second.s, loaded.s[nearest_order(there, loaded.targets)])
    longest = np.linalg.norm(second.targets - there, axis=1).max()
    assert longest < 0.8 * np.linalg.norm(loaded.targets - there, axis=1).max()
    # and that is where they went
    points = metrics.steered_points(result.poses[-1:], second.targets[None], result.gains)[0]
    assert np.linalg.norm(points - second.targets, axis=1).max() < 1e-3


def test_the_barriers_hold_under_continuous_control_too():
    experiment = load_experiment(DATA_DIR / 'head_on.yaml')
    result = simulate(experiment, rate_hz=None, duration=40.0)
    pairs, walls = barriers(result)
    assert pairs.min() > -1e-6 and walls.min() > -1e-6


def test_commands_that_act_late_lower_the_barrier_rate_to_one_over_the_loops_delay():
    """alpha (T + L) <= 1: unchanged at no latency or where it already holds, capped at
    1 / (T + L) otherwise (5 /s at T = 0.1 s becomes 2.5 /s at L = 0.3 s).
    """
    avoidance = safety.Avoidance(True, radius=0.04, margin=0.02, rate=5.0)
    assert safety.with_latency(avoidance, 0.1, 0.0) is avoidance
    assert safety.with_latency(avoidance, 0.1, 0.1) is avoidance   # 5 * 0.2 = 1
    late = safety.with_latency(avoidance, 0.1, 0.3)
    assert late.rate == pytest.approx(2.5)
    assert late._replace(rate=5.0) == avoidance


def test_bodies_without_the_filter_push_each_other_but_never_overlap():
    experiment = load_experiment(DATA_DIR / 'head_on.yaml')
    result = simulate(experiment, avoidance=safety.AVOIDANCE_OFF, duration=40.0)
    assert result.contacts['count'] >= 1 and result.contacts['time'] > 1.0
    gaps = body_metrics.surface_gaps(result.poses, experiment.radius)
    assert gaps.min() > -1e-4     # at most one 1 ms step's travel before resolution


def test_avoidance_settings_are_checked_at_load(arena_dict):
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import build_experiment
    arena_dict['avoidance'] = {'rate': 50.0}
    with pytest.raises(ConfigError, match='avoidance.rate'):
        build_experiment(arena_dict, 'a.yaml')
    arena_dict['avoidance'] = True
    arena_dict['agents']['initial'] = {'poses': [[0.5, 0.5, 0.0], [0.55, 0.5, 0.0]] + [
        [0.2 * i, 0.2, 0.0] for i in range(1, 8)]}
    with pytest.raises(ConfigError, match='agents 1 and 2 start 0.050 m apart'):
        build_experiment(arena_dict, 'a.yaml')


def test_check_warns_of_targets_too_close_and_refuses_a_curve_outside(arena_dict):
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import build_experiment
    arena_dict['agents']['spacing'] = 'uniform_s'   # the paper's: two targets 2.8 cm apart
    experiment = build_experiment(arena_dict, 'a.yaml')
    assert any('0.028 m apart' in w for w in experiment.warnings), experiment.warnings
    arena_dict['curves'][0]['x'] = '0.5 * cos(2*pi*s) + 0.5'
    with pytest.raises(ConfigError, match=r'curves\[0\]: the curve leaves the arena'):
        build_experiment(arena_dict, 'a.yaml')
