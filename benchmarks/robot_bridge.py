"""The real path to a robot: an experiment run with fake robots, then through a robot_bridge per
robot to fake_arena's emulated firmware over UDP and over pseudo-terminals (serial lines).

Run: scripts/bench robot_bridge [--experiment arena_demo] [--duration 60] [--links fake udp pty]

For each way of reaching the robots it prints the settling time of every phase and its ratio to
the fake robots' (cmd_vel straight into the simulated world), the final error, and per bridge
the lines sent and answered and the bridge latency, from a cmd_vel received to its bytes
written (p50/p99 over the run's last 1000 commands, ms; the worst robot). Goal (issue):
settling within 1.1x of the fake robots' over both links; latency p99 under 2 ms for 9 robots
at 10 Hz.
"""

import argparse
import os
from pathlib import Path
import tempfile

from curve_formation.run.run_experiment import run_experiment
from curve_formation.run.run_options import RunOptions


def quiet(*_):
    pass


def measure(experiment, duration, link, folder):
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    options = RunOptions(bridge=None if link == 'fake' else link, isolated=True)
    return run_experiment(experiment, Path(folder) / link, duration, options, log=quiet)


def settling(result):
    return [p['settle_time'] for p in result['phases']]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--experiment', default='arena_demo')
    parser.add_argument('--duration', type=float, default=60.0)
    parser.add_argument('--links', nargs='+', choices=('fake', 'udp', 'pty'),
                        default=['fake', 'udp', 'pty'])
    args = parser.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as folder:
        for link in args.links:
            results[link] = measure(args.experiment, args.duration, link, folder)
    reference = settling(results['fake']) if 'fake' in results else None
    print(f'{args.experiment}, {args.duration:g} s per run')
    print(f'{"robots via":>10s} {"settling (s)":>14s} {"x fake":>7s} {"final |e|":>10s} '
          f'{"sent":>6s} {"answered":>9s} {"failed":>6s} {"lat p50":>8s} {"lat p99 ms":>10s}')
    for link, result in results.items():
        times = settling(result)
        ratio = ('' if reference is None or None in times + reference
                 else ' '.join(f'{t / r:.3f}' for t, r in zip(times, reference, strict=True)))
        shown = ' '.join('-' if t is None else f'{t:.1f}' for t in times)
        row = f'{link:>10s} {shown:>14s} {ratio:>7s} {result["final_error_norm"]:10.2e}'
        links = result.get('links', {})
        if links:
            sent = sum(s['sent'] for s in links.values())
            replies = sum(s['replies'] for s in links.values())
            failed = sum(s['failed'] for s in links.values())
            p50 = max(s['latency_ms_p50'] for s in links.values())
            p99 = max(s['latency_ms_p99'] for s in links.values())
            row += f' {sent:6d} {replies:9d} {failed:6d} {p50:8.3f} {p99:10.3f}'
        print(row)
    for link, result in results.items():
        if result.get('links'):
            p99 = sorted(s['latency_ms_p99'] for s in result['links'].values())
            print(f'{link}: latency p99 per robot (ms), sorted: '
                  + ' '.join(f'{v:.2f}' for v in p99))
    bridged = [r for link, r in results.items() if link != 'fake' and r.get('links')]
    if bridged:
        worst = max(s['latency_ms_p99'] for r in bridged for s in r['links'].values())
        print(f'worst bridge latency p99: {worst:.3f} ms (goal < 2 ms: '
              f'{"met" if worst < 2.0 else "NOT met"})')
    if reference is not None and None not in reference:
        for link, result in results.items():
            times = settling(result)
            if link == 'fake':
                continue
            ok = None not in times and all(t <= 1.1 * r for t, r in zip(times, reference,
                                                                         strict=True))
            print(f'{link}: settling within 1.1x of fake robots: {"met" if ok else "NOT met"}')


if __name__ == '__main__':
    main()
