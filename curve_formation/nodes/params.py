"""Declare and validate a node's parameters in one place, from a table of Param entries.

Each Param has a default, a description and optional bounds; the table is also what the
parameter tables of docs/nodes.md are generated from (`curve-formation nodes-doc`), so they
cannot drift apart.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math
from types import SimpleNamespace
from typing import Any, Optional, TYPE_CHECKING

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterUninitializedException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from curve_formation.core.controller.settings import Setting


if TYPE_CHECKING:
    from curve_formation.core.config.experiment import Experiment
    from curve_formation.core.controller.disturbance import Variation


class ParameterError(ValueError):
    """A parameter value refused at start; the message names the parameter."""


_ARRAY_TYPES = {'double[]': Parameter.Type.DOUBLE_ARRAY, 'int[]': Parameter.Type.INTEGER_ARRAY,
                'string[]': Parameter.Type.STRING_ARRAY}


@dataclass(frozen=True)
class Param:
    """One parameter: name, default (None = required), description, bounds and choices.

    kind: 'double', 'int', 'bool', 'string' or an array kind ('double[]', 'int[]').
    low/high: inclusive bounds; positive: must be > 0; choices: allowed strings.
    """

    name: str
    kind: str
    default: Any
    description: str
    low: Optional[float] = None
    high: Optional[float] = None
    positive: bool = False
    choices: tuple = ()
    read_only: bool = True
    unlimited: bool = False   # infinity (`.inf`) allowed: no limit

    @classmethod
    def of(cls, setting: Setting) -> 'Param':
        """The parameter of a controller setting (core.controller.settings.Setting): its
        name, type, default, meaning and range as declared there. Where the setting's
        default lies outside its range (0: off, for a setting whose file section may be left
        out) the range starts at the default.
        """
        low, positive = setting.low, False
        if setting.above is not None:
            first = (setting.default[0] if setting.kind == 'double[]' else setting.default)
            if first > setting.above:
                positive = setting.above == 0.0
                low = None if positive else setting.above
            else:
                low = setting.default
        high = setting.high
        choices = tuple(setting.choices) if setting.kind == 'string' else ()
        if setting.choices and setting.kind == 'int':
            low, high = min(setting.choices), max(setting.choices)
        default = list(setting.default) if setting.kind == 'double[]' else setting.default
        return cls(setting.parameter, setting.kind, default, setting.description, low=low,
                   high=high, positive=positive, choices=choices,
                   unlimited=setting.unlimited)

    def descriptor(self) -> ParameterDescriptor:
        # A double also takes an integer (`-p k1:=2`, `k1: 2` in a parameters file): typed
        # dynamically, converted and range-checked in _validate.
        desc = ParameterDescriptor(description=self.description, read_only=self.read_only,
                                   dynamic_typing=self.kind in ('double', 'double[]'))
        if self.choices:
            desc.additional_constraints = f'one of {", ".join(self.choices)}'
        if self.low is not None or self.high is not None:
            low = -math.inf if self.low is None else self.low
            high = math.inf if self.high is None else self.high
            if self.kind == 'int':
                desc.integer_range = [IntegerRange(from_value=int(max(low, -2**62)),
                                                   to_value=int(min(high, 2**62)), step=0)]
            elif self.kind == 'double':
                desc.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                                to_value=float(high), step=0.0)]
        return desc

    def doc_default(self) -> str:
        if self.default is None:
            return '(required)'
        if isinstance(self.default, float) and math.isinf(self.default):
            return '.inf'   # as a parameters file writes it: no limit
        return repr(self.default)


def declare_parameters(node: Node, table: Sequence['Param']) -> SimpleNamespace:
    """Declare every Param of table on node; returns a namespace of validated values.

    Raises ParameterError naming the parameter on a missing, mistyped or out-of-range value.
    """
    values = {}
    for p in table:
        default = p.default
        dynamic = p.descriptor().dynamic_typing
        if default is None or (isinstance(default, list) and not default):
            # no value to declare with: the type (a dynamically typed one takes none)
            default = None if dynamic else _ARRAY_TYPES.get(p.kind) or _scalar_type(p.kind)
        try:
            node.declare_parameter(p.name, default, p.descriptor())
            value = node.get_parameter(p.name).value
            if value is None:   # declared without a value and given none
                raise ParameterUninitializedException(p.name)
        except ParameterUninitializedException:
            if p.default is None:
                raise ParameterError(
                    f'parameter {p.name!r} is required ({p.description}): give it with '
                    f'`-p {p.name}:=VALUE` or a --params-file (`curve-formation params '
                    'EXPERIMENT --out DIR` writes them)') from None
            value = list(p.default)
        except InvalidParameterTypeException as exc:
            raise ParameterError(f'parameter {p.name!r} has the wrong type, expected {p.kind} '
                                 f'({p.description}): {exc}') from None
        except InvalidParameterValueException as exc:
            raise ParameterError(f'parameter {p.name!r} is out of range: {exc}') from None
        values[p.name] = _validate(p, value)
    return SimpleNamespace(**values)


def _scalar_type(kind: str) -> Parameter.Type:
    return {'double': Parameter.Type.DOUBLE, 'int': Parameter.Type.INTEGER,
            'bool': Parameter.Type.BOOL, 'string': Parameter.Type.STRING}[kind]


def _validate(p: Param, value: Any) -> Any:
    if p.kind in ('double', 'double[]'):
        value = _as_doubles(p, value)
    items = list(value) if p.kind.endswith('[]') else [value]
    for item in items:
        if (p.low is not None and item < p.low) or (p.high is not None and item > p.high):
            raise ParameterError(f'parameter {p.name!r} must be in [{p.low}, {p.high}], got '
                                 f'{value!r} ({p.description})')
        if isinstance(item, float) and not math.isfinite(item) and not (
                p.unlimited and math.isinf(item) and item > 0):
            raise ParameterError(f'parameter {p.name!r} must be finite, got {value!r}')
        if p.positive and not item > 0:
            raise ParameterError(f'parameter {p.name!r} must be > 0, got {value!r} '
                                 f'({p.description})')
        if p.choices and item not in p.choices:
            raise ParameterError(f'parameter {p.name!r} must be one of {list(p.choices)}, got '
                                 f'{value!r}')
    return list(value) if p.kind.endswith('[]') else value


def _as_doubles(p: Param, value: Any) -> float | list[float]:
    """A double (or double array) parameter's value as float(s): integers are accepted."""
    def number(item: Any) -> float:
        if isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ParameterError(f'parameter {p.name!r} has the wrong type, expected '
                                 f'{p.kind} ({p.description}), got {item!r}')
        return float(item)
    if p.kind == 'double[]':
        if isinstance(value, (str, bytes)) or not hasattr(value, '__iter__'):
            raise ParameterError(f'parameter {p.name!r} has the wrong type, expected '
                                 f'{p.kind} ({p.description}), got {value!r}')
        return [number(item) for item in value]
    return number(value)


