"""How long a run's figures, animation and report take: the arena demo's 9 robots over 120 s.

Run: scripts/bench figures          (~1 min)

Simulates arena_demo for 120 s (the batch simulator, sampled at 100 Hz: 12,000 samples), then
times, each three times, figures.plots.run_figures (four figures as PNG at 300 dpi and PDF),
figures.animation.animate (MP4, 30 s of film at 15 fps) and report.write_report, and prints the
best of three of each. Goal (issue #43): figures and animation of a 9-robot, 120 s run in
under 30 s. JSON to --out (default out/bench/figures).
"""

import argparse
import json
from pathlib import Path
import shutil
import tempfile

from simulation_speed import best_time  # benchmarks/ is the script's folder

from curve_formation.core.config.loading import load_experiment
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config
from curve_formation.results.outputs import write_outputs


GOAL = 30.0   # s, figures and animation together


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='out/bench/figures')
    args = parser.parse_args()
    path = resolve_config('arena_demo')
    experiment = load_experiment(path)
    sim = simulate(experiment, duration=120.0)
    record = {'t': sim.t, 'poses': sim.poses, 'phase': sim.phase, 'dhat': sim.dhat}
    result = metrics.result_metrics(sim)
    folder = Path(tempfile.mkdtemp(prefix='bench-figures-'))
    try:
        from curve_formation.figures import plots
        from curve_formation.figures.animation import animate
        from curve_formation.results.report import write_report
        write_outputs(folder, experiment, record, result, path)   # warm: fonts, imports
        found = {
            'samples': len(sim.t), 'robots': experiment.n, 'run_seconds': float(sim.t[-1]),
            'figures_s': best_time(lambda: plots.run_figures(
                folder, experiment, sim.t, sim.poses, sim.phase, sim.dhat, result=result), 3),
            'animation_s': best_time(lambda: animate(
                folder / 'animation.mp4', experiment, sim.t, sim.poses, sim.phase), 3),
            'report_s': best_time(lambda: write_report(folder), 3),
            'report_bytes': (folder / 'report.html').stat().st_size,
        }
    finally:
        shutil.rmtree(folder)
    total = found['figures_s'] + found['animation_s']
    found['figures_and_animation_s'] = total
    found['goal_s'] = GOAL
    print(f"arena_demo, {found['robots']} robots, {found['run_seconds']:.0f} s "
          f"({found['samples']} samples)")
    print(f"  figures (4 x PNG 300 dpi + PDF): {found['figures_s']:6.2f} s")
    print(f"  animation (MP4, 30 s film):      {found['animation_s']:6.2f} s")
    print(f"  report.html ({found['report_bytes'] / 1e6:.1f} MB):        "
          f"{found['report_s']:6.2f} s")
    print(f'  figures + animation:             {total:6.2f} s  (goal < {GOAL:g} s: '
          f'{total / GOAL:.2f} of it)')
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / 'figures.json').write_text(json.dumps(found, indent=2) + '\n')


if __name__ == '__main__':
    main()
