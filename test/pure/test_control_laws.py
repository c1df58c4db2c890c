"""Our control law (observer + sampled heading) against the paper's, on the paper's cases.

The floor of a run is the settling time of the same gains, graph, heading command and start
with no disturbance and the estimator off; the goal is to settle within 1.25x the floor.
"""

import dataclasses
import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from conftest import paper_arena
from curve_formation.core.config.loading import load_experiment, with_start
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.controller.law import sampled_feedback
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.observer import ray_growth
from curve_formation.core.formation.dynamics import arc_step, measured_velocity
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


SEEDS = (0, 1)


def settle_times(case, gains, rate, start, disturbance=None):
    result = simulate(case, rate_hz=rate, gains=gains, initial_poses=start,
                      disturbance=disturbance)
    data = metrics.result_metrics(result)
    return [p['settle_time'] for p in data['phases']], result


@pytest.mark.parametrize('rate', [None, 10.0], ids=['continuous', '10Hz'])
@pytest.mark.parametrize('name', ['closed_curve', 'open_curve', 'shape_change'])
def test_observer_law_settles_within_the_disturbance_free_floor(name, rate):
    case = load_experiment(resolve_config(name))
    assert case.gains.law == 'observer' and case.gains.sampled_heading   # shipped default
    floor_gains = dataclasses.replace(case.gains, k2=0.0)
    for seed in SEEDS:
        start = seeded_start(case, seed)
        floor, _ = settle_times(case, floor_gains, rate, start, disturbance=[0.0, 0.0])
        ours, result = settle_times(case, case.gains, rate, start)
        assert None not in floor, (name, seed, floor)
        for f, t in zip(floor, ours, strict=True):
            assert t is not None and t <= 1.25 * f, (name, seed, rate, floor, ours)
        # The estimate has converged to the paper's d / k2.
        np.testing.assert_allclose(result.dhat[-1], result.disturbance / case.gains.k2,
                                   atol=1e-6)


@pytest.mark.parametrize('rate', [None, 10.0], ids=['continuous', '10Hz'])
def test_the_paper_law_with_the_same_settings_does_not_settle(rate):
    """The reference, one switch away, keeps its measured behaviour (paper-notes.md)."""
    case = load_experiment(resolve_config('closed_curve'))
    times, result = settle_times(case, case.gains.paper_law(), rate, seeded_start(case, 0))
    assert times == [None]
    assert np.abs(result.dhat[-1] - result.disturbance / case.gains.k2).max() > 0.1


def test_observer_learns_a_disturbance_injected_before_saturated_wheels():
    """Mona case: d = [0.5, 0.5] on the PC against 2.25 cm/s wheels, 20x the wheel limit.

    The law saturates its feedback inside the limits before compensating, so a saturated
    command is never mistaken for a disturbance: the estimate reaches d / k2, the formation
    settles, and the paper's law does not.
    """
    case = load_experiment(resolve_config('mona_arena'))
    ours = simulate(case)
    np.testing.assert_allclose(ours.dhat[-1] * case.gains.k2, case.disturbance, atol=1e-4)
    assert metrics.result_metrics(ours)['all_settled']
    paper = simulate(case, gains=case.gains.paper_law())
    assert paper.error_norm[-1] > 10 * ours.error_norm[-1]
    wheel = np.abs(ours.commands[..., 0]) + 0.5 * case.limits.wheel_base * np.abs(
        ours.commands[..., 1])
    assert wheel.max() <= case.limits.max_wheel_speed * (1 + 1e-9)


@pytest.mark.parametrize('seed', [None, 0, 1, 2, 3])
def test_observer_growth_learns_a_pc_disturbance_beyond_the_limits_within_seconds(seed):
    """Mona case (d 20x the wheel limit, added before the limits): with the shipped
    observer_growth every robot's estimate is within 10 % of d / k2 from 5 s on (the search
    along the saturated ray); with it off (1) most robots are still learning at 5 s (each
    tick moves the estimate at most the limits' width), some for over 15 s.
    """
    case = load_experiment(resolve_config('mona_arena'))
    assert case.gains.observer_growth > 1
    if seed is not None:
        case = with_start(case, seeded_start(case, seed))

    def learning(growth):
        result = simulate(case, duration=20.0,
                          gains=dataclasses.replace(case.gains, observer_growth=growth))
        off = (np.linalg.norm(result.gains.k2 * result.dhat - result.disturbance, axis=2)
               / np.linalg.norm(result.disturbance, axis=1))
        return off[result.t >= 5.0].max(axis=0)   # per robot, worst from 5 s on

    assert learning(case.gains.observer_growth).max() < 0.1
    assert np.sum(learning(1.0) >= 0.1) >= 4


