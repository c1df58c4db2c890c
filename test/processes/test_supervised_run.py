"""A run survives the death of any node it started, says which died, and keeps its record."""

import json
import os
import select
import signal
import subprocess
import sys
import time

import pytest

from conftest import DATA_DIR
from curve_formation.bags.analysis import analyze_bag
from curve_formation.dds_shm import files_in_use, orphan_ports, PORT_FILE
from curve_formation.run.run_options import RunOptions


def read_until(proc, text, timeout):
    """stdout lines of proc until one contains `text` (AssertionError after timeout s)."""
    lines, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline()
            lines.append(line)
            if text in line:
                return lines
        assert proc.poll() is None, ''.join(lines) + proc.stderr.read()
    raise AssertionError(f'no {text!r} in {lines}')


def node_pid(out_dir, key):
    """The pid of the run's node process `key` (its parameters file is in out_dir/params)."""
    found = subprocess.run(['pgrep', '-f', f'{out_dir}/params/{key}'], capture_output=True,
                           text=True).stdout.split()
    assert len(found) == 1, found
    return int(found[0])


def test_a_controller_killed_hard_leaves_metrics_a_bag_and_an_exit_status_naming_it(
        ros_domain, tmp_path):
    out = tmp_path / 'run'
    bag = tmp_path / 'bag'
    before = set(os.listdir('/dev/shm'))
    proc = subprocess.Popen([sys.executable, '-m', 'curve_formation.cli', 'run',
                             str(DATA_DIR / 'fast_closed.yaml'), '--out', str(out),
                             '--duration', '8', '--bag', str(bag),
                             '--controllers-per-process', '1'],   # robot_3's own process
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED='1'))
    try:
        read_until(proc, 't = 0', 90.0)
        time.sleep(2.0)
        os.kill(node_pid(out, 'robot_3.formation_controller'), signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 3, (stdout, stderr)
    assert 'robot_3.formation_controller (killed by SIGKILL)' in stderr, stderr
    assert 'died at t = ' in stdout, stdout
    result = json.loads((out / 'metrics.json').read_text())
    (death,) = result['node_deaths']
    assert death['node'] == 'robot_3.formation_controller' and 1.5 < death['t'] < 4.0, death
    assert not result['all_settled']
    assert result['phases'][0]['not_settled_because'].startswith(
        'node robot_3.formation_controller died at t = ')
    assert (out / 'paths.png').exists() and result['bag']['messages'] > 1000
    assert 'phase 0  error ' in stdout and ' at their targets' in stdout   # status every 5 s
    assert result['provenance']['experiment_file'] == str(DATA_DIR / 'fast_closed.yaml')
    # Under LOCALHOST discovery every participant has Fast DDS shared memory: the run removed
    # what its dead node left there (a file no live process holds; a port's semaphore is not
    # held between uses, so one of a live port, a test's beside this one, is left out).
    left = (set(os.listdir('/dev/shm')) - before) - files_in_use()
    orphans = set(orphan_ports())
    assert not [name for name in left if 'fastrtps' in name
                and (not PORT_FILE.match(name) or name in orphans)], left
    # The bag says the same.
    bagged = analyze_bag(bag, tmp_path / 'analysis')
    assert [d['node'] for d in bagged['node_deaths']] == ['robot_3.formation_controller']
    assert {k: bagged['run_provenance'][k] for k in ('command', 'experiment_sha256')} == {
        k: result['provenance'][k] for k in ('command', 'experiment_sha256')}
    assert abs(bagged['node_deaths'][0]['t'] - death['t']) < 0.2
    assert not bagged['all_settled']


def test_an_unexpected_error_in_the_runner_still_writes_what_was_measured(ros_domain, tmp_path,
                                                                        monkeypatch):
    from curve_formation.run.run_experiment import run_experiment
    from curve_formation.run.runner import Run
    spin_for = Run.spin_for

    def fails_later(run, seconds, status_every=None):
        spin_for(run, 3.0)
        raise RuntimeError('a fault of the runner')
    monkeypatch.setattr(Run, 'spin_for', fails_later)
    with pytest.raises(RuntimeError, match='a fault of the runner'):
        run_experiment(DATA_DIR / 'fast_closed.yaml', tmp_path, 10.0,
                       RunOptions(single_process=True), log=lambda *_: None)
    result = json.loads((tmp_path / 'metrics.json').read_text())
    assert result['runner_error'] == 'RuntimeError: a fault of the runner'
    assert 2.5 < result['duration'] < 8.0 and (tmp_path / 'paths.png').exists()
