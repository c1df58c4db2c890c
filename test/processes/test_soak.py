"""A run of half an hour keeps its memory flat (benchmarks/soak.py; behind -m slow: ~32 min)."""

import importlib.util

import pytest

from conftest import ROOT


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_a_30_minute_recorded_run_keeps_every_process_within_20_mb():
    spec = importlib.util.spec_from_file_location('soak', ROOT / 'benchmarks' / 'soak.py')
    soak = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(soak)
    status, growth, out = soak.measure(30.0, every=60.0, bag=True)
    assert status == 0, (out / 'run.log').read_text()[-3000:]
    assert 'runner' in growth and len(growth) >= 11, growth   # the runner and every node
    assert all(abs(mb) <= soak.GOAL_MB for mb in growth.values()), growth
