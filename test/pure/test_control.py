import math

import numpy as np
import pytest
from test_graph import random_rooted_graph

from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.law import (
    agent_command,
    agent_input,
    consensus_feedback,
    FEEDBACK_HEADROOM,
    observer_input,
    tail_feedback,
)
from curve_formation.core.controller.limits import (
    saturate,
    saturate_turning,
    TURN_SHARE,
    WheelLimits,
)
from curve_formation.core.controller.observer import RAY_CLIPPED
from curve_formation.core.controller.safety import AVOIDANCE_OFF
from curve_formation.core.formation.assignment import check_assumptions, uniform_parameters
from curve_formation.core.formation.curves import FourierBasis, PolynomialBasis
from curve_formation.core.formation.dynamics import wheel_speeds


def stacked_paper_input(poses, dhat, g_bar, xi, laplacian, leader, gains):
    """The paper's stacked law, with the pseudo-inverse: what the local law is held to.

    ub = -k1 (Lbar Gbar xi_e + Lambda_bar xb_e) - k2 R dhat with xi_e = Gbar^+ xb - xi.

    Args:
        poses: (n, 3) x, y, theta.  dhat: (n, 2).  g_bar: (2n, 2H).  xi: (2H,).
        laplacian: (n, n).  leader: 0-based index.  gains: Gains.
    Returns:
        ub (n, 2) in the arena frame.
    """
    n = len(poses)
    xb = poses[:, :2] + gains.offset * np.column_stack([np.cos(poses[:, 2]),
                                                        np.sin(poses[:, 2])])
    xb_e = xb.ravel() - g_bar @ xi
    xi_e = np.linalg.pinv(g_bar) @ xb.ravel() - xi
    lam = np.zeros((n, n))
    lam[leader, leader] = 1.0
    consensus = np.kron(laplacian, np.eye(2)) @ g_bar @ xi_e + np.kron(lam, np.eye(2)) @ xb_e
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    r_dhat = np.column_stack([c * dhat[:, 0] - gains.offset * s * dhat[:, 1],
                              s * dhat[:, 0] + gains.offset * c * dhat[:, 1]])
    return -gains.k1 * consensus.reshape(n, 2) - gains.k2 * r_dhat

def local_arena_input(poses, dhat, targets, graph, gains):
    """ub_i from each agent's own and in-neighbours' errors only, mapped back by R_i."""
    xb = poses[:, :2] + gains.offset * np.column_stack([np.cos(poses[:, 2]),
                                                        np.sin(poses[:, 2])])
    errors = xb - targets
    out = np.zeros_like(errors)
    for i in range(graph.n):
        ex, ey = errors[i]
        nbrs = graph.in_neighbours(i + 1)
        fx, fy = consensus_feedback(ex, ey, errors, np.array([j - 1 for j, _ in nbrs]),
                                    np.array([w for _, w in nbrs]),
                                    1.0 if i + 1 == graph.leader else 0.0)
        v, w, _, _ = agent_input(fx, fy, ex, ey, poses[i, 2], dhat[i, 0], dhat[i, 1],
                                 gains.k1, gains.k2, gains.offset)
        th = poses[i, 2]
        r = np.array([[math.cos(th), -gains.offset * math.sin(th)],
                      [math.sin(th), gains.offset * math.cos(th)]])
        out[i] = r @ [v, w]
    return out


@pytest.mark.parametrize('seed', range(25))
def test_local_law_equals_paper_pseudo_inverse_form(seed):
    rng = np.random.default_rng(seed)
    basis = FourierBasis(int(rng.integers(2, 9))) if seed % 2 else PolynomialBasis(
        int(rng.integers(2, 9)))
    n = int(rng.integers(2, basis.H + 1))
    graph = random_rooted_graph(rng, n)
    s = uniform_parameters(n, basis.closed)
    g_bar = check_assumptions(basis, s)
    xi = rng.normal(size=2 * basis.H)
    targets = (g_bar @ xi).reshape(n, 2)
    poses = np.column_stack([rng.normal(size=(n, 2)) * 3, rng.uniform(-4, 4, n)])
    dhat = rng.normal(size=(n, 2))
    gains = Gains(k1=float(rng.uniform(0.1, 3)), k2=float(rng.uniform(0, 2)),
                  offset=float(rng.choice([-1, 1]) * rng.uniform(0.005, 0.3)))
    paper = stacked_paper_input(poses, dhat, g_bar, xi, graph.laplacian, graph.leader - 1,
                                gains)
    local = local_arena_input(poses, dhat, targets, graph, gains)
    np.testing.assert_allclose(local, paper, rtol=1e-9, atol=1e-9)


