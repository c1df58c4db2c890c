"""The node graph with its controllers spread over hosts (network namespaces on a bridge).

Run: scripts/bench split_hosts [--sizes 9 16 25] [--hosts 2 4] [--seconds 15]   (root)

Host 1 runs the curve server, the N fake robots and the observer; the N controllers are
spread evenly over the other hosts (`run --only controllers --agents ...`), so every pose
and every command crosses the bridge (UDP). Printed per N and number of controller hosts:
cmd_vel rate per robot (mean, min; Hz) and pose-to-command latency (a robot's pose stamp to
the arrival of its controller's estimate on host 1: both crossings of the link; p50, p99 ms).
The one-host figures are `scripts/bench node_graph`'s. All hosts share this machine's two
cores: a spread graph needs the same CPU as one host's, so what it shows is what the network
path adds. Goal (issue): the largest N that holds 10 Hz (every robot >= 9.9 Hz).
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from node_graph import experiment_file
import numpy as np


sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test'))
from netns_hosts import available, Hosts, stop_groups  # noqa: E402 (test support)


CLI = str(Path(sys.executable).parent / 'curve-formation')


def inner(n, seconds, folder):
    """On host 1: curve server, robots and observer; prints the measurement as JSON."""
    from curve_formation.run.run_options import RunOptions
    from curve_formation.run.runner import Run
    options = RunOptions(only=frozenset({'curve_server', 'robots', 'observer'}))
    with Run(experiment_file(n, folder), Path(folder) / f'observer_{n}', options,
             log=lambda *_: None) as run:
        run.spin_for(2.0)
        monitor = run.monitor
        for lst in monitor.command_arrivals + monitor.tick_latencies:
            lst.clear()
        start = monitor.get_clock().now().nanoseconds * 1e-9
        run.spin_for(seconds)
        elapsed = monitor.get_clock().now().nanoseconds * 1e-9 - start
        rates = [len(a) / elapsed for a in monitor.command_arrivals]
        latencies = np.concatenate([np.array(v) for v in monitor.tick_latencies])
    print(json.dumps({'rate_mean': float(np.mean(rates)), 'rate_min': float(np.min(rates)),
                      'latency_p50_ms': 1e3 * float(np.percentile(latencies, 50)),
                      'latency_p99_ms': 1e3 * float(np.percentile(latencies, 99))}))


def measure(n, controller_hosts, seconds, folder):
    domain = str(60 + n % 40)
    env = dict(os.environ, ROS_DOMAIN_ID=domain, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
               PYTHONUNBUFFERED='1')
    experiment_file(n, folder)
    shares = np.array_split(np.arange(1, n + 1), controller_hosts)
    with Hosts(controller_hosts + 1, net=233) as hosts:
        controllers = [subprocess.Popen(
            hosts.prefix(k + 2) + [CLI, 'run', str(Path(folder) / f'bench_{n}.yaml'),
                                   '--only', 'controllers', '--agents',
                                   f'{share[0]}-{share[-1]}', '--duration', str(seconds + 30),
                                   '--out', str(Path(folder) / f'controllers_{n}_{k}')],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True) for k, share in enumerate(shares)]
        try:
            out = subprocess.run(hosts.prefix(1) + [sys.executable, __file__, '--inner', str(n),
                                                    '--seconds', str(seconds), '--folder',
                                                    str(folder)],
                                 env=env, capture_output=True, text=True, timeout=300)
        finally:
            stop_groups(controllers)
    lines = [line for line in out.stdout.splitlines() if line.startswith('{')]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f'N = {n}, {controller_hosts} hosts: {out.stderr[-2000:]}')
    return json.loads(lines[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sizes', type=int, nargs='+', default=[9, 16, 25])
    parser.add_argument('--hosts', type=int, nargs='+', default=[2, 4])
    parser.add_argument('--seconds', type=float, default=15.0)
    parser.add_argument('--inner', type=int, help=argparse.SUPPRESS)
    parser.add_argument('--folder', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        inner(args.inner, args.seconds, args.folder)
        return
    why = available()
    if why:
        raise SystemExit(f'split_hosts: {why}')
    print(f'{"N":>4s} {"controller hosts":>16s} {"rate mean Hz":>12s} {"rate min Hz":>11s} '
          f'{"latency p50 ms":>14s} {"p99 ms":>7s} {"holds 10 Hz":>11s}')
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            for count in args.hosts:
                r = measure(n, count, args.seconds, folder)
                print(f'{n:4d} {count:16d} {r["rate_mean"]:12.2f} {r["rate_min"]:11.2f} '
                      f'{r["latency_p50_ms"]:14.1f} {r["latency_p99_ms"]:7.1f} '
                      f'{"yes" if r["rate_min"] >= 9.9 else "no":>11s}', flush=True)
                time.sleep(1.0)


if __name__ == '__main__':
    main()
