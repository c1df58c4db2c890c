"""Every controller setting is declared once (core/controller/settings.py) and everything
else is made from that: a default or a set of choices written a second time anywhere in the
package is found here by searching the source; a rule between settings refuses the same
values in an experiment file and in a node's parameters; the node's parameter table is the
declaration's. (The file -> parameters -> node round trip: test_ros_nodes.)
"""

import ast
import math

import pytest

from conftest import ROOT
from curve_formation.core.controller.settings import SETTINGS
from curve_formation.nodes import formation_controller as node


PACKAGE = ROOT / 'curve_formation'
# The settings the redesign was measured on, and one of each kind besides.
NAMED = ('safety.leader_timeout', 'controller.law', 'limits.max_linear_accel',
         'avoidance.rate', 'controller.observer_rate', 'graph.pinning',
         'safety.pose_timeout', 'avoidance.margin')


def literal(node):
    """True where `node` writes a value down: a constant, a tuple or list of constants, or
    infinity (math.inf, float('inf')).
    """
    if isinstance(node, ast.Constant):
        return node.value is not None and node.value is not Ellipsis
    if isinstance(node, (ast.Tuple, ast.List)):
        return bool(node.elts) and all(literal(e) for e in node.elts)
    if isinstance(node, ast.Attribute):
        return node.attr == 'inf'
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id == 'float' and bool(node.args) and literal(node.args[0]))


def defaults_written(setting):
    """(file, line, how) of every place in the package that writes a default of `setting`:
    its declaration (Setting('key', ...)); a class field (a dataclass's, a NamedTuple's, a
    pydantic Field's) named by the key's last part or the ROS parameter; a Param, an
    argument's default or a dict entry named by the ROS parameter; each with a value written
    down (a call that passes a value, e.g. the paper's law, declares none).
    """
    names = {setting.name, setting.parameter}
    found = []
    for path in sorted(PACKAGE.rglob('*.py')):
        tree = ast.parse(path.read_text())
        where = str(path.relative_to(PACKAGE.parent))
        fields = [f for c in ast.walk(tree) if isinstance(c, ast.ClassDef) for f in c.body]
        for n in ast.walk(tree):
            if isinstance(n, ast.Call) and n.args and isinstance(n.args[0], ast.Constant):
                called = getattr(n.func, 'id', getattr(n.func, 'attr', ''))
                if called == 'Setting' and n.args[0].value == setting.key:
                    found.append((where, n.lineno, 'declaration'))
                if (called == 'Param' and n.args[0].value in names and len(n.args) > 2
                        and literal(n.args[2])):
                    found.append((where, n.lineno, 'Param'))
            if (isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name) and n in fields
                    and n.target.id in names and n.value is not None):
                value = n.value
                if (isinstance(value, ast.Call) and getattr(value.func, 'id', '') == 'Field'
                        and value.args):
                    value = value.args[0]
                if literal(value):
                    found.append((where, n.lineno, 'field'))
            if isinstance(n, ast.arguments):
                positional = n.posonlyargs + n.args
                for arg, value in zip(positional[len(positional) - len(n.defaults):],
                                      n.defaults, strict=True):
                    if arg.arg == setting.parameter and literal(value):
                        found.append((where, n.lineno if hasattr(n, 'lineno') else 0,
                                      'argument default'))
            if isinstance(n, ast.Dict):
                for k, v in zip(n.keys, n.values, strict=True):
                    if (isinstance(k, ast.Constant) and k.value == setting.parameter
                            and v is not None
                            and literal(v)):
                        found.append((where, k.lineno, 'dict entry'))
    return found


@pytest.mark.parametrize('key', NAMED)
def test_a_settings_default_is_written_once_in_the_package(key):
    written = defaults_written(SETTINGS[key])
    assert [how for _, _, how in written] == ['declaration'], written


def test_the_laws_are_named_once_in_the_package():
    """controller.law's choices, spelled out: only where the setting is declared."""
    laws = set(SETTINGS['controller.law'].choices)
    spelt = []
    for path in sorted(PACKAGE.rglob('*.py')):
        for n in ast.walk(ast.parse(path.read_text())):
            if (isinstance(n, (ast.Tuple, ast.List, ast.Set)) and n.elts
                    and {getattr(e, 'value', None) for e in n.elts} == laws):
                spelt.append((str(path.relative_to(PACKAGE.parent)), n.lineno))
    assert len(spelt) == 1 and spelt[0][0].endswith('core/controller/settings.py'), spelt


def test_the_nodes_parameters_are_the_declared_settings():
    params = {p.name: p for p in node.PARAMETERS}
    for setting in SETTINGS.values():
        param = params[setting.parameter]
        expected = (list(setting.default) if setting.kind == 'double[]' else setting.default)
        assert param.default == expected and param.description == setting.description


def node_accepts(params):
    """Whether a node given these parameters (the others at their defaults) starts: each
    checked as declare_parameters checks it, then agent_config's rules.
    """
    from types import SimpleNamespace

    from curve_formation.nodes.params import _validate, ParameterError
    values = {}
    try:
        for p in node.PARAMETERS:
            value = params.get(p.name, p.default)
            values[p.name] = _validate(p, value) if value is not None else None
        node.agent_config(SimpleNamespace(**values))
    except ParameterError:
        return False
    return True


