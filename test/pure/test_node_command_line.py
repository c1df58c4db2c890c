"""Nodes explain themselves and refuse a wrong start in one line: `--help`, an experiment
given as a parameters file, a file keyed for another node. And the parameters files, start
scripts and launch file `curve-formation params` writes, without starting anything.
"""

import os
import subprocess
import sys

import pytest
import yaml

from conftest import ROOT
from curve_formation.nodes.command_line import key_pattern, node_keys, parameter_value, parse
from curve_formation.nodes.docs import NODES
from curve_formation.paths import resolve_config


ARENA_DEMO = resolve_config('arena_demo')


def module_of(name):
    return dict(NODES)[name]


@pytest.mark.parametrize('name', [name for name, _ in NODES])
def test_every_node_prints_its_parameters_for_help(name, capsys):
    module = module_of(name)
    assert module.main([name, '--help']) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'usage: ros2 run curve_formation {name} --ros-args')
    for param in module.PARAMETERS:
        assert f'  {param.name} ({param.kind}, ' in out, param.name


def test_help_from_the_console_script_exits_0():
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.nodes.formation_controller',
                           '--help'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and 'index (int, required)' in proc.stdout, proc.stderr


def one_line_error(main, args, capsys):
    status = main(args)
    err = capsys.readouterr().err
    assert status == 2
    assert err.count('\n') == 1 and err.startswith('error: '), err
    return err


def test_an_experiment_given_as_a_parameters_file_names_the_fix(capsys):
    main = module_of('formation_controller').main
    err = one_line_error(main, ['formation_controller', '--ros-args', '--params-file',
                                str(ARENA_DEMO)], capsys)
    assert 'is an experiment file, not a ROS 2 parameters file' in err
    assert f'curve-formation params {ARENA_DEMO} --out DIR' in err


def test_a_parameters_file_for_another_namespace_names_the_fix(tmp_path, capsys):
    path = tmp_path / 'robot_3.yaml'
    path.write_text('/robot_3/formation_controller:\n  ros__parameters:\n    index: 3\n')
    main = module_of('formation_controller').main
    err = one_line_error(main, ['formation_controller', '--ros-args', '-r', '__ns:=/mona_3',
                                '--params-file', str(path)], capsys)
    assert 'not for this node (/mona_3/formation_controller)' in err
    assert 'key it `/**/formation_controller`' in err


def test_a_file_that_is_no_parameters_file_or_missing_names_it(tmp_path, capsys):
    main = module_of('curve_server').main
    bad = tmp_path / 'list.yaml'
    bad.write_text('- 1\n- 2\n')
    assert 'not a ROS 2 parameters file' in one_line_error(
        main, ['curve_server', '--ros-args', '--params-file', str(bad)], capsys)
    assert 'no such parameters file' in one_line_error(
        main, ['curve_server', '--ros-args', '--params-file', str(tmp_path / 'none.yaml')],
        capsys)


@pytest.mark.parametrize('key, name, matches', [
    ('/**/formation_controller', '/mona_3/formation_controller', True),
    ('/**/formation_controller', '/formation_controller', True),
    ('/**/formation_controller', '/a/b/formation_controller', True),
    ('/**/formation_controller', '/robot_3/fake_robot', False),
    ('/**', '/robot_3/fake_robot', True),
    ('/robot_*/formation_controller', '/robot_3/formation_controller', True),
    ('/robot_*/formation_controller', '/mona_3/formation_controller', False),
    ('/robot_3/formation_controller', '/robot_3/formation_controller', True),
    ('curve_server', '/curve_server', True),
])
def test_parameters_file_keys_match_node_names_as_rcl_does(key, name, matches):
    assert bool(key_pattern(key).match(name)) == matches


def test_nested_namespace_keys_and_renames_are_understood():
    assert node_keys({'robot_3': {'formation_controller': {'ros__parameters': {'a': 1}}}}) == \
        ['robot_3/formation_controller']
    line = parse(['x', '--ros-args', '-r', '__ns:=mona_3', '-r', '__node:=ctl',
                  '--params-file', 'a.yaml'], 'formation_controller')
    assert line.fully_qualified_name == '/mona_3/ctl' and line.params_files == ('a.yaml',)


