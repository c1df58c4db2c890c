"""Metrics of a formation run, from recorded time series alone.

Inputs are plain arrays so that a batch simulation, a ROS run and a bag are measured the same
way: t (R,) s, poses (R, n, 3), dhat (R, n, 2) or None, commands (R, n, 2) or None, phase (R,)
index of the active curve, and the experiment (curves, gains, graph, disturbance). The
bodies' metrics are record.body_metrics.
"""

from collections.abc import Sequence
import math
from typing import Any

import numpy as np

from curve_formation.core.base.shapes import BoolArray, FloatArray, IntArray
from curve_formation.core.controller.estop import stopped_time
from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.formation.curves import Curve
from curve_formation.core.formation.dynamics import offset_points
from curve_formation.core.record.body_metrics import body_metrics, closest_approach


def strict_json(data: Any) -> str:
    """JSON text of a metrics dict: every number that is not finite becomes null (JSON has no
    NaN or Infinity; a bare NaN would make the file unreadable by strict parsers).
    """
    import json

    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {key: clean(v) for key, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, (float, np.floating)):
            return float(value) if np.isfinite(value) else None
        if isinstance(value, np.integer):
            return int(value)
        if isinstance(value, np.bool_):
            return bool(value)
        if isinstance(value, np.ndarray):
            return clean(value.tolist())
        return value
    return json.dumps(clean(data), indent=2, allow_nan=False) + '\n'


def finite_or_none(value: float) -> float | None:
    """value as a float, or None when it is NaN or infinite (JSON has no NaN)."""
    value = float(value)
    return value if np.isfinite(value) else None


def target_errors(poses: FloatArray, phase: IntArray, experiment: Any, gains: Gains | None = None,
                  t: FloatArray | None = None, stamps: FloatArray | None = None) -> FloatArray:
    """(R, n, 2) e_i = xb_i - G(s_i) xi of the active curve (offset l from gains; the point
    steered, steered_points).

    t (R,) s: the sample times, needed when a phase's targets were re-assigned on the way
    (Phase.changes) or move; stamps (R, n) s: when each pose was taken (same clock as t), so
    that a pose is measured against its moving target at that time (see sample_targets).
    """
    gains = experiment.gains if gains is None else gains
    targets = sample_targets(experiment, phase, t, stamps)
    return steered_points(poses, targets, gains) - targets


def steered_points(poses: FloatArray, targets: FloatArray, gains: Gains) -> FloatArray:
    """(R, n, 2) the points the robots steer to their targets (R, n, 2; m, arena frame):
    xb, offset l ahead of the axle.

    With gains.reverse a robot may steer the point behind its axle instead
    (driving.drive_direction): the nearer of its two offset points to its target is taken.
    The two are 2 |l| apart and the law brings the steered one onto the target, so once a
    robot is within |l| of its target this is the steered point.
    """
    points = offset_points(poses, gains.offset)
    if gains.reverse:
        behind = offset_points(poses, -gains.offset)
        nearer = (np.linalg.norm(behind - targets, axis=-1)
                  < np.linalg.norm(points - targets, axis=-1))
        points = np.where(nearer[..., None], behind, points)
    return points


def sample_targets(experiment: Any, phase: IntArray, t: FloatArray | None = None,
                   stamps: FloatArray | None = None) -> FloatArray:
    """(R, n, 2) every agent's target at each sample: its phase's, as re-assigned by then,
    and carried with its curve in a moving phase, to the time its pose was taken.

    The one place where a run's targets are placed in time, for the simulator, the live
    monitor and the bag alike: t (R,) s since t = 0 (the curve's own time: the first curve's
    arrival); stamps (R, n) s on the same clock, when each pose was taken (NaN: unknown, or
    more than MAX_STAMP_GAP from its sample, a clock that disagrees: the sample time is used).
    A pose up to a camera frame old, measured against where its target is at the sample
    time, reads a robot on a curve moving at 1 cm/s as 0.3 mm behind.
    """
    targets = np.stack([p.targets for p in experiment.phases])[np.asarray(phase)]
    for k, p in enumerate(experiment.phases):
        if (p.changes or p.motion is not None) and t is None:
            raise ValueError('targets were re-assigned or move: the sample times are needed')
        for when, _, points in p.changes:
            targets[(phase == k) & (np.asarray(t) >= when)] = points
        if p.motion is not None:
            assert t is not None   # refused above without it
            for r in np.flatnonzero(phase == k):
                taus = np.full(targets.shape[1], t[r] - p.start)
                if stamps is not None:
                    taken = np.asarray(stamps[r], float)
                    usable = np.isfinite(taken) & (np.abs(taken - t[r]) <= MAX_STAMP_GAP)
                    taus = np.where(usable, taken - p.start, taus)
                targets[r] = p.motion.points_each(targets[r], taus)
    return targets


