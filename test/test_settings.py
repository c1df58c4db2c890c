"""Every controller setting has one default, range and set of choices: the node's parameter
table (nodes/formation_controller.py) agrees with the experiment schema (core/config/schema.py)
for every parameter that comes from an experiment key, and AgentConfig's own defaults agree with
both.
"""

import typing

from annotated_types import Ge, Gt, Le, Lt
from pydantic import BaseModel
from pydantic_core import PydanticUndefined
import pytest

from curve_formation.core.config.schema import ExperimentSpec
from curve_formation.nodes import formation_controller as node


PARAMS = {p.name: p for p in node.PARAMETERS}


def schema_field(path):
    """The pydantic FieldInfo at a dotted path of ExperimentSpec, and whether an enclosing
    section may be left out (an Optional sub-model).
    """
    model, optional = ExperimentSpec, False
    *sections, key = path.split('.')
    for name in sections:
        annotation = model.model_fields[name].annotation
        inner = [a for a in (annotation, *typing.get_args(annotation))
                 if isinstance(a, type) and issubclass(a, BaseModel)]
        optional = optional or type(None) in typing.get_args(annotation)
        model = inner[0]
    return model.model_fields[key], optional


def bounds(field):
    """(low, high, positive) as a Param states them, from the field's constraints."""
    low = high = None
    positive = False
    for m in field.metadata:
        if isinstance(m, Ge):
            low = m.ge
        elif isinstance(m, Gt):
            if m.gt == 0:
                positive = True
            else:
                low = m.gt
        elif isinstance(m, Le):
            high = m.le
        elif isinstance(m, Lt):
            high = m.lt
    return low, high, positive


def test_every_parameter_is_an_experiment_key_derived_or_the_nodes_own():
    classified = set(node.SCHEMA_KEYS) | set(node.DERIVED) | set(node.NODE_ONLY)
    assert set(PARAMS) == classified, set(PARAMS) ^ classified
    assert not set(node.SCHEMA_KEYS) & set(node.DERIVED + node.NODE_ONLY)


@pytest.mark.parametrize('name', sorted(node.SCHEMA_KEYS))
def test_a_parameter_has_its_experiment_keys_default_range_and_choices(name):
    param = PARAMS[name]
    field, in_optional_section = schema_field(node.SCHEMA_KEYS[name])
    default = field.default
    # a key that may be left out (null), or a required key of a section that may be (limits),
    # is 0 as a parameter when left out: none, unlimited
    absent_is_zero = (type(None) in typing.get_args(field.annotation)
                      or (in_optional_section and default is PydanticUndefined))
    if name == 'tail_gain':   # no tail: a cap of 1, no speed-up
        assert param.default == 1.0 and (param.low, param.high) == (1.0, None)
        return
    if absent_is_zero:
        zero = [] if param.kind.endswith('[]') else (False if param.kind == 'bool' else 0)
        assert param.default == zero, (name, param.default, default)
    elif default is not PydanticUndefined:
        expected = list(default) if isinstance(default, tuple) else default
        assert param.default == expected, (name, param.default, default)
    # else the file must give it; the parameter's default serves `ros2 run` alone
    args = typing.get_args(field.annotation)
    if typing.get_origin(field.annotation) is typing.Literal:
        if param.kind == 'string':
            assert set(param.choices) == set(args), (name, param.choices, args)
        else:
            assert (param.low, param.high) == (min(args), max(args)), name
        return
    low, high, positive = bounds(field)
    if positive and absent_is_zero:   # 0 stands for the key left out
        low, positive = 0.0, False
    assert (param.low, param.high, param.positive) == (low, high, positive), name


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
     {'reverse': True, 'wheel_base': 0.0, 'max_wheel_speed': 0.0, 'avoidance': False}),
    ("the observer's search needs wheel limits",
     lambda d: (without_limits(d), d['controller'].update(observer_growth=4.0)),
     {'observer_growth': 4.0, 'wheel_base': 0.0, 'max_wheel_speed': 0.0,
      'avoidance': False}),
    ('the command latency is at most 0.5 s',
     lambda d: d['controller'].update(command_latency=0.6), {'command_latency': 0.6}),
    ('the observer is of order 1 or 2', lambda d: d['controller'].update(observer_order=3),
     {'observer_order': 3}),
    ('adaptation gains are > 0', lambda d: d['controller'].update(adaptation=[1.0, 0.0]),
     {'adaptation': [1.0, 0.0]}),
]


@pytest.mark.parametrize('rule, break_file, break_params', RULES, ids=[r[0] for r in RULES])
def test_a_rule_refuses_the_same_setting_in_a_file_and_in_a_nodes_parameters(
        rule, break_file, break_params):
    data, params = arena_demo(), the_leaders_parameters()
    assert schema_accepts(data) and node_accepts(params)   # as shipped: both accepted
    break_file(data)
    assert not schema_accepts(data), rule
    assert not node_accepts({**params, **break_params}), rule


def test_agent_configs_defaults_are_the_schemas():
    """AgentConfig's own defaults (what a controller built in code gets) are the experiment's:
    an experiment that leaves every optional controller, safety and limit key out gives each
    agent the AgentConfig that its required settings alone give.
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
            'geofence', 'pc_disturbance', 'avoidance')}
        assert config == AgentConfig(**required), [
            (f.name, getattr(config, f.name), f.default) for f in dataclasses.fields(config)
            if f.name not in required and getattr(config, f.name) != f.default]
