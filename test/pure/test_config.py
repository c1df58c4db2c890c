"""Bad experiment files are refused with the file, the key and what was expected."""

import copy
import subprocess
import sys

import numpy as np
import pytest
import yaml

from conftest import CONFIG_DIR
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.loading import build_experiment, load_experiment


@pytest.mark.parametrize('name', sorted(p.stem for p in CONFIG_DIR.glob('*.yaml')))
def test_shipped_experiments_load(name):
    experiment = load_experiment(CONFIG_DIR / f'{name}.yaml')
    assert experiment.n == experiment.spec.agents.count
    for phase in experiment.phases:
        assert phase.fit.rms_residual < 1e-9


def set_path(data, path, value):
    node = data
    for key in path[:-1]:
        node = node[key]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value


DELETE = object()

BROKEN = [
    # (what, path, value, key in the message, words in the message)
    ('misspelt key', ('controller', 'k_1'), 1.0, 'controller.k_1', 'Extra inputs'),
    ('negative gain', ('controller', 'k1'), -1.0, 'controller.k1', 'greater than 0'),
    ('gain as text', ('controller', 'k2'), 'fast', 'controller.k2', 'valid number'),
    ('zero offset', ('controller', 'offset'), 0.0, 'controller.offset', 'non-zero'),
    # (an offset of 1.3e154 m, drawn by test_config_properties, overflowed the distances
    # of the nearest assignment)
    ('offset beyond any arena', ('controller', 'offset'), 1.3e154, 'controller.offset',
     'less than or equal to 10000'),
    ('missing duration', ('simulation', 'duration'), DELETE, 'simulation.duration', 'required'),
    ('unknown law', ('controller', 'law'), 'magic', 'controller.law', "'paper'"),
    ('edge to missing agent', ('graph', 'edges', 0, 'to'), 9, 'graph', 'numbered 1..6'),
    ('no spanning tree', ('graph', 'edges'), [{'from': 1, 'to': 2}, {'from': 3, 'to': 4},
                                              {'from': 4, 'to': 3}, {'from': 4, 'to': 5},
                                              {'from': 5, 'to': 6}], 'graph',
     'no spanning tree'),
    ('negative pinning', ('graph', 'pinning'), -1.0, 'graph.pinning', 'greater than or equal'),
    ('two leaders', ('graph', 'edges'), [{'from': 1, 'to': 2}, {'from': 2, 'to': 3}],
     'graph', 'receive from nobody'),
    ('too few harmonics', ('curves', 0, 'harmonics'), 2, 'curves[0]', 'Assumption 2'),
    ('bad expression', ('curves', 0, 'x'), 'cos(2*pi*s', 'curves[0]', 'cannot parse'),
    ('forbidden expression', ('curves', 0, 'x'), 'open("f")', 'curves[0]', "'open'"),
    ('order on a fourier basis', ('curves', 0, 'order'), 3, 'curves[0]', 'does not apply'),
    ('two curve sources', ('curves', 0, 'bezier'), [[0, 0], [1, 1]], 'curves[0]',
     'exactly one curve source'),
    ('wrong pose count', ('agents', 'initial'), {'poses': [[0, 0, 0]]},
     'agents.initial.poses', 'expected 6'),
    ('wrong disturbance shape', ('disturbance', 'value'), [1, 2, 3], 'disturbance.value',
     'at most 2 items'),
    ('negative tail radius', ('controller', 'tail'), {'radius': -0.01, 'gain': 2.0},
     'controller.tail.radius', 'greater than 0'),
]


@pytest.mark.parametrize('what, path, value, key, words', BROKEN, ids=[b[0] for b in BROKEN])
def test_broken_experiment_is_refused_clearly(closed_curve_dict, what, path, value, key,
                                              words):
    data = copy.deepcopy(closed_curve_dict)
    set_path(data, path, value)
    with pytest.raises(ConfigError) as info:
        build_experiment(data, 'exp.yaml')
    message = str(info.value)
    assert message.startswith(f'exp.yaml: {key}'), message
    assert words in message, message


def test_switch_times_must_increase(arena_dict):
    arena_dict['curves'][1]['start'] = 0.0
    with pytest.raises(ConfigError, match=r'curves\[1\]\.start: switch times must increase'):
        build_experiment(arena_dict, 'arena.yaml')