def schema_accepts(data):
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import build_experiment
    try:
        build_experiment(data, 'rules.yaml')
    except ConfigError:
        return False
    return True


def arena_demo():
    import yaml

    from curve_formation.paths import resolve_config
    return yaml.safe_load(open(resolve_config('arena_demo')))


def the_leaders_parameters():
    from curve_formation.core.config.agents import agent_configs
    from curve_formation.core.config.loading import build_experiment
    from curve_formation.core.config.parameters import node_parameters
    experiment = build_experiment(arena_demo(), 'arena_demo.yaml')
    return node_parameters(agent_configs(experiment, 10.0)[0])


def without_limits(data):
    data.pop('limits')
    data.pop('avoidance', None)


NO_LIMITS = {'wheel_base': 0.0, 'max_wheel_speed': math.inf, 'avoidance': False}
# (rule, how the file breaks it, the parameters that break it)
RULES = [
    ('the offset is non-zero', lambda d: d['controller'].update(offset=0.0), {'offset': 0.0}),
    ('k1 > 0', lambda d: d['controller'].update(k1=0.0), {'k1': 0.0}),
    ('the tail gain times k1 stays below the rate',
     lambda d: d['controller'].update(tail={'radius': 0.1, 'gain': 20.0}),
     {'tail_radius': 0.1, 'tail_gain': 20.0}),
    ('the barrier rate is at most the control rate',
     lambda d: d.setdefault('avoidance', {}).update(rate=20.0), {'avoidance_rate': 20.0}),
    ('reversing needs wheel limits',
     lambda d: (without_limits(d), d['controller'].update(reverse=True)),
     {'reverse': True, **NO_LIMITS}),
    ("the observer's search needs wheel limits",
     lambda d: (without_limits(d), d['controller'].update(observer_growth=4.0)),
     {'observer_growth': 4.0, **NO_LIMITS}),
    ('the command latency is at most 0.5 s',
     lambda d: d['controller'].update(command_latency=0.6), {'command_latency': 0.6}),
    ('the observer is of order 1 or 2', lambda d: d['controller'].update(observer_order=3),
     {'observer_order': 3}),
    ('adaptation gains are > 0', lambda d: d['controller'].update(adaptation=[1.0, 0.0]),
     {'adaptation': [1.0, 0.0]}),
    ('a limit is a positive number or none',
     lambda d: d['limits'].update(max_linear_accel=-1.0), {'max_linear_accel': -1.0}),
]


@pytest.mark.parametrize('rule, break_file, break_params', RULES, ids=[r[0] for r in RULES])
def test_a_rule_refuses_the_same_setting_in_a_file_and_in_a_nodes_parameters(
        rule, break_file, break_params):
    data, params = arena_demo(), the_leaders_parameters()
    assert schema_accepts(data) and node_accepts(params)   # as shipped: both accepted
    break_file(data)
    assert not schema_accepts(data), rule
    assert not node_accepts({**params, **break_params}), rule


def test_no_limit_is_infinity_in_a_file_and_in_a_nodes_parameters():
    """A limit left out or written `.inf` is no limit; the node takes `.inf` the same."""
    from curve_formation.core.config.loading import build_experiment
    data = arena_demo()
    data['limits']['max_linear_accel'] = math.inf
    assert build_experiment(data, 'inf.yaml').limits.max_linear_accel == math.inf
    params = the_leaders_parameters()
    assert params['max_angular_accel'] == math.inf
    assert node_accepts({**params, 'max_linear_accel': math.inf})


def test_agent_configs_defaults_are_the_schemas():
    """AgentConfig's own defaults (what a controller built in code gets) are the experiment's:
    an experiment that leaves every optional controller, safety and limit key out gives each
    agent the AgentConfig that its required settings (and what its graph gives) alone give.
    """
    import dataclasses

    from curve_formation.core.config.agents import agent_configs
    from curve_formation.core.config.loading import build_experiment
    from curve_formation.core.controller.agent_config import AgentConfig
    experiment = build_experiment({
        'name': 'defaults', 'agents': {'count': 3, 'initial': {'random': {
            'seed': 1, 'center': [0.0, 0.0], 'half_width': [1.0, 1.0]}}},
        'graph': {'edges': [{'from': 1, 'to': 2}, {'from': 2, 'to': 3}]},
        'controller': {'k1': 1.0, 'k2': 0.5, 'offset': 0.02},
        'curves': [{'basis': 'fourier', 'harmonics': 2, 'x': 'cos(2*pi*s)',
                    'y': 'sin(2*pi*s)'}],
        'simulation': {'duration': 1.0}})
    for config in agent_configs(experiment, 10.0):
        required = {f: getattr(config, f) for f in (
            'index', 'agent_count', 'neighbours', 'pinning', 'gains', 'limits', 'rate_hz',
            'geofence', 'pc_disturbance', 'avoidance', 'leader_relay')}
        assert config == AgentConfig(**required), [
            (f.name, getattr(config, f.name), f.default) for f in dataclasses.fields(config)
            if f.name not in required and getattr(config, f.name) != f.default]