@pytest.mark.parametrize('seed', [4, 6, 70])
def test_a_robot_the_safety_filter_slows_learns_a_pc_disturbance_as_fast(seed):
    """Mona case from starts where a robot begins beside another: the safety filter changes
    its clipped command, so its measured motion is below the limits. The observer searches
    along the motion before the filter (measured minus what the filter changed): every
    robot's estimate is within 10 % of d / k2 from 2 s on, as with the law alone (it took
    4.5 to 6.5 s when the search ran on the measured motion).
    """
    case = load_experiment(resolve_config('mona_arena'))
    result = simulate(with_start(case, seeded_start(case, seed)), duration=10.0)
    off = (np.linalg.norm(result.gains.k2 * result.dhat - result.disturbance, axis=2)
           / np.linalg.norm(result.disturbance, axis=1))
    assert off[result.t >= 2.0].max() < 0.1


def test_ray_growth_searches_along_a_saturated_ray():
    """Doubling while the commands stay clipped by the wheel limits and their motions lie
    along one ray, up to the law's cap; a reversal divides by 4; a command the limits did
    not clip resets to 1, however close to the limit its measured motion (a camera's noise
    takes a feedback at 98 % of the limits past 99 %); off without the cap, without a PC
    disturbance or without wheel limits.
    """
    case = load_experiment(resolve_config('mona_arena'))
    law = case.gains.tick_law(10.0, on_pc=True)._replace(max_growth=8.0)
    limits = case.limits
    top = limits.max_wheel_speed
    ray = (1.0, 0.0, 0.0)
    factors = []
    for _ in range(6):   # straight ahead at the wheel limit, clipped
        ray = ray_growth(*ray, top, 0.0, True, law, limits)
        factors.append(ray[0])
    assert factors == [1.0, 2.0, 4.0, 8.0, 8.0, 8.0]
    assert ray_growth(*ray, 0.99 * top, 0.01, True, law, limits)[0] == 8.0   # still along it
    assert ray_growth(*ray, -top, 0.0, True, law, limits)[0] == 2.0          # reversed
    turn = 2 * top / limits.wheel_base
    assert ray_growth(*ray, 0.0, turn, True, law, limits)[0] == 8.0          # a turn: across
    assert ray_growth(*ray, top, 0.0, False, law, limits) == (1.0, 0.0, 0.0)   # not clipped
    for off_law, off_limits in ((law._replace(max_growth=1.0), limits),
                                (law._replace(on_pc=False), limits),
                                (law, WheelLimits())):
        assert ray_growth(*ray, top, 0.0, True, off_law, off_limits) == (1.0, 0.0, 0.0)


@pytest.mark.parametrize('seed', [0, 1, pytest.param(2, marks=pytest.mark.slow)])   # 8 s each
def test_the_arena_case_settles_every_60_s_phase_at_10_hz(seed):
    """The issue's arena target for fixed seeds: with the shipped settings (nearest assignment,
    follower pinning 1, observer) every phase settles within its 60 s, and without the
    disturbance (the floor) too. The paper's consensus law (pinning 0, fixed assignment) does
    not settle the first phase even without disturbance: its followers drive parallel to the
    leader until it arrives, at 2.25 cm/s.
    """
    case = load_experiment(resolve_config('mona_arena'))
    start = seeded_start(case, seed)
    seeded = with_start(case, start)
    times, _ = settle_times(seeded, case.gains, 10.0, start)
    floor, _ = settle_times(seeded, dataclasses.replace(case.gains, k2=0.0), 10.0, start,
                            disturbance=[0.0, 0.0])
    for t in times + floor:
        assert t is not None and t < 60.0, (seed, times, floor)
    paper = with_start(paper_arena(), start)
    consensus, _ = settle_times(paper, dataclasses.replace(paper.gains, k2=0.0), 10.0, start,
                                disturbance=[0.0, 0.0])
    assert consensus[0] is None, consensus


