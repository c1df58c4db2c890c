"""ROS node graph timing: N fake robots + N controllers, one process each, controllers
grouped into few processes (run's default: one group per core) or all in one.

Run: scripts/bench node_graph [--sizes 9 16 25 50] [--seconds 15]
                              [--modes multi grouped single] [--avoidance]

For each N and mode it prints: cmd_vel rate per robot (Hz, mean over robots), period jitter
|interval - 100 ms| (p50/p99 over all robots) of the commands as published (DDS source
timestamps: when each controller's timer fired), as received by DDS in another process (what
a robot driver sees) and as handled by the monitor's Python callback (adds the monitor's own
scheduling), pose-to-command latency (arrival of a tick's output minus the stamp of the pose it
used, p50/p99) and CPU per robot (% of one core, all node processes, or the single process,
divided by N) and the late ticks (commands more than 150 ms apart, all robots). A robot's
rate is from its commands' source timestamps (its timer). Goal (issue): 9 robots at 10 Hz with
p99 jitter under 5 ms; the largest N that holds 10 Hz (every robot at least 9.9 Hz over the
window). In single-process mode the nodes'
log lines go to a file, not the terminal. --avoidance gives the robots bodies (0.2 m), wheels
of 2 m/s and the safety filter: every controller then takes every robot's pose, 30 times a
second, and filters every command, and one fake_arena simulates all the bodies.
"""

import argparse
import contextlib
import os
from pathlib import Path
import sys
import tempfile

import numpy as np
import yaml

from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


