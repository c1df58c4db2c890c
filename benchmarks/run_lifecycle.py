"""How long a run takes to start and to stop: what every run, and every test that runs one,
pays around its formation.

Run: scripts/bench run_lifecycle [--experiment arena_demo] [--runs 3] [--domains isolated lab]

For each kind of domain (`isolated`: a private random one, as the demo and the tests run;
`lab`: the caller's ROS_DOMAIN_ID, where a run first looks 3 s for another formation) it
prints the start, from entering the run to t = 0 (the first curve), and the stop, from
leaving it to every node process ended and the bag closed (s, median and range over the
runs). Nothing moves between the two: each run ends as soon as it has started.
"""

import argparse
import os
from pathlib import Path
import statistics
import tempfile
import time

from curve_formation.paths import resolve_config
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


def lifecycle(experiment, isolated, folder):
    """(start s, stop s) of one run of `experiment`."""
    began = time.monotonic()
    with Run(experiment, folder, RunOptions(isolated=isolated), log=lambda *_: None):
        started = time.monotonic()
    return started - began, time.monotonic() - started


def spread(values):
    return f'{statistics.median(values):5.2f} ({min(values):.2f}-{max(values):.2f})'


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--experiment', default='arena_demo')
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--domains', nargs='+', default=['isolated', 'lab'],
                        choices=['isolated', 'lab'])
    args = parser.parse_args()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    experiment = resolve_config(args.experiment)
    print(f'{"domain":>9} {"runs":>4} {"start s, median (range)":>24} '
          f'{"stop s, median (range)":>23}')
    with tempfile.TemporaryDirectory() as tmp:
        for domain in args.domains:
            times = [lifecycle(experiment, domain == 'isolated', Path(tmp) / f'{domain}_{k}')
                     for k in range(args.runs)]
            print(f'{domain:>9} {args.runs:>4} {spread([t[0] for t in times]):>24} '
                  f'{spread([t[1] for t in times]):>23}', flush=True)


if __name__ == '__main__':
    main()