def markdown_table(table: Sequence[Param]) -> str:
    """The table as Markdown rows: name, type, default, description."""
    rows = ['| parameter | type | default | meaning |', '| --- | --- | --- | --- |']
    for p in table:
        bounds = ''
        if p.positive:
            bounds = ' (> 0)'
        elif p.low is not None or p.high is not None:
            bounds = f' ([{p.low if p.low is not None else "-inf"}, '
            bounds += f'{p.high if p.high is not None else "inf"}])'
        choices = f' One of: {", ".join(p.choices)}.' if p.choices else ''
        text = f'{p.description}{bounds}.{choices}'.replace('|', '\\|')
        rows.append(f'| `{p.name}` | {p.kind} | `{p.doc_default()}` | {text} |')
    return '\n'.join(rows)


def text_table(table: Sequence[Param]) -> str:
    """The table as plain text for a terminal: one parameter per line, then its meaning."""
    lines = []
    for p in table:
        default = 'required' if p.default is None else f'default {p.default!r}'
        lines.append(f'  {p.name} ({p.kind}, {default})')
        choices = f' One of: {", ".join(p.choices)}.' if p.choices else ''
        lines.append(f'      {p.description}.{choices}')
    return '\n'.join(lines)


def experiment_parameter(value: str, needs: Sequence[str] = ()) -> 'Experiment':
    """The Experiment named by an `experiment` parameter (path or shipped name).

    needs: sections it must have (e.g. ('camera',)). ParameterError names the parameter.
    """
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.paths import resolve_config
    try:
        experiment = load_experiment(resolve_config(value))
    except (ConfigError, FileNotFoundError) as exc:
        raise ParameterError(f"parameter 'experiment': {exc}") from None
    for section in needs:
        if getattr(experiment.spec, section) is None:
            raise ParameterError(f"parameter 'experiment': {experiment.source} has no "
                                 f'`{section}` section')
    return experiment


def node_variations(value: str, n: int | None = None) -> tuple['Variation', ...]:
    """The Variations a `disturbance_varies` parameter holds (JSON; '' = none) for n agents
    (None: any number); ParameterError names the parameter and what is wrong.
    """
    if not value.strip():
        return ()   # without importing the experiment loader: ~0.2 s of a node's start-up
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.variations import variations_from_text
    try:
        return variations_from_text(value, n, "parameter 'disturbance_varies'")
    except ConfigError as exc:
        raise ParameterError(str(exc)) from None