def test_a_tail_gain_that_would_overshoot_a_sampled_command_is_refused(arena_dict):
    arena_dict['controller']['tail'] = {'radius': 0.05, 'gain': 20.0}
    with pytest.raises(ConfigError, match=r'arena.yaml: controller.tail.gain: tail.gain 20 '
                       r'times k1 0.666667 must stay below rate_hz 10'):
        build_experiment(arena_dict, 'arena.yaml')
    arena_dict['controller']['tail'] = {'radius': 0.05, 'gain': 3.0}
    assert build_experiment(arena_dict, 'arena.yaml').gains.tail_gain == 3.0


def test_initial_poses_outside_the_arena(arena_dict):
    arena_dict['agents']['initial'] = {'poses': [[0.5, 0.4, 0.0]] * 8 + [[2.5, 0.4, 0.0]]}
    with pytest.raises(ConfigError, match=r'agents.initial: agent 9 starts at .* outside'):
        build_experiment(arena_dict, 'arena.yaml')


CAMERA_BROKEN = [
    ('robot id count', ('robot_ids',), [1, 2, 3], 'camera.robot_ids', 'expected 9'),
    ('unknown dictionary', ('dictionary',), 'DICT_9X9_5', 'camera.dictionary',
     'unknown ArUco dictionary'),
    ('id beyond the dictionary', ('robot_ids', 8), 77, 'camera', 'ids 0..49'),
    ('repeated id', ('corners', 0, 'id'), 3, 'camera', 'repeated: [3]'),
    ('one corner', ('corners',), [{'id': 40, 'position': [0.05, 0.05]}], 'camera.corners',
     'at least 2'),
    ('misspelt key', ('marker_sise',), 0.04, 'camera.marker_sise', 'Extra inputs'),
]


@pytest.mark.parametrize('what, path, value, key, words', CAMERA_BROKEN,
                         ids=[b[0] for b in CAMERA_BROKEN])
def test_broken_camera_section_is_refused_clearly(arena_dict, what, path, value, key, words):
    set_path(arena_dict['camera'], path, value)
    with pytest.raises(ConfigError) as info:
        build_experiment(arena_dict, 'arena.yaml')
    message = str(info.value)
    assert message.startswith(f'arena.yaml: {key}') and words in message, message


def test_camera_needs_an_arena(arena_dict):
    del arena_dict['arena']
    with pytest.raises(ConfigError, match='arena.yaml: camera: a camera needs `arena`'):
        build_experiment(arena_dict, 'arena.yaml')


def test_robots_that_cannot_be_separated_are_refused(arena_dict):
    arena_dict['agents']['initial']['random']['min_separation'] = 0.5
    with pytest.raises(ConfigError, match='min_separation: cannot place 9 robots 0.5 m'):
        build_experiment(arena_dict, 'arena.yaml')


def test_random_starts_keep_their_separation(arena_dict):
    poses = build_experiment(arena_dict, 'arena.yaml').initial_poses
    gaps = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=2)
    assert gaps[~np.eye(len(poses), dtype=bool)].min() >= 0.1


def test_not_a_mapping():
    with pytest.raises(ConfigError, match='top level'):
        build_experiment([1, 2], 'list.yaml')


def test_cli_reports_one_line_and_exit_2(tmp_path, closed_curve_dict):
    closed_curve_dict['controller']['k1'] = -2
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump(closed_curve_dict))
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'sim', str(bad),
                           '--out', str(tmp_path / 'out')], capture_output=True, text=True)
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'error: {bad}: controller.k1:'), lines


def test_invalid_yaml_names_the_file(tmp_path):
    bad = tmp_path / 'broken.yaml'
    bad.write_text('name: [unclosed\n')
    with pytest.raises(ConfigError, match='broken.yaml: not valid YAML'):
        load_experiment(bad)


def test_reversing_without_wheel_limits_to_time_it_by_is_refused(arena_dict):
    arena_dict['controller']['reverse'] = True
    arena_dict['controller']['observer_growth'] = 1.0
    assert build_experiment(arena_dict, 'arena.yaml').gains.reverse
    del arena_dict['limits']
    with pytest.raises(ConfigError, match=r'arena.yaml: controller.reverse: needs '
                       r'limits.wheel_base and limits.max_wheel_speed'):
        build_experiment(arena_dict, 'arena.yaml')


def test_observer_growth_without_wheel_limits_to_saturate_is_refused(arena_dict):
    arena_dict['controller']['observer_growth'] = 8.0
    arena_dict['controller']['reverse'] = False
    assert build_experiment(arena_dict, 'arena.yaml').gains.observer_growth == 8.0
    del arena_dict['limits']
    with pytest.raises(ConfigError, match=r'arena.yaml: controller.observer_growth: needs '
                       r'limits.wheel_base and limits.max_wheel_speed'):
        build_experiment(arena_dict, 'arena.yaml')