def test_params_writes_every_nodes_file_and_a_start_script_per_part(params_dir):
    files = sorted(p.name for p in (params_dir / 'params').iterdir())
    assert files == ['curve_server.yaml', 'fake_arena.yaml'] + [
        f'robot_{i}.formation_controller.yaml' for i in range(1, 10)]
    scripts = sorted(p.name for p in params_dir.glob('start_*.sh'))
    assert scripts == ['start_all.sh', 'start_controllers.sh', 'start_curve_server.sh',
                       'start_robots.sh']
    assert all(os.access(params_dir / s, os.X_OK) for s in scripts)
    text = (params_dir / 'start_controllers.sh').read_text()
    for i in range(1, 10):
        assert (f'ros2 run curve_formation formation_controller --ros-args -r __ns:=/robot_{i}'
                f' --params-file "$HERE/params/robot_{i}.formation_controller.yaml" &') in text
    assert 'export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-0}"' in text
    every = (params_dir / 'start_all.sh').read_text()
    assert every.index('formation_controller') < every.index('curve_server --ros-args')
    assert subprocess.run(['bash', '-n', str(params_dir / 'start_all.sh')]).returncode == 0
    server = yaml.safe_load((params_dir / 'params' / 'curve_server.yaml').read_text())
    # nobody measures a graph started by hand: the server waits for the 9 controllers only
    assert server['/**/curve_server']['ros__parameters']['wait_for_ready'] == 9


