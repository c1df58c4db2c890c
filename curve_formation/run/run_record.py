"""What a run (runner.Run) has recorded, read: the status line it logs every few seconds,
and its metrics (metrics.json) with everything the nodes reported beside the poses (e-stops,
deaths, links, the robots as their controllers estimated them, the fleet, the pre-flight, the
controllers' ticks).

Times in s since t = 0 unless stated; errors in m.
"""

import dataclasses
import math
import time

import numpy as np

from curve_formation import diagnostics
from curve_formation.core.record import body_metrics, metrics
from curve_formation.core.record.tick_timing import run_timing
from curve_formation.interface import robot_index
from curve_formation.nodes.runtime import now_seconds


STATUS_PERIOD = 5.0    # s between the status lines of a run, and of its waiting


def status_line(run):
    """One line on `run` (runner.Run) now (None before t = 0): t, phase, error norm against the
    tolerance, the worst robot's error (mm), how many robots drive (a non-zero command) or
    stand (or that the e-stop holds them all), and how many are at their targets: within
    tolerance / sqrt(n) (all of them so is the formation within its tolerance).
    """
    monitor = run.monitor
    phases = monitor.followed_phases()
    if monitor.t0 is None or not phases:
        return None
    t = now_seconds(monitor) - monitor.t0
    k = max(p.index for p in phases if p.start <= t) if phases[0].start <= t else 0
    followed = dataclasses.replace(run.experiment, phases=phases)
    errors = metrics.target_errors(monitor.latest.poses[None], np.array([k]), followed,
                                   t=np.array([t]),
                                   stamps=(monitor.latest.pose_stamps - monitor.t0)[None])[0]
    norm = float(metrics.error_norm(errors[None])[0])
    tolerance = followed.tolerance(k)
    worst = np.nanmax(np.linalg.norm(errors, axis=1)) if np.isfinite(errors).any() \
        else math.nan
    n = run.experiment.n
    driving = int(np.sum(np.abs(monitor.latest.commands).max(axis=1) > 0))
    held = run.monitor.estop_intervals(t)
    moving = ('all held by the e-stop' if held and held[-1][1] is None
              else f'{driving} driving, {n - driving} standing')
    at_target = int(np.sum(np.linalg.norm(errors, axis=1) < tolerance / math.sqrt(n)))
    settled = 'within' if norm < tolerance else 'above'
    fleet = '' if run.fleet_status is None else f'  {run.fleet_status.summary()}'
    timing = run_timing(monitor.command_times_since(time.time() - STATUS_PERIOD),
                        run.rate_hz)['slowest']
    if timing is not None:
        fleet += (f'  slowest controller robot {timing["robot"]} at '
                  f'{timing["rate_hz"]:.2f} Hz')
    return (f't {t:6.1f} s  phase {k}  error {norm:.3g} ({settled} tolerance '
            f'{tolerance:.3g})  worst robot {1e3 * worst:.1f} mm  robots: {moving}, '
            f'{at_target} at their targets{fleet}')


def measured(run):
    """(experiment as followed, record, metrics) of what `run`'s monitor recorded (the run
    ended), for outputs.write_outputs. RuntimeError if nothing was.
    """
    data = run.recording()
    if len(data['t']) < 2:
        raise RuntimeError('nothing was recorded')
    experiment, phase = run.followed(data['t'])
    camera = 'true_poses' in data
    truth = data['true_poses'] if camera else data['poses']
    estops = run.monitor.estop_intervals(float(data['t'][-1]))
    deaths = run.monitor.node_deaths
    result = metrics.run_metrics(experiment, data['t'], data['poses'], phase,
                                 data['dhat'], data['commands'], estops=estops,
                                 deaths=deaths, stamps=data['pose_stamps'])
    if 'bodies' in result:   # measured on the bodies, i.e. the true poses
        result['bodies'] = body_metrics.body_metrics(experiment, data['t'], truth,
                                                run.monitor.contacts,
                                                data['unseen'] if camera else None)
    if run.monitor.links:   # robot_bridge's link reports, per robot
        result['links'] = {name.strip('/').split('/')[0]: diagnostics.link_summary(reports)
                           for name, reports in sorted(run.monitor.links.items())}
    if run.monitor.estimates:   # each robot as its controller estimated it, at the end
        result['robot_estimates'] = dict(sorted(run.monitor.estimates.items(),
                                                key=lambda kv: robot_index(kv[0]) or 0))
    # robot -> [[from, to or null (s), nodes]] while its cmd_vel had several publishers
    result['command_sources'] = run.monitor.command_sources
    if run.fleet_status is not None:
        result['fleet'] = run.fleet_status.as_dict()
    if run.preflight is not None:
        result['preflight'] = {**run.preflight.as_dict(),
                               **({'left_out': run.left_out['robots'],
                                   'team': run.left_out['team']}
                                  if run.left_out else {})}
    if run.monitor.t0 is not None:   # the controllers' ticks over the run
        result['ticks'] = run_timing(run.monitor.command_times_since(run.monitor.t0),
                                     run.rate_hz)
    result['control'] = f'ROS nodes at {run.rate_hz:g} Hz'
    result['mode'] = ('single process' if run.options.single_process
                      else 'one process per node')
    if camera:
        result['ground_truth'] = metrics.ground_truth_metrics(
            experiment, data, phase, run.monitor.law_pose_rms(), estops, deaths)
    return experiment, {'phase': phase, **data}, result
