"""What the command line's larger commands do, as functions: a batch simulation written to
a folder (metrics, figures), and the headless demo (the paper's cases, a ROS run with a bag,
the laws compared, the report). Prints its progress on stdout, warnings on stderr.
"""

import dataclasses
from pathlib import Path
import sys
from typing import Any

from curve_formation.core.config.experiment import Experiment
from curve_formation.core.config.loading import check_rate_override, load_experiment
from curve_formation.paths import resolve_config


PAPER_CASES = ('closed_curve', 'open_curve', 'shape_change', 'mona_arena')
DEMO_RUN = 'arena_demo'


def write_json(path: Path, data: Any) -> None:
    """`data` as strict JSON (no NaN) at `path`, its folder made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    from curve_formation.core.record.metrics import strict_json
    path.write_text(strict_json(data))


def simulate_to_dir(config: str | Path, out_dir: str | Path, rate: Any = 'config',
                    law: str | None = None, heading: str | None = None,
                    physics: str | None = None, animate: bool = False) -> dict[str, Any]:
    """Batch-simulate one experiment; write metrics.json and figures into out_dir.

    law ('paper', 'adaptive', 'observer') and heading ('paper', 'sampled') override the file's;
    physics ('kinematic', 'mujoco'; None: the file's physics.engine): the kinematic batch
    simulator, or the nodes' tick pipeline in the MuJoCo world (core.sim.pipeline).
    animate: also write animation.mp4. Writes the folder of outputs.write_outputs.
    """
    from curve_formation.core.record import metrics
    from curve_formation.results.outputs import write_outputs

    path = resolve_config(config)
    experiment = load_experiment(path)
    if rate not in ('config', None):
        check_rate_override(experiment, rate)
    warn(experiment)
    gains = experiment.gains
    if law is not None:
        gains = dataclasses.replace(gains, law=law)
    if heading is not None:
        gains = dataclasses.replace(gains, sampled_heading=heading == 'sampled')
    engine = physics or experiment.spec.physics.engine
    latency = experiment.spec.controller.command_latency
    order = experiment.spec.controller.observer_order
    experiment = dataclasses.replace(experiment, gains=gains)
    pipeline = (f"the nodes' tick pipeline, {engine} world, commands {latency:g} s late as "
                f'told, observer of order {order}')
    if engine == 'mujoco':   # robots in MuJoCo: the nodes' tick pipeline
        from curve_formation.core.sim.pipeline import simulate_pipeline
        if rate is None:
            raise ValueError("--continuous: the MuJoCo world runs the nodes' tick pipeline, "
                             'at a control rate (--rate, or controller.rate_hz)')
        result = simulate_pipeline(experiment, 'mujoco',
                                   rate_hz=None if rate == 'config' else rate)
        simulator = pipeline
    else:   # the batch simulator, or the pipeline where an online estimate would be taken
        from curve_formation.core.sim.pipeline import simulate_kinematic
        result, why = simulate_kinematic(experiment, rate)
        simulator = 'batch (compiled)' if why is None else f'{pipeline} ({why})'
    data = metrics.result_metrics(result)
    data['simulator'] = simulator
    write_outputs(out_dir, experiment, {'t': result.t, 'poses': result.poses,
                                        'dhat': result.dhat, 'commands': result.commands,
                                        'phase': result.phase},
                  data, path, label=data['control'], animate=animate)
    return data


def summary_line(name: str, data: dict[str, Any]) -> str:
    """One line of a run's or a simulation's metrics: final error and each curve's settling."""
    settle = ', '.join('not settled' if p['settle_time'] is None else f'{p["settle_time"]:.1f} s'
                       for p in data['phases'])
    stops = data.get('estop', {}).get('intervals', [])
    held = '; e-stop held {} time{} for {:.1f} s in all{}'.format(
        len(stops), 's' if len(stops) > 1 else '', data['estop']['stopped_for'],
        ' (still held at the end)' if stops[-1][1] is None else '') if stops else ''
    return (f'{name:24s} final ||e|| = {data["final_error_norm"]:.3g}, '
            f'settling per curve: {settle}{held}')


def warn(experiment: Experiment) -> None:
    """Print what the experiment allows but should not: `warning: FILE: ...` on stderr."""
    for text in experiment.warnings:
        print(f'warning: {experiment.source}: {text}', file=sys.stderr)


def run_demo(out: Path, duration: float) -> None:
    """The headless demo into `out`: the paper's cases batch-simulated with the paper's law
    and ours, then the arena demo as ROS nodes with a bag for `duration` s, the two laws
    compared from the run's start, and the report.
    """
    import shutil

    import numpy as np

    from curve_formation.results.outputs import write_law_comparison
    from curve_formation.results.report import write_report
    from curve_formation.run.run_experiment import run_experiment
    from curve_formation.run.run_options import RunOptions
    summary: dict[str, Any] = {'paper_cases_batch_simulation': {}}
    print("1/3 batch simulation of the paper's cases, with the paper's law and with ours")
    for name in PAPER_CASES:
        for law, heading in (('paper', 'paper'), ('observer', 'sampled')):
            data = simulate_to_dir(name, out / 'paper_cases' / name / law, law=law,
                                   heading=heading)
            summary['paper_cases_batch_simulation'].setdefault(name, {})[law] = data
            print('    ' + summary_line(f'{name} ({law})', data))
    print(f'2/3 ROS 2 run of {DEMO_RUN}: 9 robots in one fake arena, 9 controllers '
          f'(one group per core), curve server ({duration:g} s)')
    run_dir = out / DEMO_RUN
    result = run_experiment(DEMO_RUN, run_dir, duration,
                            RunOptions(bag_path=run_dir / 'bag', isolated=True, animate=True),
                            log=lambda m: print('    ' + m))
    summary[DEMO_RUN] = result
    print('    ' + summary_line(DEMO_RUN, result))
    print(f"3/3 the paper's law and ours from the same start ({DEMO_RUN}, simulated, with the "
          'ROS run); the report')
    record = np.load(run_dir / 'trajectory.npz')
    compared = write_law_comparison(
        run_dir, load_experiment(resolve_config(DEMO_RUN)), duration,
        [('ours over ROS 2 (this run)', record['t'], record['poses'], record['phase'])])
    summary['law_comparison_simulated'] = compared
    for law, data in compared.items():
        print('    ' + summary_line(f'{DEMO_RUN} ({law}, sim)', data))
    write_report(run_dir, f'{DEMO_RUN}: the demo run over ROS 2')
    for name in ('report.html', 'law_comparison.png', 'law_comparison.pdf', 'animation.mp4'):
        shutil.copy2(run_dir / name, out / name)
    write_json(out / 'summary.json', summary)
    print(f'wrote {out}/: report.html (open it in a browser), law_comparison.png/.pdf, '
          f'animation.mp4, summary.json; paper_cases/<case>/ and {DEMO_RUN}/ with their '
          f'reports, metrics.json and figures; {DEMO_RUN}/bag (ROS 2 bag, MCAP)')


