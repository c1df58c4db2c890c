"""What a controller believes (core.controller.plausibility, core.controller.agent): finite is not
enough.
"""

import math

import numpy as np
import pytest

from conftest import CONFIG_DIR
from curve_formation.core.config.agents import agent_configs
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.controller.agent import AgentController
from curve_formation.core.controller.plausibility import (
    bounded_command,
    DEFAULT_MAX_SPEED,
    jump_problem,
    plausible_box,
    quaternion_problem,
)
from curve_formation.core.formation.curve_codec import CodecError, decode_curve, encode_curve
from curve_formation.core.formation.curves import Curve, make_basis


@pytest.fixture(scope='module')
def arena():
    return load_experiment(CONFIG_DIR / 'arena_demo.yaml')


def leader(experiment, index=1):
    return AgentController(agent_configs(experiment, 10.0)[index - 1])


def test_a_pose_far_outside_the_arena_or_jumping_faster_than_a_robot_is_rejected(arena):
    ctrl = leader(arena)
    assert ctrl.on_pose(0.5, 0.5, 0.0, 10.0)
    assert not ctrl.on_pose(1e300, 0.5, 0.0, 10.1)
    assert 'outside' in ctrl.rejection
    # 0.3 m in 0.1 s: no Mona robot (2.25 cm/s) does that
    assert not ctrl.on_pose(0.8, 0.5, 0.0, 10.1)
    assert 'moved 0.3 m in 0.1 s' in ctrl.rejection
    assert ctrl.pose == (0.5, 0.5, 0.0) and ctrl.rejected == 2
    assert ctrl.on_pose(0.502, 0.5, 0.0, 10.1)           # what a robot does
    # a robot carried by hand is believed again once that far is reachable in the time
    assert ctrl.on_pose(0.8, 0.5, 0.0, 14.6)


def test_without_an_arena_only_absurd_positions_are_refused():
    ctrl = leader(load_experiment(CONFIG_DIR / 'closed_curve.yaml'))
    assert ctrl.on_pose(12.0, -3.0, 0.0, 1.0)
    assert not ctrl.on_pose(1e300, 0.0, 0.0, 1.1)
    assert ctrl.on_pose(40.0, 0.0, 0.0, 1.2)              # no wheel limits: no jump check


def test_a_neighbours_error_larger_than_the_arena_is_rejected(arena):
    follower = leader(arena, 2)
    j = follower.config.neighbours[0][0]
    assert follower.on_neighbour(j, 0.05, -0.02, 0, 1.0)
    assert not follower.on_neighbour(j, 1e299, 0.0, 0, 1.1)
    assert 'larger than the arena' in follower.rejection


def test_quaternions_must_be_unit():
    assert quaternion_problem(0.0, 0.0, math.sin(0.3), math.cos(0.3)) is None
    assert 'norm 0' in quaternion_problem(0.0, 0.0, 0.0, 0.0)
    assert quaternion_problem(0.0, 0.0, 2 * math.sin(0.3), 2 * math.cos(0.3)) is not None
    assert quaternion_problem(0.0, 0.0, math.nan, 1.0) is not None


def test_commands_without_wheel_limits_are_bounded_keeping_their_curvature():
    v, w = bounded_command(9.1e300, 3.0)
    assert v == pytest.approx(DEFAULT_MAX_SPEED) and w == pytest.approx(3.0 * v / 9.1e300)
    assert bounded_command(0.02, 0.5) == (0.02, 0.5)


def test_jump_check_and_box_edges():
    assert plausible_box(None)[2] == 1e4
    assert plausible_box((0.0, 0.0, 1.0, 1.0)) == (-1.0, -1.0, 2.0, 2.0)
    assert jump_problem((0.0, 0.0, 0.0), 0.019, 0.0, 0.0, 0.02) is None   # the slack
    assert jump_problem((0.0, 0.0, 0.0), 5.0, 0.0, 0.0, math.inf) is None


@pytest.mark.parametrize('label, why', [
    ('curve_id=' + '9' * 400, 'not a whole number'),
    ('curve_id=-3', 'not a whole number'),
    ('curve_id=nan', 'not a whole number'),
    ('curve_id=2147483648', 'not a whole number'),
])
def test_curve_ids_are_whole_numbers_in_range(label, why):
    curve = Curve(make_basis('fourier', 1), np.array([0.5, 0.1, 0.0, 0.5, 0.0, 0.1]))
    dims, data = encode_curve(curve, 0)
    dims[2] = (label, 0, 0)
    with pytest.raises(CodecError, match=why):
        decode_curve([(d[0], d[1]) for d in dims], data)


def test_a_basis_larger_than_a_file_allows_is_refused():
    curve = Curve(make_basis('fourier', 1), np.array([0.5, 0.1, 0.0, 0.5, 0.0, 0.1]))
    dims, data = encode_curve(curve, 0)
    dims[1] = ('basis=fourier', 10 ** 9, 0)
    with pytest.raises(CodecError, match='harmonics'):
        decode_curve([(d[0], d[1]) for d in dims], data)
