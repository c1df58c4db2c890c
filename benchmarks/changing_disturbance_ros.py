"""mona_arena's disturbance on the PC swinging +-10 % (10 s period) over the whole ROS loop:
one process per node, poses from the rendered camera (fake_camera renders the robots,
camera_tracker finds their markers) or, with --poses, from the fake robots.

Run: scripts/bench changing_disturbance_ros            (three 120 s runs; ~9 min)
     scripts/bench changing_disturbance_ros --poses    (the fake robots' poses, no camera)

Runs, each from the file's own start: the file as shipped (constant disturbance, first-order
observer at 4 /s: the reference), the swing with the second-order observer at 8 /s
(controller.observer_order 2, as benchmarks/changing_disturbance.py measures it in the
pipeline), and the swing with the file's first-order observer. Prints, per run and phase,
the settling time (and against the reference), and the error norm's mean and largest value
over each phase's last 15 s against the tolerance: how much room the camera's noise leaves.
One run per case: runs of the same case differ (the nodes' timing is not repeatable).
Issue goal: the second-order observer settles the swing. JSON to --out.
"""

import argparse
import json
import os
from pathlib import Path
import random
import tempfile

from changing_disturbance import experiment_data, SECOND_ORDER
import yaml

from curve_formation.bags.analysis import load_run
from curve_formation.core.record.metrics import error_norm, target_errors
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


# (label, relative amplitude of the disturbance's 10 s sine, controller settings changed)
RUNS = (('constant, first-order at 4 /s (the file)', 0.0, ()),
        ('+-10 %, second-order at 8 /s', 0.1, SECOND_ORDER),
        ('+-10 %, first-order at 4 /s', 0.1, ()))
TAIL = 15.0   # s at each phase's end over which the residual error is summarised


def one_run(label, amplitude, controller, camera, folder):
    data, _ = experiment_data('mona_arena', amplitude, controller)
    path = folder / 'experiment.yaml'
    path.write_text(yaml.safe_dump(data))
    duration = data['simulation']['duration']
    with Run(path, folder / 'run', RunOptions(camera={} if camera else None),
             log=lambda *_: None) as run:
        run.spin_for(duration)
        live = run.write_results()
    experiment, t, poses, phase = load_run(folder / 'run')
    norm = error_norm(target_errors(poses, phase, experiment, t=t))
    ends = [p['start'] for p in live['phases'][1:]] + [t[-1]]
    phases = []
    for p, end in zip(live['phases'], ends, strict=True):
        tail = norm[(t >= end - TAIL) & (t < end)]
        phases.append({'settle_time': p['settle_time'], 'tolerance_mm': 1e3 * p['tolerance'],
                       'tail_mean_mm': 1e3 * float(tail.mean()),
                       'tail_max_mm': 1e3 * float(tail.max())})
    return {'run': label, 'camera': camera, 'phases': phases}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--poses', action='store_true',
                        help="the fake robots' poses instead of the rendered camera")
    parser.add_argument('--out', type=Path,
                        default=Path('out/bench/changing_disturbance_ros'))
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for k, (label, amplitude, controller) in enumerate(RUNS):
            folder = Path(scratch) / str(k)
            folder.mkdir()
            rows.append(one_run(label, amplitude, controller, not args.poses, folder))
    reference = [p['settle_time'] for p in rows[0]['phases']]
    source = "the fake robots' poses" if args.poses else 'the rendered camera'
    print(f"mona_arena over ROS, poses from {source}, from the file's start:")
    for row in rows:
        for k, (p, ref) in enumerate(zip(row['phases'], reference, strict=True)):
            settle = ('not settled' if p['settle_time'] is None else
                      f"settled at {p['settle_time']:.1f} s"
                      + (f" ({p['settle_time'] / ref:.2f}x)" if ref else ''))
            print(f"  {row['run']}, phase {k}: {settle}; error over its last {TAIL:g} s "
                  f"mean {p['tail_mean_mm']:.3f} mm, largest {p['tail_max_mm']:.3f} mm "
                  f"(tolerance {p['tolerance_mm']:.3f} mm)")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'runs.json').write_text(json.dumps(rows, indent=1))
    print(f'JSON: {args.out / "runs.json"}')


if __name__ == '__main__':
    main()
