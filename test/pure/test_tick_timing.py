"""A run says whether its controllers kept their rate (core.record.tick_timing)."""

import numpy as np
import pytest

from curve_formation.core.record.tick_timing import run_timing, tick_timing
from curve_formation.results.report import verdicts


def test_a_steady_controller_keeps_its_rate_and_a_missed_tick_is_counted():
    sent = np.arange(101) * 0.1 + 5.0
    timing = tick_timing(sent, sent + 0.002, 10.0)
    assert timing['rate_hz'] == pytest.approx(10.0) and timing['missed_ticks'] == 0
    assert timing['jitter_ms_p99'] == pytest.approx(0.0, abs=1e-6)
    assert timing['command_age_ms_p50'] == pytest.approx(2.0)
    gappy = np.delete(sent, [30, 60, 61])   # one tick missed, then two in a row
    timing = tick_timing(gappy, gappy, 10.0)
    assert timing['missed_ticks'] == 3 and timing['ticks'] == 98
    assert timing['rate_hz'] == pytest.approx(97 / 10.0)
    late = sent.copy()
    late[50] += 0.04   # one tick 40 ms late: two periods off by 40 ms
    assert tick_timing(late, late, 10.0)['jitter_ms_p99'] == pytest.approx(40.0, rel=0.05)
    assert tick_timing(sent[:1], sent[:1], 10.0) is None


def test_a_run_names_its_slowest_controller_and_those_below_95_percent():
    fast = np.arange(100) * 0.1
    slow = np.arange(90) * (1 / 9.0)
    result = run_timing({1: (fast, fast), 2: (slow, slow), 3: ([], [])}, 10.0)
    assert sorted(result['robots']) == ['robot_1', 'robot_2']
    assert result['slowest'] == {'robot': 2, 'rate_hz': pytest.approx(9.0)}
    assert result['below_rate'] == [2]
    said = [text for good, text in verdicts({'ticks': result}) if not good]
    assert said == ['The controllers of robots 2 fell below 95 % of 10 Hz; slowest robot 2 '
                    'at 9 Hz, period jitter p99 up to 11.11 ms.']
    kept = run_timing({1: (fast, fast)}, 10.0)
    assert kept['below_rate'] == [] and verdicts({'ticks': kept})[0][0]
