"""A node's command line before ROS starts: `--help`, and parameters files checked for the
mistakes a new user makes (an experiment file given as a parameters file, a file keyed for
another node or namespace), each refused in one line naming the fix.

rcl itself answers the first with a 16-line traceback and ignores the second silently (the
node then stops on a required parameter it was never given).
"""

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
import re
from typing import Any

import yaml

from curve_formation.nodes.params import ParameterError


PARAMS_HINT = "`curve-formation params EXPERIMENT --out DIR` writes every node's file"
# Top-level keys of an experiment file (core/config/schema.py): a file with them is not a
# parameters file.
EXPERIMENT_KEYS = {'agents', 'curves', 'graph', 'controller', 'limits', 'simulation'}


@dataclass(frozen=True)
class NodeCommandLine:
    """What a node process was asked on its command line (after `--ros-args`)."""

    help: bool
    namespace: str          # '/' unless `-r __ns:=...`
    name: str               # the node's name, or what `-r __node:=...` renames it to
    params_files: tuple     # paths given with --params-file
    overrides: tuple = ()   # (name, value as YAML text) of each `-p NAME:=VALUE`

    @property
    def fully_qualified_name(self) -> str:
        return f'{self.namespace.rstrip("/")}/{self.name}'


def parse(argv: Sequence[str], default_name: str) -> 'NodeCommandLine':
    """NodeCommandLine of argv (sys.argv, the program first) for a node named default_name."""
    args = list(argv[1:])
    ros = args.index('--ros-args') if '--ros-args' in args else len(args)
    before, after = args[:ros], args[ros + 1:]
    namespace, name, files, overrides = '/', default_name, [], []
    k = 0
    while k < len(after):
        word = after[k]
        if word == '--ros-args':
            pass
        elif word in ('-r', '--remap') and k + 1 < len(after):
            k += 1
            target, _, value = after[k].partition(':=')
            if target == '__ns':
                namespace = value if value.startswith('/') else '/' + value
            elif target in ('__node', '__name'):
                name = value
        elif word == '--params-file' and k + 1 < len(after):
            k += 1
            files.append(after[k])
        elif word in ('-p', '--param') and k + 1 < len(after):
            k += 1
            overrides.append(tuple(after[k].split(':=', 1)))
        k += 1
    return NodeCommandLine(help=any(w in ('-h', '--help') for w in before),
                           namespace=namespace, name=name, params_files=tuple(files),
                           overrides=tuple(o for o in overrides if len(o) == 2))


def parameter_value(command_line: 'NodeCommandLine', name: str, default: Any) -> Any:
    """The value a node will be given for parameter `name` before ROS starts (e.g. to set up
    its process): the last `-p name:=VALUE`, else the last of its parameters files that sets
    it under a key matching the node, else `default`. Files are read as check_params_files
    left them (it runs first).
    """
    for key, text in reversed(command_line.overrides):
        if key == name:
            return yaml.safe_load(text)
    value = default
    for path in command_line.params_files:
        document = yaml.safe_load(Path(path).read_text())
        for key, parameters in node_entries(document):
            if key_pattern(key).match(command_line.fully_qualified_name) and isinstance(
                    parameters, dict):
                value = parameters.get(name, value)
    return value


def node_entries(document: dict[str, Any]) -> list[tuple[str, Any]]:
    """(node key, its `ros__parameters` mapping) of each entry of a parameters file's mapping:
    the key is the path of mapping keys down to it, joined by '/' (rcl allows nesting
    namespaces as mappings).
    """
    entries = []

    def walk(mapping: dict[str, Any], path: list[str]) -> None:
        for key, value in mapping.items():
            if key == 'ros__parameters':
                entries.append(('/'.join(path), value))
            elif isinstance(value, dict):
                walk(value, path + [str(key).strip('/')])
    walk(document, [])
    return entries


def node_keys(document: dict[str, Any]) -> list[str]:
    """The node keys of a parameters file's mapping (node_entries)."""
    return [key for key, _ in node_entries(document)]


def key_pattern(key: str) -> 're.Pattern[str]':
    """A regular expression for the node names a parameters file key applies to, as rcl
    matches them: `/**` any number of namespace levels, `*` one name, else the name itself.
    """
    parts = [p for p in key.strip('/').split('/') if p]
    regex = ''
    for part in parts:
        if part == '**':
            regex += '(/[^/]+)*'
        else:
            regex += '/' + '[^/]+'.join(re.escape(piece) for piece in part.split('*'))
    return re.compile(regex + '$')


def check_params_files(command_line: 'NodeCommandLine') -> None:
    """ParameterError (one line naming the fix) for a parameters file that is missing, not a
    ROS 2 parameters file (an experiment file), or that sets nothing for this node.
    """
    fqn = command_line.fully_qualified_name
    for name in command_line.params_files:
        path = Path(name)
        if not path.is_file():
            raise ParameterError(f'{name}: no such parameters file')
        try:
            document = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise ParameterError(f'{name}: not YAML ({exc.__class__.__name__}); '
                                 f'{PARAMS_HINT}') from None
        if isinstance(document, dict) and EXPERIMENT_KEYS & set(document):
            raise ParameterError(f'{name} is an experiment file, not a ROS 2 parameters file; '
                                 f'`curve-formation params {name} --out DIR` writes each '
                                 "node's parameters file from it")
        keys = node_keys(document) if isinstance(document, dict) else []
        if not keys:
            raise ParameterError(f'{name}: not a ROS 2 parameters file (expected '
                                 '`<node name>: {ros__parameters: {...}}` at the top); '
                                 f'{PARAMS_HINT}')
        if not any(key_pattern(key).match(fqn) for key in keys):
            shown = ', '.join('/' + k.strip('/') for k in keys[:3])
            raise ParameterError(f'{name} sets parameters for {shown}, not for this node '
                                 f'({fqn}): key it `/**/{command_line.name}` to apply under '
                                 f'any namespace ({PARAMS_HINT} so)')


def help_text(executable: str, module: Any) -> str:
    """What `<node> --help` prints: the node's purpose, how to start it, its parameters."""
    from curve_formation.nodes.params import text_table
    summary = ' '.join(module.__doc__.strip().split())
    return (f'usage: ros2 run curve_formation {executable} --ros-args [-r __ns:=/robot_<i>] '
            f'[--params-file FILE] [-p NAME:=VALUE ...]\n\n{summary}\n\n'
            f'parameters ({PARAMS_HINT}):\n{text_table(module.PARAMETERS)}\n')