def test_estimator_rate_is_k2_r_transpose_e():
    th, l_off, k2 = 0.7, 0.05, 0.8
    e = np.array([0.3, -0.2])
    _, _, ddv, ddw = agent_input(0, 0, e[0], e[1], th, 0, 0, 1.0, k2, l_off)
    r = np.array([[math.cos(th), -l_off * math.sin(th)], [math.sin(th), l_off * math.cos(th)]])
    np.testing.assert_allclose([ddv, ddw], k2 * r.T @ e)


@pytest.mark.parametrize('v, w', [(0.1, 0.0), (-0.3, 2.0), (0.01, -40.0), (0.0, 5.0),
                                  (0.02, 0.1), (-1e-3, 1e-3)])
def test_saturation_respects_wheel_limits_and_keeps_curvature(v, w):
    base, vmax = 0.08, 0.0225
    sv, sw = saturate(v, w, base, vmax, math.inf)
    left, right = wheel_speeds(sv, sw, base)
    assert max(abs(right), abs(left)) <= vmax * (1 + 1e-12)
    assert sv * w == pytest.approx(sw * v, abs=1e-15)  # same curvature (or both zero)
    if max(abs(x) for x in wheel_speeds(v, w, base)) <= vmax:
        assert (sv, sw) == (v, w)


def test_angular_rate_bound():
    sv, sw = saturate(0.1, 10.0, 0.0, math.inf, 2.0)
    assert sw == pytest.approx(2.0)
    assert sv == pytest.approx(0.02)


@pytest.mark.parametrize('v, w, drift', [(0.1, 2.0, (0.0, 0.0)), (0.05, 0.3, (0.0, 0.0)),
                                         (-0.2, -5.0, (0.0, 0.0)), (0.05, 0.0, (0.005, 0.1)),
                                         (0.01, 3.0, (0.005, 0.1)), (0.01, 0.05, (0.0, 0.0)),
                                         (0.134, -0.3, (0.005, 0.1)), (0.1, -2.0, (0.005, 0.1))])
def test_saturation_turning_first_keeps_the_turn_and_gives_the_speed_what_is_left(v, w, drift):
    """The motion (v, w) asked, within the wheel limits around a drift: the command (motion
    minus drift) within the limits; of the motion's turn asked, at least TURN_SHARE (and at
    least what scaling down would keep), unless the command turns as fast as the wheels can;
    the speed gets what the wheels have left (a robot far off its heading turns in place); a
    motion within the limits unchanged. (0.134, -0.3) against a turn drift of 0.1: a quarter
    of the command (-0.4) would only cancel the drift and leave the robot not turning, stuck
    beside another robot (arena_demo seed 48).
    """
    base, vmax = 0.08, 0.0225
    sv, sw = saturate_turning(v, w, *drift, base, vmax, math.inf)
    left, right = wheel_speeds(sv - drift[0], sw - drift[1], base)
    assert max(abs(right), abs(left)) <= vmax * (1 + 1e-12)
    asked_v, asked_w = v - drift[0], w - drift[1]
    if max(abs(x) for x in wheel_speeds(asked_v, asked_w, base)) <= vmax:
        assert (sv, sw) == (v, w)
        return
    top = vmax / (0.5 * base)                  # the command's turn with no forward command
    command_w = sw - drift[1]
    assert abs(command_w) <= top + 1e-12
    sat_v, sat_w = saturate(asked_v, asked_w, base, vmax, math.inf)
    scaled = sat_w + drift[1] if (sat_w + drift[1]) * w > 0.0 else 0.0
    if abs(command_w) < top - 1e-12:   # the turn kept is not cut by the wheels
        assert sw * w >= 0.0 and abs(sw) <= abs(w) + 1e-12
        assert abs(sw) >= max(TURN_SHARE * abs(w), abs(scaled)) - 1e-12
    room = vmax - abs(command_w) * 0.5 * base
    assert sv - drift[0] == pytest.approx(max(-room, min(room, asked_v)))
    assert sv * v >= 0.0   # never the other way
    if abs(w) * TURN_SHARE >= top + abs(drift[1]):   # far off: in place (but for the drift)
        assert sv - drift[0] == pytest.approx(0.0, abs=1e-15)


