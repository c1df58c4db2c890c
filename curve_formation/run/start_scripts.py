"""Start scripts of an experiment's node graph: the `ros2 run` lines a lab types, one script
per part of the graph (a part per host, or all on one), written beside the parameters files.

`curve-formation params EXPERIMENT --out DIR` writes them without starting anything, and
`run` writes the same into its output folder (params/ and start_*.sh), so a run can be
started again by hand. Each script:
- exports ROS_DOMAIN_ID (ROS's default 0 when unset) and says which domain and discovery
  range its nodes use;
- starts each node as `ros2 run curve_formation <node> --ros-args -r __ns:=... --params-file
  "$HERE/params/<key>.yaml" &`, the curve server last (it waits for the others anyway);
- with robot bridges, runs `curve-formation preflight` before them (it needs the links they
  would hold) and stops, exit status 2, if it refuses;
- stops them all on Ctrl-C (SIGINT: each sends a last zero command) and exits when they do;
  start_all.sh with an observer also stops them when the observer has measured the run.
"""

from dataclasses import dataclass
from pathlib import Path
import shlex

from curve_formation.run.launches import (
    BRIDGE,
    executable,
    grouped,
    GroupLaunch,
    part_of,
    write_group_file,
    write_params_files,
)
from curve_formation.scheduling import CONTROLLERS


PACKAGE = 'curve_formation'
OBSERVER = 'observer'


def server_last(launches):
    """The launches with the curve server moved last (it waits for the others anyway)."""
    server = [launch for launch in launches if part_of(launch.module) == 'curve_server']
    return [launch for launch in launches if launch not in server] + server


MOVING = ('controllers', 'curve_server')   # the parts whose nodes make robots move


def start_order(launches):
    """The order one host starts a graph in: what moves no robot (camera, simulated robots),
    then the robot bridges (after the pre-flight, which needs their links), the controllers,
    the curve server.
    """
    ordered = server_last(launches)
    bridges = [launch for launch in ordered if launch.module == BRIDGE]
    moving = [launch for launch in ordered if part_of(launch.module) in MOVING]
    return ([launch for launch in ordered if launch not in bridges and launch not in moving]
            + bridges + moving)


def node_line(launch):
    """The `ros2 run` line of one node (its parameters file under $HERE/params)."""
    return (f'ros2 run {PACKAGE} {executable(launch.module)} --ros-args -r '
            f'__ns:={launch.namespace} --params-file "$HERE/params/{launch.key}.yaml"')


def observer_line(run_args):
    """The line of the part that measures: `curve-formation run ... --only observer` with the
    graph's own options (run_args, a list), its outputs in $HERE/run.
    """
    words = ' '.join(shlex.quote(a) for a in run_args)
    return (f'ros2 run {PACKAGE} curve-formation run {words} --only {OBSERVER} '
            '--out "$HERE/run"')


def preflight_line(experiment_path):
    """The pre-flight of the experiment's robots (`curve-formation preflight`), run before
    the robot bridges take their links; its failure stops what the script started.
    """
    return (f'ros2 run {PACKAGE} curve-formation preflight {shlex.quote(str(experiment_path))}'
            ' || { echo "pre-flight refused: no robot bridge started"; stop 2; }')


def script_text(title, lines, measured=False, gate=None):
    """A script that starts each line in the background. measured: the first line is the
    observer, whose end (the run's duration is over) stops the others. gate: (index, line):
    `line` runs in the foreground before lines[index:] start (the pre-flight).
    """
    started = [f'{line} &\npids+=($!)' for line in lines]
    if gate is not None:
        started.insert(gate[0], gate[1])
    body = '\n'.join(started)
    if measured:
        body += ('\nwait "${pids[0]}"; status=$?   # the observer ends the run\n'
                 'kill -INT "${pids[@]:1}" 2>/dev/null\nwait\nexit $status')
    else:
        body += '\nwait'

    return f"""#!/usr/bin/env bash
# {title}
# Written by `curve-formation params` (or `run`); start it on the host that runs these nodes.
# Ctrl-C stops every node it started.
set -u
HERE="$(cd "$(dirname "${{BASH_SOURCE[0]}}")" && pwd)"
export ROS_DOMAIN_ID="${{ROS_DOMAIN_ID:-0}}"
echo "ROS_DOMAIN_ID=$ROS_DOMAIN_ID, discovery range ${{ROS_AUTOMATIC_DISCOVERY_RANGE:-SUBNET}}"
pids=()
stop() {{ kill -INT "${{pids[@]}}" 2>/dev/null; wait; exit "${{1:-130}}"; }}
trap stop INT TERM
{body}
"""


def group_line(group):
    """The line of a group of controllers sharing a process (nodes.node_group)."""
    return f'ros2 run {PACKAGE} node_group "$HERE/params/{group.file_name}"'


def _part(unit):
    return 'controllers' if isinstance(unit, GroupLaunch) else part_of(unit.module)