def experiment_file(n, folder, avoidance=False):
    """n agents on a closed curve at 10 Hz, chain + skip edges, converging settings; with
    avoidance, bodies of 0.2 m kept 0.1 m apart. Past 50 agents the curve and the starts grow
    with n, so that the targets stay about 1 m apart.
    """
    grow = max(1.0, n / 50)
    edges = [{'from': i, 'to': i + 1} for i in range(1, n)]
    edges += [{'from': i, 'to': i + 2} for i in range(1, n - 1, 3)]
    path = Path(folder) / f'bench_{n}.yaml'
    bodies = {'robots': {'radius': 0.2}, 'avoidance': {'margin': 0.1}} if avoidance else {}
    # With bodies, targets spaced by arc length and an offset of 0.2 m leave them room
    # whichever way the robots face at the end (`check` warns of none; with the curve's own s
    # and 0.3 m, two robots could arrive where the safety filter holds them off their targets)
    spacing = {'spacing': 'arc_length'} if avoidance else {}
    # With avoidance, wheels of 2 m/s (not 100): a robot's barriers then reach the robots
    # within 4 v_max / alpha = 1.6 m, not all of them.
    speed = 2.0 if avoidance else 100.0
    path.write_text(yaml.safe_dump({
        'name': f'bench_{n}', **bodies,
        'agents': {'count': n, **spacing, 'initial': {'random': {'seed': 1, 'center': [0, 0],
                                                      'half_width': [10 * grow] * 2,
                                                      'min_separation': 0.6}}},
        'graph': {'edges': edges},
        'controller': {'k1': 1.0, 'k2': 0.0, 'offset': 0.2 if avoidance else 0.3,
                       'rate_hz': 10.0},
        'limits': {'wheel_base': 0.1, 'max_wheel_speed': speed, 'max_angular_rate': 10.0},
        'curves': [{'basis': 'fourier', 'harmonics': max(2, n // 2),
                    'samples': max(400, 3 * n + 3),
                    'x': f'{grow:g} * (8 + sin(6*pi*s)) * cos(2*pi*s)',
                    'y': f'{grow:g} * (8 + cos(4*pi*s)) * sin(2*pi*s)'}],
        'simulation': {'duration': 60.0},
        # News of the leader crosses up to ~n / 1.3 hops, one pose period (33 ms) each: the
        # default 1 s would stop the far followers of a 50-robot chain now and then.
        'safety': {'leader_timeout': max(1.0, 0.05 * n)},
    }))
    return path


def cpu_seconds(pids):
    """User + system CPU seconds of the given processes (Linux /proc)."""
    tick = os.sysconf('SC_CLK_TCK')
    total = 0.0
    for pid in pids:
        try:
            fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
        except (FileNotFoundError, ProcessLookupError):
            pass
    return total


MODES = {'multi': {'controllers_per_process': 1}, 'grouped': {},
         'single': {'single_process': True}}


def measure(n, mode, seconds, folder, avoidance=False):
    path = experiment_file(n, folder, avoidance)
    out = Path(folder) / f'run_{n}_{mode}'
    with quiet_stderr(Path(folder) / f'nodes_{n}.log'), \
            Run(path, out, RunOptions(isolated=True, **MODES[mode]),
                log=lambda *_: None) as run:
        run.spin_for(2.0)   # let every controller start driving
        monitor = run.monitor
        for lst in monitor.command_arrivals + monitor.tick_latencies:
            lst.clear()
        pids = [p.pid for p in run.processes.values()] or [os.getpid()]
        processes = len(run.processes) + 1   # and the runner's
        cpu0, wall0 = cpu_seconds(pids), monitor.get_clock().now().nanoseconds * 1e-9
        run.spin_for(seconds)
        cpu1, wall1 = cpu_seconds(pids), monitor.get_clock().now().nanoseconds * 1e-9
        arrivals = [np.array(a).reshape(-1, 3) for a in monitor.command_arrivals]
        latencies = np.concatenate([np.array(v) for v in monitor.tick_latencies])
    elapsed = wall1 - wall0
    # Each controller's rate from its commands' DDS source timestamps (when its timer fired):
    # counting those handled in the window would also count the monitor's backlog at its ends.
    rates = [(len(a) - 1) / (a[-1, 0] - a[0, 0]) for a in arrivals]
    late = sum(int(np.sum(np.diff(a[:, 0]) > 0.15)) for a in arrivals)
    result = {'n': n, 'mode': mode, 'processes': processes,
              'rate_mean': float(np.mean(rates)), 'rate_min': float(np.min(rates)),
              'late_ticks': late}
    for column, name in enumerate(('published', 'received', 'handled')):
        jitter = np.concatenate([np.abs(np.diff(a[:, column]) - 0.1)
                                 for a in arrivals if len(a) > 1])
        result[f'{name}_p50_ms'] = 1e3 * float(np.percentile(jitter, 50))
        result[f'{name}_p99_ms'] = 1e3 * float(np.percentile(jitter, 99))
    return {**result, 'latency_p50_ms': 1e3 * float(np.percentile(latencies, 50)),
            'latency_p99_ms': 1e3 * float(np.percentile(latencies, 99)),
            'cpu_per_robot_pct': 100 * (cpu1 - cpu0) / elapsed / n}


@contextlib.contextmanager
def quiet_stderr(path):
    """Send this process's stderr (in-process nodes' log lines) to a file for a while."""
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, 'w') as log:
        os.dup2(log.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sizes', type=int, nargs='+', default=[9, 16, 25, 50])
    parser.add_argument('--seconds', type=float, default=15.0)
    parser.add_argument('--modes', nargs='+', default=list(MODES), choices=list(MODES))
    parser.add_argument('--avoidance', action='store_true',
                        help='bodies and the safety filter in every controller')
    args = parser.parse_args()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    print('jitter |interval - 100 ms| p50/p99 in ms as published, received and handled; '
          'pose-to-command latency p50/p99 in ms; CPU in % of one core')
    print(f'{"N":>4s} {"mode":>7s} {"procs":>5s} {"Hz mean":>8s} {"Hz min":>7s} '
          f'{"published":>12s} {"received":>12s} {"handled":>12s} {"latency":>12s} '
          f'{"CPU/robot":>9s} {"late":>7s}')
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            for mode in args.modes:
                try:
                    r = measure(n, mode, args.seconds, folder, args.avoidance)
                except (TimeoutError, RuntimeError) as exc:
                    print(f'{n:4d} {mode:>7s} failed: {str(exc).splitlines()[0]}', flush=True)
                    continue
                holds = 'holds 10 Hz' if r['rate_min'] >= 9.9 else 'below 10 Hz'
                cells = ' '.join(f'{r[name + "_p50_ms"]:5.1f}/{r[name + "_p99_ms"]:<6.1f}'
                                 for name in ('published', 'received', 'handled', 'latency'))
                print(f'{r["n"]:4d} {r["mode"]:>7s} {r["processes"]:5d} {r["rate_mean"]:8.2f} '
                      f'{r["rate_min"]:7.2f} {cells} {r["cpu_per_robot_pct"]:8.1f}% '
                      f'{r["late_ticks"]:7d}   {holds}',
                      flush=True)


if __name__ == '__main__':
    main()