def test_a_lone_robot_turns_in_place_first_and_arrives_as_fast_as_a_differential_drive_can():
    """A Mona facing +x, its target 30 cm to its left (no disturbance, 10 Hz): turning in
    place at the wheels' limit, then straight, takes 16.1 s (Balkcom and Mason: the fastest
    way); the law arrives within 4 % of that (scaling the saturated command down, keeping its
    curvature, drove a wide arc: 17.1 s).
    """
    from test_driving import lone_trip, MONA
    target = (0.0, 0.3)
    turn_rate = 2 * MONA.max_wheel_speed / MONA.wheel_base
    fastest = math.hypot(*target) / MONA.max_wheel_speed + 0.5 * math.pi / turn_rate
    assert lone_trip(target, False) < 1.04 * fastest


@pytest.mark.parametrize('on_pc', [False, True])
def test_the_observer_feedback_uses_the_whole_limits_unless_d_enters_before_them(on_pc):
    """A target far ahead, the estimate at zero: with the disturbance on the robot the
    observer law drives at the wheel limit; with it added on the PC, before the limits, its
    feedback keeps FEEDBACK_HEADROOM of them (else a saturated command would look the same for
    a whole ray of estimates).
    """
    limits = WheelLimits(0.08, 0.0225)
    law = Gains(2 / 3, 1 / 3, 0.01, law='observer', sampled_heading=True).tick_law(10.0, on_pc)
    v, w, *_ = agent_command(-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                             0.0, 0.0, 0.0, law, limits, np.zeros((1, 3)), 0, AVOIDANCE_OFF)
    assert w == pytest.approx(0.0, abs=1e-12)
    share = FEEDBACK_HEADROOM if on_pc else 1.0
    assert v == pytest.approx(share * limits.max_wheel_speed, rel=1e-12)


@pytest.mark.parametrize('learnt', [True, False])
def test_with_d_added_on_the_pc_the_law_turns_in_place_once_its_command_is_not_clipped(learnt):
    """The Mona arena case (d = (0.5, 0.5) added on the PC, before the wheel limits), target
    30 cm to the robot's left. With d learnt (k2 dhat = d) the command is the law's own and
    turns in place at FEEDBACK_HEADROOM of the wheels' limit. Not yet learnt, the command
    is clipped and the law keeps its curvature (observer_input's turn_first off): a turn in
    place clipped at the limits would be a saturated ray along which the observer's search
    winds up its turn channel.
    """
    limits = WheelLimits(0.08, 0.0225)
    law = Gains(2 / 3, 1 / 3, 0.01, law='observer', sampled_heading=True).tick_law(10.0, True)
    d = (0.5, 0.5)
    dhat = (d[0] / law.k2, d[1] / law.k2) if learnt else (0.0, 0.0)
    v, w, ref_v, ref_w, *_ = agent_command(0.0, -0.3, 0.0, 0.0, 0.0, -0.3, 0.0, 0.0, 0.0,
                                           *dhat, 0.0, 0.0, *d, law, limits, np.zeros((1, 3)),
                                           0, AVOIDANCE_OFF)
    room = FEEDBACK_HEADROOM * limits.max_wheel_speed
    if learnt:
        assert v == pytest.approx(0.0, abs=1e-12)
        assert w == pytest.approx(room / (0.5 * limits.wheel_base), rel=1e-9)
    else:
        kept = observer_input(0.0, -0.3, 0.0, *dhat, law.k1, law.k2, law.offset, law.hold,
                              limits.wheel_base, room, math.inf, turn_first=False)
        assert (ref_v, ref_w) == pytest.approx(kept, rel=1e-12)
        assert saturate(kept[0] + d[0], kept[1] + d[1], limits.wheel_base,
                        limits.max_wheel_speed, math.inf) == pytest.approx((v, w), rel=1e-12)


