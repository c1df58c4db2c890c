"""A long run: memory (RSS) of the runner and of every node process over time.

Run: scripts/bench soak [--minutes 30] [--experiment arena_demo] [--every 60] [--bag]

Starts `curve-formation run EXPERIMENT --isolated --duration MINUTES*60` as a user would (a
new process, one process per node, a private domain) and reads /proc every `every` s: the RSS
(MB) of the runner and of each node process it started. Printed: one row per reading, then
per process its RSS after the first `--warm-up` s and at the end and the difference. Goal
(issue #38): the runner flat within 20 MB over 30 minutes; the nodes flat too. With --bag the
run records its bag (about 440 MB an hour), as `scripts/demo` does.
test/processes/test_soak.py runs it behind -m slow.
"""

import argparse
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time


PAGE = os.sysconf('SC_PAGE_SIZE')
GOAL_MB = 20.0


def process_tree(root):
    """{pid: label} of root and its descendants (label: the node's namespace and name)."""
    parents = {}
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / 'stat').read_text()
            except OSError:
                continue
            parents[int(entry.name)] = int(stat.rsplit(')', 1)[1].split()[1])
    tree, frontier = {root}, [root]
    while frontier:
        pid = frontier.pop()
        children = [p for p, parent in parents.items() if parent == pid and p not in tree]
        tree.update(children)
        frontier.extend(children)
    return {pid: label(pid, root) for pid in tree}


def label(pid, root):
    if pid == root:
        return 'runner'   # the monitor and the recorder, and the results at the end
    try:
        argv = (Path('/proc') / str(pid) / 'cmdline').read_bytes().split(b'\0')
    except OSError:
        return str(pid)
    words = [a.decode(errors='replace') for a in argv if a]
    if '-m' in words[:-1]:   # python -m curve_formation.nodes.<node>
        name = words[words.index('-m') + 1].rsplit('.', 1)[-1]
    else:
        name = Path(words[0]).name if words else str(pid)
    namespace = next((w.split(':=', 1)[1] for w in words if w.startswith('__ns:=')), '')
    return f'{namespace}/{name}'.strip('/') + f' ({pid})'


def rss_mb(pid):
    try:
        pages = int((Path('/proc') / str(pid) / 'statm').read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return None
    return pages * PAGE / 2 ** 20


def measure(minutes, experiment='arena_demo', every=60.0, warm_up=60.0, bag=False,
            log=print):
    """Run the experiment `minutes` long as `curve-formation run --isolated` and read every
    process's RSS every `every` s. Returns (exit status, {process: growth MB from the first
    reading after warm_up s to the last}, output folder).
    """
    out = Path(tempfile.mkdtemp(prefix='soak-'))
    command = [sys.executable, '-m', 'curve_formation.cli', 'run', experiment, '--isolated',
               '--duration', f'{minutes * 60:g}', '--out', str(out / 'run'),
               '--controllers-per-process', '1']   # every node's memory on its own
    if bag:
        command += ['--bag', str(out / 'bag')]
    log(f'{" ".join(command[2:])}  (outputs in {out})')
    with open(out / 'run.log', 'w') as run_log:
        runner = subprocess.Popen(command, stdout=run_log, stderr=subprocess.STDOUT)
        start = time.monotonic()
        readings = {}    # label -> [(t s, RSS MB)]
        try:
            while runner.poll() is None:
                t = time.monotonic() - start
                row = {}
                for pid, name in process_tree(runner.pid).items():
                    mb = rss_mb(pid)
                    if mb is not None:
                        readings.setdefault(name, []).append((t, mb))
                        row[name] = mb
                nodes = sum(mb for name, mb in row.items() if name != 'runner')
                log(f't {t / 60:6.1f} min  runner {row.get("runner", float("nan")):7.1f} MB  '
                    f'{len(row) - 1} node processes {nodes:8.1f} MB')
                deadline = time.monotonic() + every
                while runner.poll() is None and time.monotonic() < deadline:
                    time.sleep(0.5)
        finally:
            if runner.poll() is None:
                runner.terminate()
            runner.wait()
    log(f'run exited {runner.returncode}; log {out / "run.log"}')
    log(f'\n{"process":40s} {"after warm-up":>14s} {"end":>8s} {"growth":>8s}  MB')
    growth = {}
    for name, series in sorted(readings.items()):
        warm = [mb for t, mb in series if t >= warm_up]
        if len(warm) >= 2:
            growth[name] = warm[-1] - warm[0]
            log(f'{name:40s} {warm[0]:14.1f} {warm[-1]:8.1f} {growth[name]:+8.1f}')
    return runner.returncode, growth, out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--minutes', type=float, default=30.0)
    parser.add_argument('--experiment', default='arena_demo')
    parser.add_argument('--every', type=float, default=60.0, help='seconds between readings')
    parser.add_argument('--warm-up', type=float, default=60.0,
                        help='seconds after the start from which growth is measured')
    parser.add_argument('--bag', action='store_true', help="record the run's bag as well")
    args = parser.parse_args()
    status, growth, _ = measure(args.minutes, args.experiment, args.every, args.warm_up,
                                args.bag, log=lambda line: print(line, flush=True))
    runner = growth.get('runner')
    nodes = max((g for name, g in growth.items() if name != 'runner'), default=0.0)
    if runner is not None:
        print(f'\nrunner growth {runner:+.1f} MB over {args.minutes:g} min (goal: within '
              f'{GOAL_MB:g} MB over 30 min: {"met" if abs(runner) <= GOAL_MB else "NOT met"}); '
              f'largest node growth {nodes:+.1f} MB')
    return status


if __name__ == '__main__':
    sys.exit(main())
