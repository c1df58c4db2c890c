"""How a run scales with the team: N simulated robots (one kinematic fake arena, bodies and
the safety filter on, a generated closed curve) in the default mode (controllers in one group
per core) and in one process.

Run: scripts/bench scale [--sizes 9 25 50 100] [--seconds 30] [--modes grouped single]
     [--realtime-priority P] [--busy-neighbour]

--busy-neighbour measures beside a busy neighbour, as the issue's goals are stated and as the
default test run has its tests without DDS: a Python loop at nice 19, started from this
process (so in its session) for the whole of each run.

For each N and mode it prints: achieved control rate (Hz) of the slowest controller and the
1st percentile over the robots, period jitter p99 (ms, worst robot), CPU per robot (% of one
core: every node process, or the one process, over the measured window), DDS participants
(node processes and the runner), the time from the start to the first curve (discovery and
start-up, s) and whether the formation settled within the run. The rates and jitters are the
run's own metrics.json `ticks` (core/record/tick_timing.py).
"""

import argparse
import contextlib
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from node_graph import cpu_seconds, experiment_file, quiet_stderr
import numpy as np

from curve_formation import scheduling
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


MODES = {'grouped': {}, 'single': {'single_process': True}}


def measure(n, mode, seconds, folder, priority=scheduling.CONTROLLERS):
    """One run of n robots in `mode` (its controllers at SCHED_FIFO `priority`, 0: normal
    scheduling): the row this benchmark prints.
    """
    path = experiment_file(n, folder, avoidance=True)
    began = time.monotonic()
    with quiet_stderr(Path(folder) / f'nodes_{n}_{mode}.log'), \
            Run(path, Path(folder) / f'run_{n}_{mode}', RunOptions(
                isolated=True, realtime_priority=priority, **MODES[mode]),
                log=lambda *_: None) as run:
        to_first_curve = time.monotonic() - began
        pids = [p.pid for p in run.processes.values()] + [os.getpid()]
        participants = len(run.processes) + 1
        cpu0, wall0 = cpu_seconds(pids), time.monotonic()
        run.spin_for(seconds)
        cpu = (cpu_seconds(pids) - cpu0) / (time.monotonic() - wall0)
        _, _, result = run.measure()
    rates = [t['rate_hz'] for t in result['ticks']['robots'].values() if t['rate_hz']]
    return {'n': n, 'mode': mode, 'rate_min': min(rates, default=0.0),
            'rate_p1': float(np.percentile(rates, 1)) if rates else 0.0,
            'jitter_p99': result['ticks']['jitter_ms_p99_worst'],
            'cpu_per_robot': 100 * cpu / n, 'participants': participants,
            'first_curve_s': to_first_curve, 'settled': bool(result.get('all_settled'))}


@contextlib.contextmanager
def busy_neighbour(on):
    """A nice-19 Python loop beside the block (when `on`): one core's worth of work that only
    takes what the run leaves, at normal scheduling.
    """
    if not on:
        yield
        return
    loop = subprocess.Popen(['nice', '-n', '19', sys.executable, '-c',
                             'while True: sum(i * i for i in range(10000))'])
    try:
        yield
    finally:
        loop.kill()
        loop.wait()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sizes', type=int, nargs='+', default=[9, 25, 50, 100])
    parser.add_argument('--seconds', type=float, default=30.0)
    parser.add_argument('--modes', nargs='+', default=list(MODES), choices=list(MODES))
    parser.add_argument('--realtime-priority', type=int, default=scheduling.CONTROLLERS,
                        help="the controllers' SCHED_FIFO priority (run --realtime-priority; "
                        '0: normal scheduling)')
    parser.add_argument('--busy-neighbour', action='store_true',
                        help='measure beside a nice-19 Python loop (as the goals are stated)')
    args = parser.parse_args()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    print(f'{"N":>4s} {"mode":>8s} {"Hz min":>7s} {"Hz p1":>6s} {"jitter p99 ms":>13s} '
          f'{"CPU/robot":>9s} {"participants":>12s} {"first curve s":>13s}  settled')
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            for mode in args.modes:
                try:
                    with busy_neighbour(args.busy_neighbour):
                        r = measure(n, mode, args.seconds, folder, args.realtime_priority)
                except (TimeoutError, RuntimeError) as exc:
                    print(f'{n:4d} {mode:>8s} failed: {str(exc).splitlines()[0]}', flush=True)
                    continue
                print(f'{r["n"]:4d} {r["mode"]:>8s} {r["rate_min"]:7.2f} {r["rate_p1"]:6.2f} '
                      f'{r["jitter_p99"]:13.1f} {r["cpu_per_robot"]:8.1f}% '
                      f'{r["participants"]:12d} {r["first_curve_s"]:13.1f}  '
                      f'{"yes" if r["settled"] else "no"}', flush=True)


if __name__ == '__main__':
    main()
