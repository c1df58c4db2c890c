"""Settling of each control law on the paper's cases, over random starts; scaling in n and d.

Run: scripts/bench convergence   (or --quick for 3 seeds and no scaling parts)

For every paper case, seed (random start drawn from the case's start box), control mode
(continuous; 10 Hz zero-order hold) and law, it reports the time after each curve switch
until ||e|| < tolerance * curve size for good, the final max |dhat - d/k2| and the peak wheel
speed. The floor of a run is the same gains, graph, heading command and start with no
disturbance and the estimator off (k2 = 0); `ratio` is settling / floor, per phase.
At 10 Hz the paper's heading command needs a bounded turn rate: where a case has no limits,
its 10 Hz runs with the paper heading get |w| <= 10 rad/s (paper-notes.md).
Writes JSON and figures to --out (default out/bench/convergence).
"""

import argparse
import dataclasses
import json
from pathlib import Path
import time

import matplotlib
import numpy as np
from scenarios import scaled_experiment
import yaml

from curve_formation.core.config.loading import (
    as_in_the_paper,
    build_experiment,
    load_experiment,
    with_start,
)
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402


CASES = ('closed_curve', 'open_curve', 'shape_change', 'mona_arena', 'mona_arena/paper')
MODES = (('continuous', None), ('10 Hz', 10.0))
TURN_BOUND = 10.0   # rad/s, for the paper heading at 10 Hz when a case has no limits


def laws(gains):
    """name -> gains of each law compared; the paper's k1, k2, l throughout."""
    paper = gains.paper_law()
    return {
        'paper': paper,
        'adaptive': dataclasses.replace(paper, law='adaptive',
                                        adaptation=(1.0, 1.0 / gains.offset ** 2)),
        'observer': dataclasses.replace(paper, law='observer'),
        'observer+sampled': dataclasses.replace(paper, law='observer', sampled_heading=True),
    }


def limits_for(case, gains, rate):
    limits = case.limits
    unlimited = (limits.max_wheel_speed == np.inf and limits.max_angular_rate == np.inf)
    if rate and unlimited and not gains.sampled_heading:
        return limits._replace(max_angular_rate=TURN_BOUND)
    return limits


def one_run(case, gains, rate, start, disturbance=None):
    """Per-phase settle times, final estimate error and peak wheel speed of one run."""
    limits = limits_for(case, gains, rate)
    result = simulate(case, rate_hz=rate, gains=gains, initial_poses=start,
                      disturbance=disturbance, limits=limits)
    data = metrics.result_metrics(result)
    estimate = (float(np.abs(result.dhat[-1] - result.disturbance / gains.k2).max())
                if gains.k2 > 0 else 0.0)
    return {'settle': [p['settle_time'] for p in data['phases']],
            'estimate_error': estimate,
            # without a wheel base (the abstract cases) the peak wheel speed is the peak |v|
            'peak_wheel_speed': data.get('peak_wheel_speed', data['peak_v']),
            'peak_w': data['peak_w']}


def load_case(name):
    """A shipped experiment; 'mona_arena/paper' is the arena case with the paper's agents,
    graph and law and point robots (core.config.experiment.as_in_the_paper).
    """
    base, _, variant = name.partition('/')
    if not variant:
        return load_experiment(resolve_config(base))
    data = as_in_the_paper(yaml.safe_load(resolve_config(base).read_text()))
    return build_experiment(data, name)


def paper_cases(seeds, names=CASES):
    rows = []
    for name in names:
        case = load_case(name)
        for mode, rate in MODES:
            started = time.perf_counter()
            runs = {law: [] for law in laws(case.gains)}
            floors = {False: [], True: []}
            for seed in seeds:
                start = seeded_start(case, seed)
                seeded = with_start(case, start)   # `nearest` assigns from each start
                for sampled in (False, True):
                    if sampled and rate is None:
                        floors[True].append(floors[False][-1])   # identical when continuous
                        continue
                    floor = dataclasses.replace(case.gains.paper_law(), k2=0.0,
                                                sampled_heading=sampled)
                    floors[sampled].append(one_run(seeded, floor, rate, start, [0.0, 0.0]))
                for law, gains in laws(case.gains).items():
                    runs[law].append(one_run(seeded, gains, rate, start))
            for law, gains in laws(case.gains).items():
                rows.append(summarise(name, mode, law, runs[law],
                                      floors[gains.sampled_heading]))
            print(f'  {name} {mode}: {len(seeds)} seeds in {time.perf_counter() - started:.0f} s',
                  flush=True)
    return rows


