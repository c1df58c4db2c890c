"""The arena cases from random starts through the ROS node graph and the fake overhead camera,
against the batch simulator from the same starts.

Run: scripts/bench camera_starts   (about 11 minutes: three starts of mona_arena, 120 s each,
and three of arena_demo, 90 s each; --seeds 5 7 for others)

Each start is the experiment file's random start box drawn with another seed (as
scripts/bench collision_avoidance draws them: seeds 0, 1, 2 are its first three). A run is
`curve-formation run FILE --camera`: one process per node, fake_arena's bodies, fake_camera
rendering the robots' markers, camera_tracker's poses feeding every controller. Printed per
start: settling per phase on the true poses and in the simulator, the ROS run's ratio to the
straight-trip bound, contacts, the smallest surface gap and how long any marker was hidden.
"""

import argparse
import json
import os
from pathlib import Path
import re
import tempfile

from collision_avoidance import lower_bounds, settling

from curve_formation.cli import main as cli
from curve_formation.core.config.loading import load_experiment, with_start
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


CASES = ('mona_arena', 'arena_demo')


def reseeded(name, seed):
    """The shipped experiment's text with its random start box drawn with `seed`."""
    text = resolve_config(name).read_text()
    text, count = re.subn(r'(random: \{seed: )\d+', rf'\g<1>{seed}', text)
    if count != 1:
        raise ValueError(f'{name}: expected one random start box to reseed')
    return text


def camera_run(config, out):
    """metrics.json of `curve-formation run config --camera`."""
    assert cli(['run', str(config), '--out', str(out), '--camera', '--isolated']) == 0
    return json.loads((Path(out) / 'metrics.json').read_text())


def seconds(value):
    return f'{value:5.1f}' if value is not None else '    -'


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', '95')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    folder = Path(tempfile.mkdtemp(prefix='camera-starts-'))
    rows = []
    for name in CASES:
        case = load_experiment(resolve_config(name))
        for seed in args.seeds:
            config = folder / f'{name}_seed{seed}.yaml'
            config.write_text(reseeded(name, seed))
            simulated = simulate(with_start(case, seeded_start(case, seed)))
            sim_times, _ = settling(simulated)
            data = camera_run(config, folder / f'{name}_seed{seed}')
            true_times = [p['settle_time'] for p in data['ground_truth']['phases']]
            rows.append((name, seed, true_times, sim_times, lower_bounds(simulated),
                         data['bodies']))
    print(f'\n{"case":>10s} {"seed":>4s} {"phase":>5s} {"camera run s":>12s} {"simulated s":>11s} '
          f'{"run / bound":>11s} {"contacts":>8s} {"gap mm":>7s} {"hidden s":>8s}')
    for name, seed, true_times, sim_times, bounds, bodies in rows:
        for k, (run_t, sim_t, bound) in enumerate(zip(true_times, sim_times, bounds,
                                                      strict=True)):
            ratio = f'{run_t / bound:11.2f}' if run_t is not None else '          -'
            print(f'{name:>10s} {seed:4d} {k:5d} {seconds(run_t):>12s} {seconds(sim_t):>11s} '
                  f'{ratio} {bodies["contacts"]["count"]:8.0f} '
                  f'{1000 * bodies["smallest_gap"]:7.2f} {bodies["marker_hidden_time"]:8.2f}')
    print(f'(runs in {folder})')


if __name__ == '__main__':
    main()