def test_params_with_an_observer_waits_for_it_and_measures(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'params', 'arena_demo',
                           '--out', str(tmp_path), '--observer'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    server = yaml.safe_load((tmp_path / 'params' / 'curve_server.yaml').read_text())
    assert server['/**/curve_server']['ros__parameters']['wait_for_ready'] == 10
    observer = (tmp_path / 'start_observer.sh').read_text()
    assert (f'ros2 run curve_formation curve-formation run {ARENA_DEMO} --only observer '
            '--out "$HERE/run" &') in observer
    assert 'the observer ends the run' in (tmp_path / 'start_all.sh').read_text()


class Recorded:
    """Stands in for a launch action or substitution: keeps what it was built with."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class LaunchConfiguration(Recorded):
    def perform(self, context):
        return context[self.args[0]]


@pytest.fixture
def launch_file(monkeypatch):
    """launch/formation.launch.py loaded over stand-ins for `launch` and `launch_ros` (not
    installable here): what it builds, not `ros2 launch` itself, is tested.
    """
    import runpy
    import types
    names = {'launch': ['LaunchDescription'],
             'launch.actions': ['DeclareLaunchArgument', 'ExecuteProcess', 'OpaqueFunction'],
             'launch.substitutions': [], 'launch_ros.actions': ['Node'],
             'launch_ros.substitutions': ['ExecutableInPackage']}
    for module, classes in names.items():
        fake = types.ModuleType(module)
        for name in classes:
            setattr(fake, name, type(name, (Recorded,), {}))
        monkeypatch.setitem(sys.modules, module, fake)
    sys.modules['launch.substitutions'].LaunchConfiguration = LaunchConfiguration
    root = str(ROOT)
    return runpy.run_path(os.path.join(root, 'launch', 'formation.launch.py'))


def launched(launch_file, **arguments):
    description = launch_file['generate_launch_description']()
    (actions,) = description.args
    declared = {a.kwargs['name'] if 'name' in a.kwargs else a.args[0]: a.kwargs['default_value']
                for a in actions if type(a).__name__ == 'DeclareLaunchArgument'}
    (opaque,) = [a for a in actions if type(a).__name__ == 'OpaqueFunction']
    return opaque.kwargs['function']({**declared, **arguments})


def test_the_launch_file_starts_the_graph_params_writes(launch_file, params_dir, tmp_path):
    actions = launched(launch_file, experiment='arena_demo', out=str(tmp_path),
                       controllers_per_process='1')
    nodes = [(a.kwargs['executable'], a.kwargs['namespace']) for a in actions]
    script = (params_dir / 'start_all.sh').read_text()
    lines = [line for line in script.splitlines() if line.startswith('ros2 run')]
    assert [(line.split()[3], line.split()[6].removeprefix('__ns:=')) for line in lines] == nodes
    for action in actions:
        (params_file,) = action.kwargs['parameters']
        assert (tmp_path / 'params').samefile(os.path.dirname(params_file))
        key = os.path.basename(params_file)
        assert (tmp_path / 'params' / key).read_text() == (params_dir / 'params' / key).read_text()


def test_the_launch_file_with_an_observer_measures_the_run(launch_file, tmp_path):
    actions = launched(launch_file, experiment='arena_demo', out=str(tmp_path), observer='true',
                       sim='false')
    command = actions[0].kwargs['cmd']
    assert command[1:] == ['run', 'arena_demo', '--only', 'observer', '--out',
                           str(tmp_path / 'run'), '--force', '--no-sim']
    assert command[0].args == ('curve-formation', 'curve_formation')
    assert not any(a.kwargs.get('executable') == 'fake_arena' for a in actions[1:])


def test_a_parameter_is_read_before_ros_starts_as_rcl_will_give_it(tmp_path):
    """What a process sets up before ROS starts (its realtime priority) is read as the node
    will get it: the last `-p` wins over the files, a later file over an earlier one, a key
    for another node is not this one's, and nothing given leaves the default.
    """
    first, second = tmp_path / 'a.yaml', tmp_path / 'b.yaml'
    first.write_text(yaml.safe_dump({'/**/formation_controller': {
        'ros__parameters': {'realtime_priority': 5, 'index': 3}}}))
    second.write_text(yaml.safe_dump({
        'robot_3': {'formation_controller': {'ros__parameters': {'realtime_priority': 7}}},
        '/robot_4/formation_controller': {'ros__parameters': {'realtime_priority': 9}}}))
    argv = ['formation_controller', '--ros-args', '-r', '__ns:=/robot_3', '--params-file',
            str(first), '--params-file', str(second)]
    assert parameter_value(parse(argv, 'formation_controller'), 'realtime_priority', 0) == 7
    line = parse(argv + ['-p', 'realtime_priority:=12', '-p', 'realtime_priority:=11'],
                 'formation_controller')
    assert parameter_value(line, 'realtime_priority', 0) == 11
    assert parameter_value(parse(argv[:5], 'formation_controller'), 'realtime_priority', 0) == 0
    assert parameter_value(parse(argv[:7], 'formation_controller'), 'realtime_priority', 0) == 5


def test_a_realtime_priority_out_of_range_stops_the_controller_naming_it(capsys):
    from curve_formation.nodes.formation_controller import main
    status = main(['formation_controller', '--ros-args', '-p', 'realtime_priority:=120'])
    assert status == 2
    assert "parameter 'realtime_priority': expected an integer from 0 (normal scheduling) " \
        'to 99, got 120' in capsys.readouterr().err


def test_the_realtime_priority_is_declared_once_for_the_command_line_the_run_and_the_node(
        capsys):
    """`run --realtime-priority` refuses what the controller's parameter refuses, in the same
    words, and the run, its command line and the node start from the same default.
    """
    from curve_formation import scheduling
    from curve_formation.cli import build_parser
    from curve_formation.nodes.formation_controller import PARAMETERS
    from curve_formation.run.run_options import RunOptions
    parser = build_parser()
    for given in ('120', 'ten'):
        with pytest.raises(SystemExit):
            parser.parse_args(['run', 'arena_demo', '--realtime-priority', given])
        err = capsys.readouterr().err
        assert '--realtime-priority' in err and ('to 99, got 120' in err or "'ten'" in err), err
    node_default = next(p.default for p in PARAMETERS if p.name == 'realtime_priority')
    assert (parser.parse_args(['run', 'arena_demo']).realtime_priority == node_default
            == RunOptions().realtime_priority == scheduling.CONTROLLERS)
