"""Property-based: any mutation of a valid experiment loads, or is refused cleanly."""

import copy

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import pytest
import yaml

from conftest import CONFIG_DIR
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.loading import build_experiment


BASE = yaml.safe_load((CONFIG_DIR / 'mona_arena.yaml').read_text())


def paths(node, prefix=()):
    """Every key path of a nested dict/list."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) \
        if isinstance(node, list) else []
    for key, value in items:
        out.append(prefix + (key,))
        out.extend(paths(value, prefix + (key,)))
    return out


PATHS = paths(BASE)
WRONG = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                  st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                  st.lists(st.floats(-100, 100), max_size=4), st.just({}),
                  st.just('sin(s'), st.just('__import__("os")'), st.just(-1.0), st.just(0))


@st.composite
def mutations(draw):
    data = copy.deepcopy(BASE)
    kind = draw(st.sampled_from(['replace', 'delete', 'add']))
    path = draw(st.sampled_from(PATHS))
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    if kind == 'replace':
        parent[path[-1]] = draw(WRONG)
    elif kind == 'delete':
        if isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent.pop(path[-1])
    elif isinstance(parent, dict):
        parent[draw(st.text('abcdefghijklmnopqrstuvwxyz_', min_size=1, max_size=10))] = 1
    return data


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutations())
def test_mutated_experiments_load_or_are_refused_with_file_and_key(data):
    try:
        experiment = build_experiment(data, 'arena.yaml')
    except ConfigError as exc:
        message = str(exc)
        assert message.startswith('arena.yaml: ')
        assert '\n' not in message.strip() or 'Traceback' not in message
        return
    # Whatever loads is usable: assumptions hold for every curve.
    assert all(p.curve.basis.H >= experiment.n for p in experiment.phases)


@pytest.mark.parametrize('text', ['', 'just a string', '[1, 2, 3]', 'a: [', '{name: 1}'])
def test_non_experiments_are_refused(tmp_path, text):
    from curve_formation.core.config.loading import load_experiment
    path = tmp_path / 'x.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=r'x\.yaml: '):
        load_experiment(path)