def summarise(case, mode, law, runs, floors):
    phases = len(runs[0]['settle'])
    settled = sum(all(t is not None for t in r['settle']) for r in runs)
    per_phase = []
    for k in range(phases):
        times = [r['settle'][k] for r in runs]
        floor = [f['settle'][k] for f in floors]
        ratios = [t / f for t, f in zip(times, floor, strict=True)
                  if t is not None and f is not None and f > 0]
        done = [t for t in times if t is not None]
        per_phase.append({
            'settled': len(done), 'median': _median(done),
            'max': max(done) if len(done) == len(times) else None,
            'floor_median': _median([f for f in floor if f is not None]),
            'floor_settled': sum(f is not None for f in floor),
            'ratio_max': (max(ratios) if len(ratios) == len(times) else None),
        })
    return {'case': case, 'mode': mode, 'law': law, 'seeds': len(runs), 'settled': settled,
            'phases': per_phase,
            'estimate_error_median': float(np.median([r['estimate_error'] for r in runs])),
            'peak_wheel_speed_max': max(r['peak_wheel_speed'] for r in runs)}


def _median(values):
    return float(np.median(values)) if values else None


def _fmt(value, spec='.1f'):
    return '-' if value is None else format(value, spec)


def print_table(rows):
    print('\n| case | control | law | all phases settled | settling s, median / max (per '
          'phase) | floor s, median | ratio max | final max abs(dhat - d/k2), median | peak '
          'wheel speed |')
    print('|---|---|---|---|---|---|---|---|---|')
    for r in rows:
        settle = '; '.join(f'{_fmt(p["median"])} / {_fmt(p["max"])}' for p in r['phases'])
        floor = '; '.join(f'{_fmt(p["floor_median"])} ({p["floor_settled"]}/{r["seeds"]})'
                          for p in r['phases'])
        ratio = '; '.join(_fmt(p['ratio_max'], '.2f') for p in r['phases'])
        print(f'| {r["case"]} | {r["mode"]} | {r["law"]} | {r["settled"]}/{r["seeds"]} | '
              f'{settle} | {floor} | {ratio} | {r["estimate_error_median"]:.2g} | '
              f'{r["peak_wheel_speed_max"]:.3g} |')


def scaling_in_n(sizes, seeds):
    """Observer+sampled vs its floor at 10 Hz on the scaled scenario, per n."""
    print('\nSettling vs number of agents (10 Hz, observer + sampled heading, d = [1, 1], '
          'chain + skip edges, wheels <= 5 m/s)')
    print(f'{"n":>5s} {"settled":>8s} {"median s":>9s} {"max s":>7s} {"floor median s":>15s} '
          f'{"ratio max":>10s}')
    out = []
    for n in sizes:
        duration = 60.0 + 2.0 * n
        times, floors = [], []
        for seed in seeds:
            case = scaled_experiment(n, seed, duration, law='observer', heading='sampled')
            r = one_run(case, case.gains, 10.0, case.initial_poses)
            f = one_run(case, dataclasses.replace(case.gains, k2=0.0), 10.0,
                        case.initial_poses, [0.0, 0.0])
            times.append(r['settle'][0])
            floors.append(f['settle'][0])
        row = _scaling_row(n, times, floors)
        out.append(row)
    return out


