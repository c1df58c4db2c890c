"""Analyse a recorded run from its bag alone: the batch simulator's metrics and figures.

The bag's metadata carries the experiment file (written by `curve-formation run --bag`); the
curves are taken from the recorded /formation/curve messages, so a curve that was observed at
run time is measured too. Poses, commands and estimates are sampled on a uniform grid (latest
value, NaN before the first) from t = 0 at the first curve message.
"""

from dataclasses import dataclass, replace
import json
import math
from pathlib import Path
import re

import numpy as np
import yaml

from curve_formation.bag import bag_info, BagError, read_messages
from curve_formation.core import metrics, plots
from curve_formation.core.assignment import agent_parameters
from curve_formation.core.curve_codec import decode_curve, yaw_from_quaternion
from curve_formation.core.curves import Fit
from curve_formation.core.experiment import build_experiment, load_experiment, Phase


EXPERIMENT_KEY = 'curve_formation.experiment'
_ROBOT_TOPIC = re.compile(r'^/robot_(\d+)/(pose|cmd_vel|disturbance_estimate)$')


@dataclass
class BagRun:
    """A run read from a bag: the experiment (phases from the bag's curves) and series."""

    experiment: object
    t: np.ndarray          # (R,) s since the first curve
    poses: np.ndarray      # (R, n, 3)
    commands: np.ndarray   # (R, n, 2)
    dhat: np.ndarray       # (R, n, 2)
    phase: np.ndarray      # (R,)
    counts: dict           # {topic: messages read}


def load_bag_run(path, experiment_path=None, sample_hz=20.0):
    """Read a bag into a BagRun; BagError with a clear message if it cannot be used."""
    path = Path(path)
    _, custom = bag_info(path)
    if experiment_path is not None:
        experiment = load_experiment(experiment_path)
    elif EXPERIMENT_KEY in custom:
        experiment = build_experiment(yaml.safe_load(custom[EXPERIMENT_KEY]),
                                      f'{path} (metadata)')
    else:
        raise BagError(f'{path}: the bag does not carry its experiment; pass --experiment')
    n = experiment.n
    events = {'pose': [[] for _ in range(n)], 'cmd_vel': [[] for _ in range(n)],
              'disturbance_estimate': [[] for _ in range(n)]}
    curves, counts = [], {}
    for topic, _, stamp, msg in read_messages(path):
        counts[topic] = counts.get(topic, 0) + 1
        t = stamp * 1e-9
        if topic == '/formation/curve':
            curve, curve_id = decode_curve([(d.label, d.size) for d in msg.layout.dim],
                                           msg.data)
            curves.append((t, curve_id, curve))
            continue
        match = _ROBOT_TOPIC.match(topic)
        if not match or not 1 <= int(match.group(1)) <= n:
            continue
        kind, i = match.group(2), int(match.group(1)) - 1
        if kind == 'pose':
            q = msg.pose.orientation
            value = (msg.pose.position.x, msg.pose.position.y,
                     yaw_from_quaternion(q.x, q.y, q.z, q.w))
        elif kind == 'cmd_vel':
            value = (msg.linear.x, msg.angular.z)
        else:
            value = (msg.vector.x, msg.vector.y)
        events[kind][i].append((t, value))
    if not curves:
        raise BagError(f'{path}: no /formation/curve message: nothing to measure against')
    t0 = curves[0][0]
    end = max((ev[-1][0] for ev in events['pose'] if ev), default=t0)
    if end - t0 < 2.0 / sample_hz:
        raise BagError(f'{path}: less than two samples of poses after the first curve')
    grid = t0 + np.arange(0.0, end - t0, 1.0 / sample_hz)
    phases = _bag_phases(experiment, curves, t0)
    curve_times = np.array([c[0] for c in curves])
    phase = np.searchsorted(curve_times, grid, side='right') - 1
    return BagRun(replace(experiment, phases=phases), grid - t0,
                  _sample(events['pose'], grid, 3), _sample(events['cmd_vel'], grid, 2),
                  _sample(events['disturbance_estimate'], grid, 2), phase, counts)


def _bag_phases(experiment, curves, t0):
    spacing = experiment.spec.agents.spacing
    phases = []
    for k, (t, _, curve) in enumerate(curves):
        s = agent_parameters(curve, experiment.n, spacing)
        g_bar = curve.basis.G(s).reshape(2 * experiment.n, 2 * curve.basis.H)
        phases.append(Phase(k, t - t0, Fit(curve, math.nan, math.nan, 0), s, curve.points(s),
                            g_bar))
    return tuple(phases)


def _sample(per_robot, grid, width):
    """(R, n, width): each robot's latest value at each grid time, NaN before its first."""
    out = np.full((len(grid), len(per_robot), width), np.nan)
    for i, events in enumerate(per_robot):
        if not events:
            continue
        times = np.array([t for t, _ in events])
        values = np.array([v for _, v in events], dtype=float)
        index = np.searchsorted(times, grid, side='right') - 1
        valid = index >= 0
        out[valid, i] = values[index[valid]]
    return out


def analyze_bag(path, out_dir, experiment_path=None, compare=None):
    """metrics.json and the paper's figures from a bag; `compare` overlays a second bag."""
    run = load_bag_run(path, experiment_path)
    usable = ~np.isnan(run.poses).any(axis=(1, 2))
    if not usable.any():
        raise BagError(f"{path}: no time at which every robot's pose is known")
    first = np.argmax(usable)
    t, poses, phase = run.t[first:], run.poses[first:], run.phase[first:]
    dhat = np.nan_to_num(run.dhat[first:])
    result = metrics.run_metrics(run.experiment, t, poses, phase, dhat,
                                 np.nan_to_num(run.commands[first:]))
    result['bag'] = {'path': str(path), 'messages': run.counts}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plots.run_figures(out, run.experiment, t, poses, phase, dhat, label=Path(path).name)
    if compare is not None:
        other = load_bag_run(compare, experiment_path)
        ok = ~np.isnan(other.poses).any(axis=(1, 2))
        errors = [metrics.error_norm(metrics.target_errors(r_poses, r_phase, run.experiment))
                  for r_poses, r_phase in ((poses, phase), (other.poses[ok], other.phase[ok]))]
        plots.plot_error_norm(out / 'compare_error_norm.png', run.experiment,
                              [(Path(path).name, t, errors[0]),
                               (Path(compare).name, other.t[ok], errors[1])])
        plots.plot_paths(out / 'compare_paths.png', run.experiment, poses, phase,
                         overlay=(Path(compare).name, other.poses[ok]))
        result['compare'] = metrics.run_metrics(run.experiment, other.t[ok], other.poses[ok],
                                                other.phase[ok])
    (out / 'metrics.json').write_text(json.dumps(result, indent=2) + '\n')
    return result
