"""The bag of a run stopped from outside: closed and valid after Ctrl-C or SIGTERM, and at
most the last second lost after SIGKILL.
"""

import json
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from conftest import DATA_DIR
from curve_formation.bags.bag import bag_summary, BagError, read_messages


def start_run(tmp_path, ros_env, sigint_ignored=False, storage='mcap'):
    """`curve-formation run` with a bag, returned once its t = 0; with `sigint_ignored` as
    from a background job of a non-interactive shell (SIGINT inherited ignored).
    """
    proc = subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.cli', 'run', str(DATA_DIR / 'fast_closed.yaml'),
         '--out', str(tmp_path / 'run'), '--duration', '120', '--bag', str(tmp_path / 'bag'),
         '--bag-storage', storage],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env,
        preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if sigint_ignored
        else None)
    deadline = time.monotonic() + 120
    for line in proc.stdout:
        if 't = 0' in line:
            return proc
        assert time.monotonic() < deadline, 'the run did not start'
    raise AssertionError(f'the run ended early: {proc.wait()}')


def wait_for_status(proc, timeout=60.0):
    """Read the run's output until its first status line (`t ... s  phase ...`)."""
    deadline = time.monotonic() + timeout
    for line in proc.stdout:
        if line.lstrip().startswith('t ') and ' phase ' in line:
            return
        assert time.monotonic() < deadline, 'no status line from the run'
    raise AssertionError(f'the run ended early: {proc.wait()}')


@pytest.mark.parametrize('sig', [signal.SIGINT, pytest.param(
    signal.SIGTERM, marks=pytest.mark.slow)])   # 16 s each: the default run stays under 10 min
def test_interrupted_run_leaves_a_closed_valid_bag(tmp_path, ros_env, sig):
    """SIGTERM comes as to a background job of a non-interactive shell (SIGINT inherited
    ignored): the run must still stop every node promptly, each sending its zero command.
    """
    proc = start_run(tmp_path, ros_env, sigint_ignored=sig == signal.SIGTERM)
    wait_for_status(proc)   # the run records: its first 5 s status line
    proc.send_signal(sig)
    signalled = time.time()
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    # Every node (curve server, 6 controllers, 6 fake robots) took the runner's SIGINT and
    # ended through its own shutdown, which writes its publication counts, within its group's
    # 10 s timeout (after which it would have been killed, writing nothing).
    counts = list((tmp_path / 'run' / 'publications').glob('*.json'))
    assert len(counts) == 13, counts
    assert max(path.stat().st_mtime for path in counts) - signalled < 10.0
    for log in (tmp_path / 'run' / 'logs').glob('*.log'):   # every node process's
        assert 'Traceback' not in log.read_text(), log.name
    summary = bag_summary(tmp_path / 'bag')
    for i in range(1, 7):
        msgtype, count = summary[f'/robot_{i}/cmd_vel']
        assert msgtype == 'geometry_msgs/msg/Twist' and count >= 40   # >= 4 s at 10 Hz
        assert summary[f'/robot_{i}/pose'][1] >= 100                  # >= 4 s at 30 Hz
    last = {}
    for topic, _, _, msg in read_messages(tmp_path / 'bag', [f'/robot_{i}/cmd_vel'
                                                            for i in range(1, 7)]):
        last[topic] = (msg.linear.x, msg.angular.z)
    # A complete, indexed MCAP file, as Jazzy's reader needs it.
    assert _complete_mcap_messages(tmp_path / 'bag' / 'bag.mcap', summary=True)[0] == sum(
        count for _, count in summary.values())
    # Each controller's final command, sent as it was stopped, is zero and was recorded.
    assert all(v == (0.0, 0.0) for v in last.values()), last
    # Every message the nodes published on a reliable topic (while subscribed) is in the bag;
    # of the best-effort poses DDS may drop a few under load.
    accounting = json.loads((tmp_path / 'run' / 'metrics.json').read_text())['bag']
    assert accounting['published'] > 1000 and accounting['lost'] == 0, accounting
    assert accounting['lost_best_effort'] < 0.005 * accounting['published'], accounting


@pytest.mark.parametrize('storage', ['mcap', pytest.param('sqlite3', marks=pytest.mark.slow)])
def test_hard_killed_run_loses_at_most_the_last_second(tmp_path, ros_env, storage):
    """Killed hard, the bag holds all but the last second, and `bag repair` makes a complete
    bag of it that our reader (and, for MCAP, the independent mcap reader) reads whole.
    """
    proc = start_run(tmp_path, ros_env, storage=storage)
    bag = tmp_path / 'bag'
    deadline = time.monotonic() + 60
    while _stored_messages(bag, storage)[0] <= 1000:   # a few seconds of the run on disk
        assert time.monotonic() < deadline and proc.poll() is None, 'the bag did not fill'
        time.sleep(0.2)
    killed_at = time.time()
    proc.kill()
    proc.wait(10)
    assert not (bag / 'metadata.yaml').exists()   # never closed
    count, newest = _stored_messages(bag, storage)
    assert count > 1000
    assert killed_at - newest * 1e-9 < 1.5   # commit period 1 s, plus scheduling slack
    with pytest.raises(BagError, match='bag repair'):
        list(read_messages(bag))
    repaired = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'bag', 'repair',
                               str(bag)], capture_output=True, text=True)
    assert repaired.returncode == 0, repaired.stderr
    assert f'{count} messages' in repaired.stdout
    stamps = [stamp for _, _, stamp, _ in read_messages(tmp_path / 'bag-repaired')]
    assert len(stamps) == count and max(stamps) == newest
    if storage == 'mcap':
        assert _complete_mcap_messages(tmp_path / 'bag-repaired' / 'bag-repaired.mcap',
                                       summary=True) == (count, newest)
    # The node processes do not outlive a killed runner.
    deadline = time.monotonic() + 20
    while subprocess.run(['pgrep', '-f', str(tmp_path / 'run' / 'params')],
                         capture_output=True).returncode == 0:
        assert time.monotonic() < deadline, 'node processes outlived the killed runner'
        time.sleep(0.2)


def _stored_messages(bag, storage):
    """(count, newest timestamp in ns) of the messages a bag being written holds on disk."""
    if storage == 'mcap':
        path = bag / 'bag.mcap'
        return _complete_mcap_messages(path) if path.exists() else (0, 0)
    try:
        with sqlite3.connect(f'file:{bag / "bag.db3"}?mode=ro', uri=True) as conn:
            count, newest = conn.execute(
                'SELECT COUNT(*), MAX(timestamp) FROM messages').fetchone()
    except sqlite3.OperationalError:   # not created yet, or locked by the writer
        return 0, 0
    return count, newest or 0


def _complete_mcap_messages(path, summary=False):
    """(count, newest log time in ns) of an MCAP file's messages, read with the independent
    `mcap` library: record by record up to a killed writer's unfinished tail, or (summary)
    through the file's summary and indexes, as Jazzy's reader does.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader
    count, newest = 0, 0
    with open(path, 'rb') as stream:
        if summary:
            for _, _, message in make_reader(stream).iter_messages():
                count, newest = count + 1, max(newest, message.log_time)
            return count, newest
        try:
            for record in StreamReader(stream).records:
                if type(record).__name__ == 'Message':
                    count, newest = count + 1, max(newest, record.log_time)
        except (McapError, EOFError, ValueError):
            pass   # the chunk being written when the process was killed
    return count, newest
