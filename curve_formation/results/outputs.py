"""What every run leaves in its folder, written in one place for `sim`, `run`, `analyze` and
the demo: metrics.json (with units and provenance), the figures (PNG and PDF), trajectory.npz,
experiment.yaml, optionally the animation, and report.html over all of them.
"""

from pathlib import Path

import numpy as np

from curve_formation.core.record import metrics
from curve_formation.figures import plots
from curve_formation.results.provenance import described
from curve_formation.results.report import write_report


ANIMATION = 'animation.mp4'


def write_outputs(out, experiment, record, result, experiment_path=None, label='run',
                  experiment_text=None, animate=False):
    """Write a run's outputs into `out` and return its metrics (with units and provenance).

    record: the run's samples: 't' (R,) s, 'poses' (R, n, 3), 'phase' (R,), optionally
    'dhat' (R, n, 2) and any other arrays, all kept in trajectory.npz. result: its metrics
    (metrics.run_metrics and what the caller adds). experiment_text: the experiment as run
    (default: the file's text). animate: also write animation.mp4 (figures.animation).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    described_result = write_metrics(out, result, experiment_path)
    t, poses, phase = record['t'], record['poses'], record['phase']
    plots.run_figures(out, experiment, t, poses, phase, record.get('dhat'), label=label,
                      result=result)
    np.savez_compressed(out / 'trajectory.npz', **record)
    if experiment_text is None and experiment_path is not None:
        experiment_text = Path(experiment_path).read_text()
    if experiment_text is not None:
        (out / 'experiment.yaml').write_text(experiment_text)
    if animate:
        from curve_formation.figures.animation import animate as film
        film(out / ANIMATION, experiment, t, poses, phase)
    write_report(out)
    return described_result


def write_metrics(out, result, experiment_path=None):
    """metrics.json in `out`: the result with its units and provenance, which it returns."""
    described_result = described(result, experiment_path)
    (Path(out) / 'metrics.json').write_text(metrics.strict_json(described_result))
    return described_result


LAW_COMPARISON = 'law_comparison.png'


def write_law_comparison(out, experiment, duration, runs=()):
    """law_comparison.png (and .pdf) in `out`: the formation error of the paper's law and of
    the experiment's own law, both simulated from the experiment's start for `duration` s,
    with `runs` ([(label, t, poses, phase)], e.g. the same experiment over ROS) overlaid.
    Returns the simulated metrics {'paper': ..., 'ours': ...}.
    """
    import dataclasses

    from curve_formation.core.sim.pipeline import simulate_kinematic
    paper = dataclasses.replace(experiment.gains, law='paper', sampled_heading=False)
    series, found = [], {}
    for key, label, gains in (('paper', "paper's law (simulated)", paper),
                              ('ours', f'{experiment.gains.law} law (simulated)',
                               experiment.gains)):
        sim, _ = simulate_kinematic(dataclasses.replace(experiment, gains=gains),
                                    duration=duration)
        series.append((label, sim.t, sim.error_norm))
        found[key] = metrics.result_metrics(sim)
    for label, t, poses, phase in runs:
        errors = metrics.target_errors(poses, phase, experiment, t=t)
        series.append((label, t, metrics.error_norm(errors)))
    plots.plot_error_norm(Path(out) / LAW_COMPARISON, experiment, series,
                          experiment.tolerance(),
                          title=f"{experiment.name}: the paper's law and ours, same start")
    return found