# Longest a pose's stamp may be from its sample time (s) and still date it: further apart,
# the pose's clock is not the run's (another host without time sync).
MAX_STAMP_GAP = 0.5


def error_norm(errors: FloatArray) -> FloatArray:
    """(R,) ||xb_e|| over all agents."""
    return np.linalg.norm(errors.reshape(len(errors), -1), axis=1)


def lyapunov(errors: FloatArray, dhat: FloatArray | None, experiment: Any,
             disturbance: FloatArray | None = None, gains: Gains | None = None) -> FloatArray:
    """(R,) the Lyapunov function of the run's law (docs/control-laws.md).

    paper, adaptive: V = xe^T (P kron I2) xe + sum_i p_i dtilde_i^T Gamma^-1 dtilde_i with
    dtilde = dhat - d / k2 and Gamma the per-channel adaptation gains (identity for paper).
    observer: W = xe^T (P kron I2) xe + c |k2 dtilde|^2 with
    c = 2 p_max^2 max(1, l^2) / (k1 q_min lambda), q_min the smallest eigenvalue of Q.
    With k2 = 0 the estimate is off and each is the error term alone.
    """
    gains = experiment.gains if gains is None else gains
    certificate = experiment.graph.certificate()
    weights = np.diag(certificate.P)
    value = np.einsum('i,rij,rij->r', weights, errors, errors)
    if gains.k2 > 0 and dhat is not None:
        d = experiment.disturbance if disturbance is None else disturbance
        tilde = dhat - np.asarray(d) / gains.k2
        if gains.law == 'observer':
            c = (2 * weights.max() ** 2 * max(1.0, gains.offset ** 2)
                 / (gains.k1 * certificate.min_eig_Q * gains.observer_rate))
            value = value + c * gains.k2 ** 2 * np.einsum('rij,rij->r', tilde, tilde)
        else:
            scaled = tilde / np.asarray(gains.estimator_gains())
            value = value + np.einsum('i,rij,rij->r', weights, tilde, scaled)
    return value


# A phase settles only if its error stays below the tolerance for at least this long before
# the phase (or the run) ends: SETTLE_HOLD s, or SETTLE_HOLD_SHARE of a shorter phase. A
# norm that ripples about the tolerance and dips below it in the last samples has not settled.
SETTLE_HOLD = 5.0


SETTLE_HOLD_SHARE = 0.1


def settle_time(t: FloatArray, norm: FloatArray, tolerance: float, start: float, end: float,
                hold: float = 0.0) -> float | None:
    """Time after `start` (s) from which norm stays below tolerance until `end`, else None;
    None also if it stays there less than `hold` s before the window's last sample.

    Only samples in [start, end) count; None also when the window has no sample.
    """
    window = (t >= start) & (t < end)
    if not window.any():
        return None
    # NaN compares false: a sample whose error is not finite counts as not settled.
    above = np.flatnonzero(~(norm[window] < tolerance))
    times = t[window]
    if above.size == 0:
        return float(times[0] - start)
    if above[-1] == len(times) - 1 or times[-1] - times[above[-1] + 1] < hold:
        return None
    return float(times[above[-1] + 1] - start)


def settle_hold(start: float, end: float) -> float:
    """How long (s) a phase observed from `start` to `end` (s) must stay settled."""
    return min(SETTLE_HOLD, SETTLE_HOLD_SHARE * max(end - start, 0.0))


def estop_hold(intervals: Sequence[tuple[float, float | None]], start: float, end: float
               ) -> float:
    """When a phase [start, end) (s) was last released from an e-stop: -inf if no e-stop
    interval overlaps it, inf if one still holds at its end, else the last release time.
    """
    last = -math.inf
    for a, b in intervals:
        if a >= end or (b is not None and b <= start):
            continue
        if b is None or b >= end:
            return math.inf
        last = max(last, b)
    return last


def orientation_rates(t: FloatArray, poses: FloatArray, window: float = 1.0) -> FloatArray:
    """(n,) mean heading rates (rad/s) over the last `window` seconds."""
    last = t >= t[-1] - window
    heading = np.unwrap(poses[last, :, 2], axis=0)
    span = t[last][-1] - t[last][0]
    return (heading[-1] - heading[0]) / span if span > 0 else np.zeros(poses.shape[1])


def arc_coordinates(curve: Curve, points: FloatArray, count: int = 4000
                    ) -> tuple[FloatArray, float]:
    """Arc-length coordinate (units of c) of the nearest curve point to each of points (m, 2)."""
    s_table, length = curve.arc_length_table(count)
    dense = curve.points(s_table)
    nearest = np.argmin(np.linalg.norm(points[:, None, :] - dense[None], axis=2), axis=1)
    return length[nearest], length[-1]


