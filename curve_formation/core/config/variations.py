"""A disturbance's variations over time (disturbance.varies) checked against the team, and
as the JSON text a controller node takes them in (its disturbance_varies parameter).
"""

from collections.abc import Sequence
import json

from pydantic import TypeAdapter, ValidationError

from curve_formation.core.config import safe_yaml
from curve_formation.core.config.errors import ConfigError, validation_problem
from curve_formation.core.config.experiment import Experiment
from curve_formation.core.config.schema import VariationSpec
from curve_formation.core.controller.disturbance import Variation


def checked_variations(specs: Sequence[VariationSpec], n: int | None, source: str, key: str
                        ) -> tuple[Variation, ...]:
    out = []
    for k, v in enumerate(specs):
        agents = v.agents or []
        wrong = [i for i in agents if not 1 <= i <= (n or i)]
        if wrong or len(set(agents)) != len(agents):
            raise ConfigError(source, f'{key}[{k}].agents', f'expected distinct agents among '
                              f'1..{n or "n"}, got {agents}')
        fields = {name: value for name, value in v.model_dump(exclude={'agents'}).items()
                  if value is not None}
        out.append(Variation(**fields, agents=tuple(i - 1 for i in agents)))
    return tuple(out)


def variations_text(experiment: Experiment) -> str:
    """The experiment's disturbance.varies as JSON ('' if constant), for a node parameter."""
    varies = experiment.spec.disturbance.varies
    return json.dumps([v.model_dump(exclude_none=True) for v in varies]) if varies else ''


def variations_from_text(text: str, n: int | None, source: str) -> tuple[Variation, ...]:
    """Variations from the JSON (or YAML) list a node parameter holds ('' = none), checked as
    the experiment's `disturbance.varies` for n agents (None: any number); ConfigError naming
    `source`.
    """
    if not text.strip():
        return ()
    try:
        specs = TypeAdapter(list[VariationSpec]).validate_python(safe_yaml.load(text))
    except ValidationError as exc:
        key, problem = validation_problem(exc)
        raise ConfigError(source, f'varies{key if key.startswith("[") else "." + key}',
                          problem) from None
    except ValueError as exc:   # not YAML
        raise ConfigError(source, 'varies', str(exc)) from None
    return checked_variations(specs, n, source, 'varies')
