"""node_group: several of the package's nodes in one process, one context and one executor,
as a ROS component container holds its components: a team of N controllers in groups of K
needs about N / K DDS participants instead of N (`run --controllers-per-process K`).

Started as `node_group GROUP.yaml [--ros-args ...]`; GROUP.yaml lists the nodes:
`[{module: curve_formation.nodes.formation_controller, class: FormationController, namespace:
/robot_3, params_file: PATH}, ...]`, each node taking its parameters from its own
parameters file (keyed `/**/<node name>`, as `params` writes them). One node's error at
start ends the process (exit status 2, naming the node); a crash takes down this group, not
the others.
"""

from functools import partial
import importlib
from pathlib import Path
import sys
from typing import Any

from rclpy.node import Node
from rclpy.parameter import Parameter
import yaml

from curve_formation.nodes.params import ParameterError
from curve_formation.nodes.runtime import checked_priority, run_nodes
from curve_formation.nodes.shared_readers import readers_shared
from curve_formation.scheduling import CONTROLLERS, PARAMETER


NODE_NAME = 'node_group'   # also its console script's name
FIELDS = {'module', 'class', 'namespace', 'params_file'}   # of each node a group lists


def group_entries(path: str | Path) -> list[dict[str, str]]:
    """The nodes a group file lists; ParameterError naming the file if it lists none well."""
    try:
        entries = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ParameterError(f'{path}: cannot read the group ({exc})') from None
    if not isinstance(entries, list) or not entries or not all(
            isinstance(e, dict) and FIELDS <= set(e) for e in entries):
        raise ParameterError(f'{path}: expected a list of {{{", ".join(sorted(FIELDS))}}}')
    return entries


def node_parameters(params_file: str | Path) -> dict[str, Any]:
    """The parameters a `params`-written file sets (its one `/**/<name>` entry);
    ParameterError naming the file if it is not such a file.
    """
    try:
        (entry,) = yaml.safe_load(Path(params_file).read_text()).values()
        return dict(entry['ros__parameters'])
    except (OSError, yaml.YAMLError, AttributeError, TypeError, ValueError, KeyError) as exc:
        raise ParameterError(f'{params_file}: expected the parameters of one node, '
                             f'{{/**/<name>: {{ros__parameters: {{...}}}}}} ({exc!r})') from None


def make_node(entry: dict[str, str], parameters: dict[str, Any]) -> Node:
    """One listed node, in its namespace with its file's parameters."""
    try:
        return getattr(importlib.import_module(entry['module']), entry['class'])(
            namespace=entry['namespace'],
            parameter_overrides=[Parameter(k, value=v) for k, v in parameters.items()])
    except ParameterError as exc:
        raise ParameterError(f"{entry['namespace']} {entry['module']}: {exc}") from None


def main(args: list[str] | None = None) -> int:
    argv = sys.argv if args is None else args
    if len(argv) < 2 or argv[1].startswith('-'):
        print('usage: node_group GROUP.yaml [--ros-args ...]', file=sys.stderr)
        return 2
    try:
        entries = group_entries(argv[1])
    except ParameterError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    folder = Path(argv[1]).resolve().parent
    try:   # (a relative parameters file is read beside the group file)
        parameters = [node_parameters(folder / entry['params_file']) for entry in entries]
        # the process's priority: the highest its nodes ask (run_nodes)
        priority = max(checked_priority(PARAMETER, given.get(PARAMETER, CONTROLLERS))
                       for given in parameters)
    except ParameterError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    # one subscription per broadcast topic for all its nodes, the states of its robots
    # handed over in the process
    with readers_shared(entry['namespace'] for entry in entries):
        return run_nodes([partial(make_node, entry, given)
                          for entry, given in zip(entries, parameters, strict=True)],
                         argv[2:] or None,
                         priority=priority)


if __name__ == '__main__':
    raise SystemExit(main())