def _line(unit):
    return group_line(unit) if isinstance(unit, GroupLaunch) else node_line(unit)


def _is_bridge(unit):
    return not isinstance(unit, GroupLaunch) and unit.module == BRIDGE


def start_scripts(launches, experiment_name, run_args=None, group_size=1):
    """{file name: text}: start_<part>.sh for each part of the graph that has nodes (and
    start_observer.sh with run_args), and start_all.sh with every line, for one host; the
    controllers `group_size` to a process (launches.grouped).
    """
    parts = {}
    if run_args is not None:
        parts[OBSERVER] = [observer_line(run_args)]
    units = grouped(server_last(launches), group_size)
    bridges = [unit for unit in units if _is_bridge(unit)]
    for unit in units:
        if unit not in bridges:
            parts.setdefault(_part(unit), []).append(_line(unit))
    gate = {}
    if bridges:   # the robots behind links: pre-flight, then their bridges
        check = preflight_line(units[-1].parameters['experiment'])
        robots = parts.setdefault('robots', [])
        gate['robots'] = (len(robots), check)
        robots += [_line(unit) for unit in bridges]
    scripts = {f'start_{part}.sh': script_text(f'{experiment_name}: {part}', lines,
                                               gate=gate.get(part))
               for part, lines in parts.items()}
    # on one host: what moves no robot, the pre-flight, then the bridges, controllers, server
    ordered = grouped(start_order(launches), group_size)
    first = parts.get(OBSERVER, [])
    still = len(first) + sum(not _is_bridge(unit) and _part(unit) not in MOVING
                             for unit in ordered)
    scripts['start_all.sh'] = script_text(
        f'{experiment_name}: the whole graph on one host',
        first + [_line(unit) for unit in ordered], measured=run_args is not None,
        gate=(still, gate['robots'][1]) if bridges else None)
    return scripts


def write_node_files(launches, folder, experiment_name, run_args=None, group_size=1):
    """Each node's parameters file in folder/params (and each group's file, with the
    controllers group_size to a process) and the start scripts in folder; returns ({launch
    key: parameters file}, [script paths]).
    """
    folder = Path(folder)
    params = write_params_files(launches, folder / 'params')
    for unit in grouped(launches, group_size):
        if isinstance(unit, GroupLaunch):
            write_group_file(unit, folder / 'params')
    written = []
    for name, text in start_scripts(launches, experiment_name, run_args, group_size).items():
        path = folder / name
        path.write_text(text)
        path.chmod(0o755)
        written.append(path)
    return params, written


@dataclass(frozen=True)
class NodeStart:
    """One node as a launch file starts it: `ros2 run curve_formation <executable>` in
    `namespace` with its parameters file; or, with arguments, a group of controllers
    (node_group with its group file).
    """

    executable: str
    namespace: str
    name: str
    params_file: Path
    arguments: tuple = ()


def graph_launches(experiment_path, folder, with_robots=True, camera=False, bridge=None,
                   rate_hz=None, bag_path=None, observed=False, physics=None,
                   controllers_per_process=None, realtime_priority=CONTROLLERS):
    """(Experiment, [NodeLaunch]) of an experiment file's graph for `params` and the launch
    file, as `run` builds it (launches.node_launches; a bridge's links in folder/links).
    observed: a `curve-formation run --only observer` (with bag_path, its recorder too) will
    measure the run, and the curve server waits for it. physics: the simulated robots' world
    (None: the experiment's). controllers_per_process: as `run` takes it (None: its default
    for the team).
    """
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.run.launches import node_launches
    from curve_formation.run.run_options import RunOptions
    experiment = load_experiment(experiment_path)
    options = RunOptions(with_robots=with_robots, camera={} if camera else None,
                         bridge=bridge, rate_hz=rate_hz, bag_path=bag_path, physics=physics,
                         controllers_per_process=controllers_per_process,
                         realtime_priority=realtime_priority)
    return experiment, node_launches(experiment, experiment_path, options,
                                      Path(folder) / 'links', observed=observed)


def graph_starts(experiment, folder, **graph):
    """The nodes of an experiment's graph (a path or shipped name) as
    launch/formation.launch.py starts them, in start_order (no pre-flight: a launch file
    cannot wait for one), their parameters files written
    into folder/params; graph: graph_launches's options.
    """
    from curve_formation.paths import resolve_config
    from curve_formation.run.run_options import RunOptions
    found, launches = graph_launches(resolve_config(experiment), folder, **graph)
    size = RunOptions(controllers_per_process=graph.get('controllers_per_process')
                      ).group_size(found.n)
    params = write_params_files(launches, Path(folder) / 'params')
    starts = []
    for unit in grouped(start_order(launches), size):
        if isinstance(unit, GroupLaunch):
            path = write_group_file(unit, Path(folder) / 'params')
            starts.append(NodeStart('node_group', '/', unit.key, path, (str(path),)))
        else:
            starts.append(NodeStart(executable(unit.module), unit.namespace, unit.name,
                                    params[unit.key]))
    return starts
