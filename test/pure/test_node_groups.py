"""Controllers grouped into few processes (run --controllers-per-process, nodes.node_group):
the default group size for a team, the same groups in params and the launch file, and a
group file without nodes refused.
"""


import yaml

from curve_formation.run.launches import held_robots
from curve_formation.run.run_options import GROUP_MOST, MOST_GROUPS, RunOptions


def test_the_default_groups_any_team_up_to_100_into_at_most_16_participants():
    """One group per core (one controller each where the team has no more robots than
    cores), at most GROUP_MOST controllers each and 16 participants in all, on any PC.
    """
    options = RunOptions()
    assert [options.group_size(n, 2) for n in (1, 2, 3, 9)] == [1, 1, 2, 5]
    assert [options.group_size(n, 16) for n in (9, 13, 14)] == [1, 1, 2]   # <= 13 groups
    for cores in (1, 2, 4, 16, 64):
        for n in range(1, 101):
            size = options.group_size(n, cores)
            groups = -(-n // size)
            # with the curve server, the robots (a fake arena or the bridges' PC), the runner
            assert groups + 3 <= 16 and size <= max(GROUP_MOST, -(-n // MOST_GROUPS)), (
                n, cores, size)
            assert groups >= min(cores, -(-n // GROUP_MOST)), (n, cores, size)
    assert options.group_size(50, 2) == 25 and options.group_size(100, 2) == 25
    assert RunOptions(controllers_per_process=4).group_size(9) == 4
    assert RunOptions(single_process=True, controllers_per_process=4).group_size(9) == 1
    assert held_robots('controllers_5-8') == [5, 6, 7, 8]
    assert held_robots('robot_3.formation_controller') == [3] and held_robots('curve_server') == []


def test_params_and_the_launch_file_group_the_controllers_as_run_does(tmp_path):
    from curve_formation.cli import main
    from curve_formation.run.start_scripts import graph_starts
    assert main(['params', 'arena_demo', '--out', str(tmp_path), '--controllers-per-process',
                 '4', '--realtime-priority', '15']) == 0
    lines = (tmp_path / 'start_controllers.sh').read_text().splitlines()
    groups = [line for line in lines if line.startswith('ros2 run')]
    assert groups == [f'ros2 run curve_formation node_group "$HERE/params/controllers_{k}'
                      '.group.yaml" &' for k in ('1-4', '5-8', '9-9')]
    group = yaml.safe_load((tmp_path / 'params' / 'controllers_5-8.group.yaml').read_text())
    assert [entry['params_file'] for entry in group] == [
        f'robot_{i}.formation_controller.yaml' for i in (5, 6, 7, 8)]
    assert all((tmp_path / 'params' / entry['params_file']).exists() for entry in group)
    controller = yaml.safe_load((tmp_path / 'params' / 'robot_5.formation_controller.yaml')
                                .read_text())['/**/formation_controller']['ros__parameters']
    assert controller['realtime_priority'] == 15   # the group takes it (node_group)
    starts = graph_starts('arena_demo', tmp_path / 'launch', controllers_per_process=4)
    grouped = [start for start in starts if start.arguments]
    assert [start.name for start in grouped] == ['controllers_1-4', 'controllers_5-8',
                                                 'controllers_9-9']
    assert all(start.executable == 'node_group' for start in grouped)
    assert not any(start.executable == 'formation_controller' for start in starts)


def test_a_group_file_that_lists_no_nodes_is_refused_naming_it(tmp_path, capsys):
    from curve_formation.nodes.node_group import main
    path = tmp_path / 'group.yaml'
    path.write_text('- {module: x}\n')
    assert main(['node_group', str(path)]) == 2
    assert f'{path}: expected a list of {{class, module, namespace, params_file}}' in \
        capsys.readouterr().err


def test_a_group_whose_parameters_file_is_not_one_is_refused_naming_it(tmp_path, capsys):
    """A listed node's parameters file that is missing, or not one node's parameters, stops
    the group before any node starts, naming the file.
    """
    from curve_formation.nodes.node_group import main
    path = tmp_path / 'group.yaml'
    path.write_text('- {module: curve_formation.nodes.formation_controller, class: '
                    'FormationController, namespace: /robot_1, params_file: robot_1.yaml}\n')
    for text in (None, '[1, 2]\n', 'a: {b: 1}\nc: {d: 2}\n', '/**/x: {parameters: {}}\n'):
        if text is not None:
            (tmp_path / 'robot_1.yaml').write_text(text)
        assert main(['node_group', str(path)]) == 2
        err = capsys.readouterr().err
        assert f"{tmp_path / 'robot_1.yaml'}: expected the parameters of one node" in err, err
