"""Bad input never crashes a command and never reads as success: one `error:` line naming the
file and the key, exit status 2, in bounded time and memory; metrics never claim a settling
they did not see.
"""

import json
import math
import subprocess
import sys

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from conftest import CONFIG_DIR
from curve_formation.cli import main
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.loading import build_experiment, parse_experiment_text
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate


BASE = (CONFIG_DIR / 'closed_curve.yaml').read_text()


def variant(old, new, text=BASE):
    assert old in text, old
    return text.replace(old, new, 1)


CURVE_X = 'x: (8 + sin(4*pi*s)) * cos(2*pi*s) + 4'
LAUGHS = 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + ''.join(
    f'{chr(98 + k)}: &{chr(98 + k)} [*{chr(97 + k)},*{chr(97 + k)},*{chr(97 + k)},'
    f'*{chr(97 + k)},*{chr(97 + k)},*{chr(97 + k)},*{chr(97 + k)},*{chr(97 + k)},'
    f'*{chr(97 + k)}]\n' for k in range(8))

# name: (file content, what the error line must say)
BAD = {
    'nan start pose': (variant('random: {seed: 1, center: [4.0, 4.0], half_width: [10.0, '
                               '10.0]}', 'poses: [[.nan, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, '
                               '0], [4, 0, 0], [5, 0, 0]]'), 'agents.initial.poses'),
    'infinite start pose': (variant('random: {seed: 1, center: [4.0, 4.0], half_width: [10.0, '
                                    '10.0]}', 'poses: [[.inf, 0, 0], [1, 0, 0], [2, 0, 0], '
                                    '[3, 0, 0], [4, 0, 0], [5, 0, 0]]'), 'finite'),
    'nan disturbance': (variant('value: [1.0, 1.0]', 'value: [.nan, 1.0]'),
                        'disturbance.value'),
    'huge integer literal': (variant(CURVE_X, 'x: ' + '9' * 400 + ' * s'), 'too large'),
    'long expression': (variant(CURVE_X, 'x: ' + '+'.join(['s'] * 3000)), 'at most 5000'),
    'deeply nested expression': (variant(CURVE_X, 'x: ' + '(' * 300 + 's' + ')' * 300),
                                 'curves[0]'),
    'utf-16 file': (BASE.encode('utf-16'), 'UTF-16'),
    'binary file': (bytes(range(256)) * 8, 'not UTF-8'),
    'nul in text': ('name: a\x00b\n', 'NUL'),
    'deeply nested yaml': ('name: ' + '[' * 5000 + ']' * 5000 + '\n', 'nested more than'),
    'billion laughs': (LAUGHS, 'aliases'),
    'duplicate key': (BASE + 'controller: {k1: 5.0, k2: 1.0, offset: 0.01}\n',
                      "key 'controller' appears twice"),
    'too many steps': (variant('duration: 60.0', 'duration: 1.0e+9'), 'simulation'),
    'too many samples': (variant('record_dt: 0.01', 'record_dt: 0.001').replace(
        'duration: 60.0', 'duration: 99000.0'), 'simulation.record_dt'),
    'record_dt off the step': (variant('record_dt: 0.01', 'record_dt: 0.0015'),
                               'simulation.record_dt: record_dt (0.0015 s) must be a whole'),
    'control period off the step': (variant('rate_hz: null', 'rate_hz: 7.0'),
                                    'controller.rate_hz'),
    'zero-size curve': (variant(CURVE_X, 'x: 1.0 + 0*s').replace(
        'y: (8 + cos(4*pi*s)) * sin(2*pi*s) + 4', 'y: 2.0 + 0*s'), 'zero size'),
    'empty file': ('', 'expected a mapping'),
    'a list': ('- 1\n- 2\n', 'expected a mapping'),
    'file too big': ('# ' + 'x' * 1_100_000 + '\n' + BASE, 'more than 1000000 bytes'),
    'huge count': (variant('count: 6', 'count: ' + '9' * 60), 'agents.count'),
    'long string value': (variant('name: closed_curve', 'name: ' + 'n' * 200_000).replace(
        'k1: 1.0', 'k1: "' + 'k' * 200_000 + '"'), 'controller.k1'),
}


@pytest.mark.parametrize('name', list(BAD))
def test_bad_experiment_file_is_one_error_line(name, tmp_path, capsys):
    content, expected = BAD[name]
    path = tmp_path / 'bad.yaml'
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    for command in (['check', str(path)], ['sim', str(path), '--out', str(tmp_path / 'o')]):
        assert main(command) == 2, (name, command)
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f'error: {path}'), err[:600]
        assert len(lines[0]) < 500 and expected in lines[0], lines[0]
        assert 'Traceback' not in err