def spacing_uniformity(curve: Curve, points: FloatArray) -> dict[str, float]:
    """Gaps in arc length between consecutive agents along the curve.

    Returns {'cv': std/mean of the gaps, 'min_over_max': smallest/largest gap}; closed curves
    include the gap that wraps around.
    """
    coords, total = arc_coordinates(curve, points)
    order = np.sort(coords)
    gaps = np.diff(np.append(order, order[0] + total) if curve.basis.closed else order)
    if len(gaps) == 0 or gaps.max() <= 0:
        return {'cv': float('nan'), 'min_over_max': float('nan')}
    return {'cv': float(gaps.std() / gaps.mean()),
            'min_over_max': float(gaps.min() / gaps.max())}


def peak_speeds(commands: FloatArray | None, wheel_base: float) -> dict[str, float]:
    """Peak |v|, |w| and, with a wheel base, peak wheel speed of the sent commands."""
    if commands is None or len(commands) == 0:
        return {}
    v, w = commands[..., 0], commands[..., 1]
    out = {'peak_v': float(np.abs(v).max()), 'peak_w': float(np.abs(w).max())}
    if wheel_base:
        out['peak_wheel_speed'] = float((np.abs(v) + 0.5 * wheel_base * np.abs(w)).max())
    return out


def run_metrics(experiment: Any, t: FloatArray, poses: FloatArray, phase: IntArray,
                dhat: FloatArray | None = None, commands: FloatArray | None = None,
                tolerance: float | None = None, gains: Gains | None = None,
                disturbance: FloatArray | None = None, limits: WheelLimits | None = None,
                contacts: dict[str, Any] | None = None, unseen: BoolArray | None = None,
                estops: Sequence[tuple[float, float | None]] | None = None,
                deaths: Sequence[Any] = (), stamps: FloatArray | None = None
                ) -> dict[str, Any]:
    """All metrics of a run as a JSON-ready dict (one entry per curve phase).

    gains, disturbance and limits default to the experiment's; pass the ones the run used
    (disturbance: (n, 2), or (R, n, 2) at each sample where it varies).
    contacts, unseen: see body_metrics (experiments with bodies or avoidance).
    estops: [(start, stop or None)] (s) while the e-stop held robots (core.controller.estop): a
    phase
    they interrupt settles only after the release, and not at all if still held at its end.
    deaths: [(t s or None (before t = 0), node, how)] of the run's nodes that died: a phase
    that ends after one is never settled (it lost a robot or a node that drives them).
    stamps (R, n): when each pose was taken (sample_targets).
    """
    tolerance = experiment.spec.metrics.tolerance if tolerance is None else tolerance
    gains = experiment.gains if gains is None else gains
    if disturbance is None:   # at each sample where it varies
        disturbance = (experiment.disturbance_at(t) if experiment.variations
                       else experiment.disturbance)
    disturbance = np.asarray(disturbance, float)
    d_first, d_last = ((disturbance[:1], disturbance[-1:]) if disturbance.ndim == 3
                       else (disturbance, disturbance))
    limits = experiment.limits if limits is None else limits
    targets = sample_targets(experiment, phase, t, stamps)
    points = steered_points(poses, targets, gains)
    errors = points - targets
    norm = error_norm(errors)
    ends = [p.start for p in experiment.phases[1:]] + [float('inf')]
    phases = []
    for p, end in zip(experiment.phases, ends, strict=True):
        window = (t >= p.start) & (t < end)
        if not window.any():
            continue
        size = p.curve.size()
        last = np.flatnonzero(window)[-1]
        agent_err = np.linalg.norm(errors[last], axis=1)
        held = estop_hold(estops or (), p.start, min(end, float(t[-1])))
        settle = None
        lost = [(when, node) for when, node, _ in deaths if when is None or when < end]
        if held != math.inf and not lost:
            begin = max(p.start, held)
            settle = settle_time(t, norm, tolerance * size, begin, end,
                                 settle_hold(begin, min(end, float(t[-1]))))
            settle = None if settle is None else settle + max(held - p.start, 0.0)
        finite = bool(np.isfinite(norm[window]).all())
        phases.append({
            'index': p.index, 'start': p.start, 'curve_size': size,
            'basis': p.curve.basis.describe(),
            'fit_rms_residual': finite_or_none(p.fit.rms_residual),
            'tolerance': tolerance * size, 'settled': settle is not None,
            'settle_time': settle,
            'not_settled_because': None if settle is not None else (
                'node {} died {}'.format(lost[0][1], 'before t = 0' if lost[0][0] is None
                                         else f'at t = {lost[0][0]:.1f} s') if lost
                else 'the e-stop was engaged at the end of the phase' if held == math.inf
                else 'the error is not finite (NaN or infinite)' if not finite
                else 'the error does not stay below the tolerance (for '
                f'{settle_hold(max(p.start, held), min(end, float(t[-1]))):g} s before the '
                'end of the phase)'),
            'interrupted_by_estop': held > -math.inf,
            'initial_error_norm': float(norm[window][0]),
            'final_error_norm': float(norm[last]),
            'final_max_agent_error': float(agent_err.max()),
            'spacing': spacing_uniformity(p.curve if p.motion is None else
                                          p.motion.curve(p.curve, t[last] - p.start),
                                          points[last]),
            'target_spacing': spacing_uniformity(p.curve, p.targets),
            'reassignments': len(p.changes),
        })
    cert = experiment.graph.certificate()
    out = {
        'experiment': experiment.name, 'agents': experiment.n,
        'theorem1_min_eig': {'P': cert.min_eig_P, 'Q': cert.min_eig_Q},
        'duration': float(t[-1]), 'phases': phases,
        'final_error_norm': float(norm[-1]),
        'final_orientation_rates_max': float(np.abs(orientation_rates(t, poses)).max()),
        'lyapunov_initial': float(lyapunov(errors[:1], None if dhat is None else dhat[:1],
                                           experiment, d_first, gains)[0]),
        'lyapunov_final': float(lyapunov(errors[-1:], None if dhat is None else dhat[-1:],
                                         experiment, d_last, gains)[0]),
        'all_settled': all(p['settled'] for p in phases),
        'closest_approach': closest_approach(poses)[0],
    }
    if estops is not None:
        out['estop'] = {'intervals': [[a, b] for a, b in estops],
                        'stopped_for': stopped_time(estops, float(t[-1]))}
    if dhat is not None and gains.k2 > 0:
        target = d_last.reshape(-1, experiment.n, 2)[-1] / gains.k2
        out['final_estimate_error_max'] = float(np.linalg.norm(dhat[-1] - target, axis=1).max())
    out.update(peak_speeds(commands, limits.wheel_base))
    if experiment.radius > 0 or experiment.avoidance.on:
        out['bodies'] = body_metrics(experiment, t, poses, contacts, unseen)
    return out