@pytest.mark.parametrize('residual', [0.0, 0.02, 0.2, 20.0])
def test_the_search_starts_on_a_command_cut_well_past_the_limits_only(residual):
    """mona_arena's limits, d added on the PC, a target far ahead: the feedback drives at
    FEEDBACK_HEADROOM of the wheel limit, and the estimate misses d by `residual` times the
    limit along the heading. agent_command's `limited` (ray_growth's start) holds only where
    the command goes past the limits by more than RAY_CLIPPED: a d not yet learnt (20x), not
    the few % camera noise in the estimate of a learnt one adds.
    """
    limits = WheelLimits(0.08, 0.0225)
    law = Gains(2 / 3, 1 / 3, 0.01, law='observer', sampled_heading=True).tick_law(10.0, True)
    d = (0.5, 0.5)
    miss = residual * limits.max_wheel_speed
    dhat = ((d[0] - miss) / law.k2, d[1] / law.k2)
    *_, limited = agent_command(-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, *dhat, 0.0, 0.0,
                                *d, law, limits, np.zeros((1, 3)), 0, AVOIDANCE_OFF)
    assert limited == (FEEDBACK_HEADROOM + residual > RAY_CLIPPED)


def test_the_tail_scales_the_feedback_as_its_square_root_near_the_target_only():
    radius, gain = 0.05, 3.0
    assert tail_feedback(0.03, -0.04, radius, gain) == (0.03, -0.04)     # |f| = radius
    assert tail_feedback(0.003, 0.004, 0.0, gain) == (0.003, 0.004)      # off
    assert tail_feedback(0.0, 0.0, radius, gain) == (0.0, 0.0)
    for size in (0.04, 0.02, 0.01, radius / gain ** 2):
        fx, fy = tail_feedback(0.6 * size, -0.8 * size, radius, gain)
        assert math.hypot(fx, fy) == pytest.approx(math.sqrt(radius * size))
        assert math.atan2(fy, fx) == pytest.approx(math.atan2(-0.8, 0.6))
    # Below radius / gain^2 the gain is capped: linear again, `gain` times the paper's.
    fx, fy = tail_feedback(1e-4, 0.0, radius, gain)
    assert (fx, fy) == pytest.approx((gain * 1e-4, 0.0))


def test_the_tail_ends_a_lone_robots_approach_sooner_than_the_linear_law():
    """One leader, no disturbance, no limits, continuous: the linear law takes ln(e0 / e) / k1
    from 20 mm to 0.1 mm; with the tail the time from radius to radius / gain^2 is finite
    (2 (sqrt(e0) - sqrt(e)) / (k1 sqrt(radius))) and the rest is k1 gain fast.
    """
    k1, radius, gain, dt = 0.5, 0.05, 3.0, 1e-3
    times = []
    for tail in (0.0, radius):
        e, t = 0.02, 0.0
        while e > 1e-4:
            fx, _ = tail_feedback(e, 0.0, tail, gain)
            e -= k1 * fx * dt
            t += dt
        times.append(t)
    linear, tailed = times
    assert linear == pytest.approx(math.log(0.02 / 1e-4) / k1, rel=1e-3)
    expected = (2 * (math.sqrt(0.02) - math.sqrt(radius / gain ** 2)) / (k1 * math.sqrt(radius))
                + math.log(radius / gain ** 2 / 1e-4) / (k1 * gain))
    assert tailed == pytest.approx(expected, rel=1e-2)
    assert tailed < 0.5 * linear