def test_a_long_sum_of_terms_parses_and_runs(tmp_path, capsys):
    """A thousand terms (2 kB) is an ordinary size: no recursion limit hit."""
    path = tmp_path / 'long.yaml'
    path.write_text(variant(CURVE_X, 'x: 8 * cos(2*pi*s) + 4 + ' + '+'.join(['0'] * 1000)))
    assert main(['check', str(path)]) == 0, capsys.readouterr().err


def test_the_billion_laughs_cost_no_time_or_memory():
    """In its own process, with 1 GB of address space: refused within seconds."""
    code = ('import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30)); '
            'from curve_formation.core.config.errors import ConfigError\n'
            'from curve_formation.core.config.loading import parse_experiment_text\n'
            'try:\n    parse_experiment_text(sys.stdin.read(), "laughs.yaml")\n'
            'except ConfigError as exc:\n    print(exc)')
    proc = subprocess.run([sys.executable, '-c', code], input=LAUGHS + 'c2: [*i, *i, *i]\n',
                          capture_output=True, text=True, timeout=20)
    assert proc.returncode == 0 and 'aliases' in proc.stdout, proc.stdout + proc.stderr


def test_outputs_that_cannot_be_written_are_refused_before_running(tmp_path, capsys):
    taken = tmp_path / 'a_file'
    taken.write_text('x')
    assert main(['sim', 'closed_curve', '--out', str(taken)]) == 2
    assert 'is not a folder' in capsys.readouterr().err
    assert main(['sim', 'closed_curve', '--out', '/proc/curve_formation_out']) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: /proc/curve_formation_out') and len(err.splitlines()) == 1


def test_a_rate_that_is_not_a_whole_number_of_steps_is_refused(tmp_path, capsys):
    assert main(['sim', 'closed_curve', '--rate', '7', '--out', str(tmp_path)]) == 2
    assert 'must be a whole multiple of dt' in capsys.readouterr().err


def test_non_finite_errors_are_never_reported_as_settled():
    """NaN compares false: 'never above the tolerance' must not read as settled."""
    t = np.arange(0.0, 2.0, 0.1)
    norm = np.full_like(t, np.nan)
    assert metrics.settle_time(t, norm, 1e-3, 0.0, np.inf) is None
    norm[:5] = 1.0
    assert metrics.settle_time(t, norm, 1e-3, 0.0, np.inf) is None
    data = {'settled': False, 'final_error_norm': float('nan'), 'peak': np.float64(np.inf)}
    text = metrics.strict_json(data)
    assert json.loads(text) == {'settled': False, 'final_error_norm': None, 'peak': None}


@given(st.data())
@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
def test_mutated_experiment_text_is_refused_cleanly_or_runs(data):
    """Edits of the YAML text itself (characters inserted, deleted or replaced, lines
    repeated or dropped): either a clear ConfigError line, or an experiment the simulator
    runs.
    """
    text = BASE
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(['insert', 'delete', 'replace', 'repeat', 'drop']))
        lines = text.splitlines(keepends=True)
        if kind in ('repeat', 'drop') and lines:
            k = data.draw(st.integers(0, len(lines) - 1))
            lines[k:k + 1] = [lines[k]] * 2 if kind == 'repeat' else []
            text = ''.join(lines)
            continue
        at = data.draw(st.integers(0, len(text)))
        piece = data.draw(st.sampled_from(['-', '0', '9', ':', ' ', '\n', '[', ']', '{', '}',
                                           ',', '*', '&a ', '.nan', '1e999', 'é', '\t', '"']))
        if kind == 'insert':
            text = text[:at] + piece + text[at:]
        elif kind == 'delete':
            text = text[:at] + text[at + len(piece):]
        else:
            text = text[:at] + piece + text[at + 1:]
    try:
        experiment = build_experiment(parse_experiment_text(text, 'mutated.yaml'),
                                      'mutated.yaml')
    except ConfigError as exc:
        line = str(exc)
        assert line.startswith('mutated.yaml') and '\n' not in line.strip()
        assert len(line) < 500
        return
    sim = experiment.spec.simulation
    result = simulate(experiment, duration=max(sim.record_dt, sim.dt) * 3)
    assert np.isfinite(result.poses[0]).all()
    assert math.isfinite(result.t[-1])


@pytest.mark.parametrize('argv', [['sim', 'closed_curve', '--rate', '0', '--out', 'x'],
                                  ['run', 'closed_curve', '--duration', '-5'],
                                  ['sim', 'closed_curve', '--rate', 'nan', '--out', 'x'],
                                  ['replay', 'bag', '--start', '-1'], ['bogus'], ['bag']])
def test_command_line_misuse_is_one_error_line(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith('error: curve-formation'), err