def scaling_in_d(sizes, seeds, n=9):
    """Observer+sampled and paper at 10 Hz on the scaled scenario, per disturbance size."""
    print(f'\nSettling vs disturbance size (10 Hz, n = {n}, d = size * [1, 1], wheels <= 5 m/s)')
    print(f'{"|d|":>5s} {"law":>17s} {"settled":>8s} {"median s":>9s} {"max s":>7s} '
          f'{"floor median s":>15s} {"ratio max":>10s}')
    out = []
    for size in sizes:
        for law, heading in (('observer', 'sampled'), ('paper', 'paper')):
            times, floors = [], []
            for seed in seeds:
                case = scaled_experiment(n, seed, 90.0, (size, size), law=law, heading=heading)
                gains = case.gains
                r = one_run(case, gains, 10.0, case.initial_poses)
                f = one_run(case, dataclasses.replace(gains, k2=0.0), 10.0,
                            case.initial_poses, [0.0, 0.0])
                times.append(r['settle'][0])
                floors.append(f['settle'][0])
            row = _scaling_row(size, times, floors, law)
            out.append(row)
    return out


def _scaling_row(key, times, floors, law=None):
    done = [t for t in times if t is not None]
    ratios = [t / f for t, f in zip(times, floors, strict=True) if t is not None and f]
    row = {'key': key, 'law': law, 'settled': len(done), 'seeds': len(times),
           'median': _median(done), 'max': max(done) if len(done) == len(times) else None,
           'floor_median': _median([f for f in floors if f is not None]),
           'ratio_max': max(ratios) if len(ratios) == len(times) else None}
    label = f'{key:5g}' + (f' {law:>17s}' if law else '')
    print(f'{label} {len(done):5d}/{len(times):<2d} {_fmt(row["median"]):>9s} '
          f'{_fmt(row["max"]):>7s} {_fmt(row["floor_median"]):>15s} '
          f'{_fmt(row["ratio_max"], ".2f"):>10s}', flush=True)
    return row


def figures(out, n_rows, d_rows):
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    if n_rows:
        axes[0].plot([r['key'] for r in n_rows], [r['median'] for r in n_rows], 'o-',
                     label='observer + sampled, d = [1, 1]')
        axes[0].plot([r['key'] for r in n_rows], [r['floor_median'] for r in n_rows], 's--',
                     label='floor (d = 0, k2 = 0)')
        axes[0].set(xlabel='agents n', ylabel='median settling time (s)',
                    title='10 Hz, chain + skip edges')
        axes[0].legend()
    for law in ('observer', 'paper'):
        rows = [r for r in d_rows if r['law'] == law]
        if rows:
            axes[1].plot([r['key'] for r in rows],
                         [np.nan if r['median'] is None else r['median'] for r in rows], 'o-',
                         label=law)
    axes[1].set(xlabel='disturbance size (d = size [1, 1])', ylabel='median settling time (s)',
                title='10 Hz, n = 9 (missing = not settled)')
    axes[1].legend()
    fig.tight_layout()
    fig.savefig(out / 'convergence_scaling.png', dpi=120)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--quick', action='store_true', help='3 seeds, no scaling parts')
    parser.add_argument('--out', default='out/bench/convergence')
    parser.add_argument('--cases', nargs='+', default=list(CASES), choices=CASES,
                        help='paper cases to run (default: all)')
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = range(3 if args.quick else args.seeds)
    started = time.perf_counter()
    print(f'Paper cases, {len(seeds)} seeds each')
    rows = paper_cases(seeds, args.cases)
    print_table(rows)
    n_rows = d_rows = []
    if not args.quick:
        n_rows = scaling_in_n([6, 12, 25, 50, 100], range(5))
        d_rows = scaling_in_d([0.0, 0.25, 1.0, 2.0, 4.0], range(5))
        figures(out, n_rows, d_rows)
    (out / 'convergence.json').write_text(json.dumps(
        {'paper_cases': rows, 'scaling_n': n_rows, 'scaling_d': d_rows}, indent=1) + '\n')
    print(f'\nwrote {out}/convergence.json (and convergence_scaling.png); '
          f'{time.perf_counter() - started:.0f} s in all')


if __name__ == '__main__':
    main()