@given(along=st.floats(-5, 5), across=st.floats(-5, 5),
       offset=st.sampled_from([0.01, 0.1, -0.05]))
@settings(max_examples=200, deadline=None)
def test_sampled_heading_never_overshoots_and_tends_to_the_paper_law(along, across, offset):
    period = 0.1
    v, w = sampled_feedback(along, across, offset, period)
    if math.hypot(along, across) < 1e-9:
        assert abs(v) < 1e-9 and abs(w) < 1e-6
        return
    # Angle between the (reversed, for l < 0) heading and ub before and after one period.
    sign = 1.0 if offset > 0 else -1.0
    before = math.atan2(sign * across, sign * along)
    if abs(before) > math.pi - 1e-9:
        return   # exactly facing away: an unstable rest, either way round is right
    after = before - w * period
    assert abs(after) <= abs(before) + 1e-12
    assert after * before >= -1e-12            # same side: no overshoot
    tiny = 1e-7
    v0, w0 = sampled_feedback(along, across, offset, tiny)
    assert v0 == pytest.approx(along, abs=1e-3 * math.hypot(along, across))
    assert w0 == pytest.approx(across / offset, rel=1e-3, abs=1e-3)


@given(v=st.floats(-2, 2), w=st.floats(-20, 20), theta=st.floats(-4, 4))
@settings(max_examples=200, deadline=None)
def test_body_velocity_inverts_an_arc(v, w, theta):
    dt = 0.1
    end = arc_step(0.3, -0.2, theta, v, w, dt)
    mv, mw = measured_velocity(0.3, -0.2, theta, *end, dt)
    assert mv == pytest.approx(v, abs=1e-9)
    assert mw == pytest.approx(w, abs=1e-9)


def heading_rate_growth(push, k1=1.0, offset=0.01, duration=2.0, dt=1e-3):
    """Growth rate (1/s) of the heading rate of one robot at the paper law's rest state.

    The estimate is off by a forward push `push` (m/s): d = [push, 0] with k2 = 0. The robot
    starts at its rest point e = push h / k1 with the heading turned by 1e-6 rad.
    """
    from curve_formation.core.controller.law import agent_input
    target = np.array([offset - push / k1, 0.0])   # xb - target = push h / k1 at rest

    def rates(state):
        ex, ey = state[:2] + offset * np.array([math.cos(state[2]), math.sin(state[2])]) - target
        v, w, _, _ = agent_input(ex, ey, ex, ey, state[2], 0.0, 0.0, k1, 0.0, offset)
        return np.array([(v + push) * math.cos(state[2]), (v + push) * math.sin(state[2]), w])

    state = np.array([0.0, 0.0, 1e-6])   # heading h = (1, 0) at rest, turned by 1e-6 rad
    turn_rates = []
    for _ in range(int(duration / dt)):
        a = rates(state)
        b = rates(state + 0.5 * dt * a)
        c = rates(state + 0.5 * dt * b)
        d = rates(state + dt * c)
        state = state + dt / 6 * (a + 2 * b + 2 * c + d)
        turn_rates.append(abs(a[2]))
    t = np.arange(len(turn_rates)) * dt
    late = t > duration / 2
    return np.polyfit(t[late], np.log(np.array(turn_rates)[late]), 1)[0]


@pytest.mark.parametrize('push_over_k1l', [0.5, 2.0, 4.0])
def test_paper_rest_state_is_unstable_once_the_push_exceeds_k1_l(push_over_k1l):
    """docs/control-laws.md: linearised, the heading mode grows at p / l - k1 (p: forward
    push the estimate has not cancelled), so the rest state is unstable once p > k1 l.
    """
    k1, offset = 1.0, 0.01
    push = push_over_k1l * k1 * offset
    rate = heading_rate_growth(push, k1, offset)
    assert rate == pytest.approx(push / offset - k1, abs=0.05)