def result_metrics(result: Any, tolerance: float | None = None) -> dict[str, Any]:
    """run_metrics for a simulator.SimResult."""
    out = run_metrics(result.experiment, result.t, result.poses, result.phase, result.dhat,
                      result.commands, tolerance, result.gains, result.disturbance,
                      result.limits, contacts=result.contacts)
    out['control'] = ('continuous' if result.rate_hz is None
                      else f'zero-order hold at {result.rate_hz:g} Hz')
    if result.experiment.spec.controller.estimate_latency and result.latencies is not None:
        out['estimated_latency'] = [float(v) for v in result.latencies]
    if result.motor_lags is not None:
        out['estimated_motor_time_constant'] = [float(v) for v in result.motor_lags]
    if result.wheel_gains is not None:
        out['estimated_wheel_gains'] = [None if g is None else [float(g[0]), float(g[1])]
                                        for g in result.wheel_gains]
    if result.dead_bands is not None:
        out['estimated_dead_band'] = [None if b is None else float(b)
                                      for b in result.dead_bands]
    if result.estimates is not None:   # as a ROS run's (its controllers' /diagnostics)
        out['robot_estimates'] = {f'robot_{i + 1}': e for i, e in enumerate(result.estimates)}
    return out


def ground_truth_metrics(experiment: Any, data: dict[str, Any], phase: IntArray,
                         law_pose_rms: float | None = None,
                         estops: Sequence[tuple[float, float | None]] | None = None,
                         deaths: Sequence[Any] = ()) -> dict[str, Any]:
    """With a camera: the formation measured on the fake robots' true poses, how far the
    tracked poses (as last received, up to a frame and its latency old) were from them, and
    law_pose_rms (m): the RMS over every tick of every robot of how far the pose its law used
    (carried forward to the tick with predict_pose) was from the truth at that tick. estops,
    deaths: as run_metrics.
    """
    truth = data['true_poses']
    seen = np.isfinite(truth).all(axis=2) & np.isfinite(data['poses']).all(axis=2)
    gap = np.linalg.norm(data['poses'][..., :2] - truth[..., :2], axis=2)[seen]
    turn = np.abs(np.angle(np.exp(1j * (data['poses'][..., 2] - truth[..., 2]))))[seen]
    out = run_metrics(experiment, data['t'], truth, phase, estops=estops, deaths=deaths)
    return {'final_error_norm': out['final_error_norm'],
            'phases': [{k: p[k] for k in ('settled', 'settle_time', 'final_error_norm')}
                       for p in out['phases']],
            'tracked_vs_true_position_rms': float(np.sqrt(np.mean(gap ** 2))),
            'tracked_vs_true_heading_rms_deg': float(np.degrees(np.sqrt(np.mean(turn ** 2)))),
            'law_pose_vs_true_position_rms': law_pose_rms}
