"""An experiment's node graph: `ros2 launch curve_formation formation.launch.py
experiment:=arena_demo`.

Arguments: experiment (a YAML path or shipped name), out (where the nodes' parameters files
go; default /tmp/curve_formation/<experiment>), sim (true: fake robots; false: real robots
publish /robot_<i>/pose), camera (true: poses from camera_tracker), bridge ('', udp or pty),
observer (true: `curve-formation run --only observer` measures the run into OUT/run and the
curve server waits for it), controllers_per_process (K controllers to a process, node_group),
realtime_priority (the controllers' processes' SCHED_FIFO priority, 0: normal scheduling).
The nodes and their parameters come from the same generator as
`curve-formation params` and `run` (curve_formation.run.start_scripts.graph_starts).
"""

from pathlib import Path

from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.substitutions import ExecutableInPackage

from curve_formation.run.start_scripts import graph_starts
from curve_formation.scheduling import CONTROLLERS
from launch import LaunchDescription


ARGUMENTS = (
    ('experiment', 'arena_demo', 'experiment YAML path or shipped name'),
    ('out', '', "folder for the nodes' parameters files (default /tmp/curve_formation/NAME)"),
    ('sim', 'true', 'true: fake robots; false: the real robots publish /robot_<i>/pose'),
    ('camera', 'false', 'true: poses from camera_tracker (the experiment needs `camera`)'),
    ('bridge', '', "'', udp or pty: each cmd_vel through a robot_bridge"),
    ('observer', 'false', 'true: curve-formation run --only observer measures the run'),
    ('controllers_per_process', '', "K controllers share each process ('': one group per "
     'core, at most 25 controllers and 13 groups; 1: a process each)'),
    ('realtime_priority', str(CONTROLLERS), "SCHED_FIFO priority (1-99) of the controllers' "
     'processes; 0: normal scheduling (see curve-formation run --help)'),
)


def _nodes(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)
    experiment = arg('experiment')
    out = Path(arg('out') or f'/tmp/curve_formation/{Path(experiment).stem}')
    observed = arg('observer') == 'true'
    starts = graph_starts(experiment, out, with_robots=arg('sim') == 'true',
                          camera=arg('camera') == 'true', bridge=arg('bridge') or None,
                          observed=observed,
                          controllers_per_process=int(arg('controllers_per_process') or 0)
                          or None,
                          realtime_priority=int(arg('realtime_priority') or CONTROLLERS))
    actions = [Node(package='curve_formation', executable=start.executable,
                    arguments=list(start.arguments), output='screen') if start.arguments
               else Node(package='curve_formation', executable=start.executable,
                         namespace=start.namespace, name=start.name,
                         parameters=[str(start.params_file)], output='screen')
               for start in starts]
    if observed:
        command = [ExecutableInPackage('curve-formation', 'curve_formation'), 'run',
                   experiment, '--only', 'observer',
                   '--out', str(out / 'run'), '--force']
        command += [] if arg('sim') == 'true' else ['--no-sim']
        command += ['--camera'] if arg('camera') == 'true' else []
        command += ['--bridge', arg('bridge')] if arg('bridge') else []
        actions.insert(0, ExecuteProcess(cmd=command, output='screen'))
    return actions


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in ARGUMENTS]
        + [OpaqueFunction(function=_nodes)])
