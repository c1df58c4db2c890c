"""Batch simulator: n unicycles with constant input disturbance under the formation law.

Two control modes:
- continuous: the law is evaluated at every RK4 stage and the estimator is integrated with the
  robots (the paper's setting);
- zero-order hold at `rate_hz`: the law is evaluated once per control period from the latest
  poses, its estimator advanced by one Euler step (the observer: by one filter step from the
  motion over the period just ended), and the command held while the robots are integrated
  exactly over each fine step dt, which is what the ROS controller nodes do.

Laws (core.control.LAWS): paper, adaptive (per-channel estimator gains), observer.

The stepping loop is compiled with numba; it calls the same per-agent functions as the ROS
controller (core.control), and its cost is linear in agents plus edges.
"""

from dataclasses import dataclass
import hashlib
import math
from pathlib import Path
import types

import numba
import numpy as np

from curve_formation.core import control, dynamics, metrics


def drop_stale_cache(folder=Path(__file__).parent):
    """Delete numba's compiled cache when control.py, dynamics.py or this file changed.

    numba checks a cached function against its own source file only, not against the
    functions it compiled in from other modules: after an edit of control.py the stepping loop
    would run the old law. Installed copies never change; an unwritable cache is left alone.
    """
    sources = b''.join((folder / name).read_bytes()
                       for name in ('control.py', 'dynamics.py', 'simulator.py'))
    digest = hashlib.sha256(sources).hexdigest()
    cache = folder / '__pycache__'
    stamp = cache / 'simulator.sources.sha256'
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        for path in cache.glob('*.nb[ic]'):
            path.unlink()
        cache.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        return False
    return True


drop_stale_cache()


def _jit(function, **callees):
    """numba-compile a core function, with the core functions it calls compiled as well."""
    scope = dict(function.__globals__, **callees)
    copy = types.FunctionType(function.__code__, scope, function.__name__,
                              function.__defaults__)
    return numba.njit(cache=True)(copy)


_agent_input = _jit(control.agent_input,
                    sampled_feedback=numba.njit(cache=True)(control.sampled_feedback))
_saturate = numba.njit(cache=True)(control.saturate)
_observer_input = _jit(control.observer_input, agent_input=_agent_input, saturate=_saturate)
_arc = _jit(dynamics.arc_step, chord_ratio=numba.njit(cache=True)(dynamics.chord_ratio))
_observer_step = numba.njit(cache=True)(control.observer_step)
OBSERVER = control.LAWS['observer']

# Largest heading change (rad) of one RK4 substep in continuous mode.
MAX_TURN_PER_SUBSTEP = 0.05


@numba.njit(cache=True)
def _controls(poses, dhat, targets, tgt, src, wts, pins, law, k1, k2, offset, gamma_v, gamma_w,
              period, observer_rate, on_pc, d_pc, d_robot, wheel_base, vmax, wmax, err, fb,
              motion, cmd, ref, ddhat):
    """Evaluate the law for all agents: fills err, fb, cmd (sent), motion (actual), ref, ddhat.

    d_pc (n, 2) is added to the command before the wheel limits (injected on the PC),
    d_robot (n, 2) after them (physical). ref is what the observer compares the motion with:
    the law's command where the disturbance enters (before the limits when on_pc, after them
    otherwise); ddhat the continuous-time estimator rate.
    """
    n = poses.shape[0]
    for i in range(n):
        err[i, 0] = poses[i, 0] + offset * math.cos(poses[i, 2]) - targets[i, 0]
        err[i, 1] = poses[i, 1] + offset * math.sin(poses[i, 2]) - targets[i, 1]
        fb[i, 0] = pins[i] * err[i, 0]
        fb[i, 1] = pins[i] * err[i, 1]
    for k in range(tgt.shape[0]):
        i = tgt[k]
        j = src[k]
        fb[i, 0] += wts[k] * (err[i, 0] - err[j, 0])
        fb[i, 1] += wts[k] * (err[i, 1] - err[j, 1])
    for i in range(n):
        if law == OBSERVER:
            u_v, u_w = _observer_input(fb[i, 0], fb[i, 1], poses[i, 2], dhat[i, 0], dhat[i, 1],
                                       k1, k2, offset, period, wheel_base, vmax, wmax)
            ddv = 0.0
            ddw = 0.0
        else:
            u_v, u_w, ddv, ddw = _agent_input(fb[i, 0], fb[i, 1], err[i, 0], err[i, 1],
                                              poses[i, 2], dhat[i, 0], dhat[i, 1], k1, k2,
                                              offset, gamma_v, gamma_w, period)
        v, w = _saturate(u_v + d_pc[i, 0], u_w + d_pc[i, 1], wheel_base, vmax, wmax)
        motion[i, 0] = v + d_robot[i, 0]
        motion[i, 1] = w + d_robot[i, 1]
        cmd[i, 0] = v
        cmd[i, 1] = w
        # On the robot the disturbance enters after the limits, so ref is the command sent.
        ref[i, 0] = u_v if on_pc else v
        ref[i, 1] = u_w if on_pc else w
        if law == OBSERVER and k2 != 0.0:   # k2 = 0: estimator off
            ddv = observer_rate * ((motion[i, 0] - ref[i, 0]) / k2 - dhat[i, 0])
            ddw = observer_rate * ((motion[i, 1] - ref[i, 1]) / k2 - dhat[i, 1])
        ddhat[i, 0] = ddv
        ddhat[i, 1] = ddw


@numba.njit(cache=True)
def _arc_step(poses, motion, dt):
    """Exact unicycle motion over dt with constant (v, w) per agent."""
    for i in range(poses.shape[0]):
        poses[i, 0], poses[i, 1], poses[i, 2] = _arc(poses[i, 0], poses[i, 1], poses[i, 2],
                                                     motion[i, 0], motion[i, 1], dt)


@numba.njit(cache=True)
def _run(poses, dhat, targets, tgt, src, wts, pins, law, k1, k2, offset, gamma_v, gamma_w,
         period, observer_rate, on_pc, d_pc, d_robot, wheel_base, vmax, wmax, dt, step0, steps,
         control_every, record_every, motion, cmd, ref, tick_offsets, start_steps, rec_poses,
         rec_dhat, rec_cmd):
    """Advance poses (n, 3) and dhat (n, 2) in place by `steps` fine steps from `step0`.

    motion, cmd and ref (n, 2) hold the zero-order-hold command across calls; agent i ticks
    at the steps where (step - tick_offsets[i]) % control_every == 0, from step start_steps[i]
    on. With the observer, a tick first updates dhat from the motion over the period just
    ended (exact here: the held motion is what the pose difference would measure).
    """
    n = poses.shape[0]
    err = np.zeros((n, 2))
    fb = np.zeros((n, 2))
    ddhat = np.zeros((n, 2))
    if control_every > 0:
        dt_control = control_every * dt
        blend = 1.0 - math.exp(-observer_rate * dt_control)
        new_motion = np.zeros((n, 2))
        new_cmd = np.zeros((n, 2))
        new_ref = np.zeros((n, 2))
        for step in range(step0, step0 + steps):
            ticking = False
            for i in range(n):
                if (step - tick_offsets[i]) % control_every == 0:
                    ticking = True
                    if law == OBSERVER and step >= start_steps[i]:
                        dhat[i, 0], dhat[i, 1] = _observer_step(
                            dhat[i, 0], dhat[i, 1], motion[i, 0], motion[i, 1], ref[i, 0],
                            ref[i, 1], k2, blend)
            if ticking:
                _controls(poses, dhat, targets, tgt, src, wts, pins, law, k1, k2, offset,
                          gamma_v, gamma_w, period, observer_rate, on_pc, d_pc, d_robot,
                          wheel_base, vmax, wmax, err, fb, new_motion, new_cmd, new_ref, ddhat)
                for i in range(n):
                    if step < start_steps[i]:
                        continue   # not started yet: motors off, estimator idle
                    if (step - tick_offsets[i]) % control_every == 0:
                        motion[i, 0] = new_motion[i, 0]
                        motion[i, 1] = new_motion[i, 1]
                        cmd[i, 0] = new_cmd[i, 0]
                        cmd[i, 1] = new_cmd[i, 1]
                        ref[i, 0] = new_ref[i, 0]
                        ref[i, 1] = new_ref[i, 1]
                        if law != OBSERVER:
                            dhat[i, 0] += dt_control * ddhat[i, 0]
                            dhat[i, 1] += dt_control * ddhat[i, 1]
            if step % record_every == 0:
                r = step // record_every
                rec_poses[r] = poses
                rec_dhat[r] = dhat
                rec_cmd[r] = cmd
            _arc_step(poses, motion, dt)
        return
    # Continuous control: RK4 on (poses, dhat) with the law evaluated at every stage. The
    # heading turns at up to k1 |e| / l (1000 rad/s at the paper's start), so each step is
    # split into substeps that turn at most MAX_TURN_PER_SUBSTEP.
    kp = np.zeros((4, n, 3))
    kd = np.zeros((4, n, 2))
    p_stage = np.zeros((n, 3))
    d_stage = np.zeros((n, 2))
    for step in range(step0, step0 + steps):
        _controls(poses, dhat, targets, tgt, src, wts, pins, law, k1, k2, offset, gamma_v,
                  gamma_w, 0.0, observer_rate, on_pc, d_pc, d_robot, wheel_base, vmax, wmax,
                  err, fb, motion, cmd, ref, ddhat)
        if step % record_every == 0:
            r = step // record_every
            rec_poses[r] = poses
            rec_dhat[r] = dhat
            rec_cmd[r] = cmd
        fastest = 0.0
        for i in range(n):
            fastest = max(fastest, abs(motion[i, 1]))
        substeps = max(1, int(math.ceil(fastest * dt / MAX_TURN_PER_SUBSTEP)))
        h = dt / substeps
        for _ in range(substeps):
            for stage in range(4):
                frac = 0.0 if stage == 0 else (h if stage == 3 else 0.5 * h)
                for i in range(n):
                    for c in range(3):
                        p_stage[i, c] = poses[i, c] + frac * kp[stage - 1, i, c]
                    for c in range(2):
                        d_stage[i, c] = dhat[i, c] + frac * kd[stage - 1, i, c]
                _controls(p_stage, d_stage, targets, tgt, src, wts, pins, law, k1, k2,
                          offset, gamma_v, gamma_w, 0.0, observer_rate, on_pc, d_pc, d_robot,
                          wheel_base, vmax, wmax, err, fb, motion, cmd, ref, ddhat)
                for i in range(n):
                    kp[stage, i, 0] = motion[i, 0] * math.cos(p_stage[i, 2])
                    kp[stage, i, 1] = motion[i, 0] * math.sin(p_stage[i, 2])
                    kp[stage, i, 2] = motion[i, 1]
                    kd[stage, i, 0] = ddhat[i, 0]
                    kd[stage, i, 1] = ddhat[i, 1]
            for i in range(n):
                for c in range(3):
                    poses[i, c] += h / 6.0 * (kp[0, i, c] + 2.0 * kp[1, i, c]
                                              + 2.0 * kp[2, i, c] + kp[3, i, c])
                for c in range(2):
                    dhat[i, c] += h / 6.0 * (kd[0, i, c] + 2.0 * kd[1, i, c]
                                             + 2.0 * kd[2, i, c] + kd[3, i, c])


@dataclass
class SimResult:
    """Recorded time series.

    t: (R,) s.  poses: (R, n, 3) x, y, theta (arena frame).  dhat: (R, n, 2) estimates.
    commands: (R, n, 2) (v, w) sent to the robots (after limits; with an on_pc disturbance it
    includes d).  phase: (R,) index of the active curve.  gains, limits, disturbance (n, 2):
    the settings the run used (the experiment's unless overridden).
    """

    experiment: object
    rate_hz: object
    gains: object
    limits: object
    disturbance: np.ndarray
    t: np.ndarray
    poses: np.ndarray
    dhat: np.ndarray
    commands: np.ndarray
    phase: np.ndarray

    @property
    def errors(self):
        """(R, n, 2) target errors e_i = xb_i - G(s_i) xi of the active curve."""
        return metrics.target_errors(self.poses, self.phase, self.experiment, self.gains)

    @property
    def error_norm(self):
        """(R,) ||xb_e||, the norm of all agents' stacked errors."""
        return metrics.error_norm(self.errors)

    @property
    def lyapunov(self):
        """(R,) the paper's Lyapunov function V with the run's gains and disturbance."""
        return metrics.lyapunov(self.errors, self.dhat, self.experiment, self.disturbance,
                                self.gains)


def simulate(experiment, rate_hz='config', duration=None, dt=None, record_dt=None,
             disturbance=None, gains=None, limits=None, initial_poses=None, tick_phases=None,
             start_delays=None):
    """Simulate an Experiment; keyword arguments override the file's settings.

    rate_hz: 'config' (the file's controller.rate_hz), None (continuous) or a rate (Hz).
    tick_phases: (n,) fractions in [0, 1) of a control period by which each agent's ticks lag
    (unsynchronised controllers, as the ROS nodes run); default all 0 (synchronous).
    start_delays: (n,) s before each agent's controller starts (zero-order hold only), as
    followers wait for news of the leader; default all 0.
    Returns a SimResult.
    """
    spec = experiment.spec
    rate_hz = spec.controller.rate_hz if rate_hz == 'config' else rate_hz
    duration = spec.simulation.duration if duration is None else duration
    dt = spec.simulation.dt if dt is None else dt
    record_dt = spec.simulation.record_dt if record_dt is None else record_dt
    gains = experiment.gains if gains is None else gains
    limits = experiment.limits if limits is None else limits
    dist = experiment.disturbance if disturbance is None else np.asarray(disturbance, float)
    dist = np.broadcast_to(dist, (experiment.n, 2)).astype(float)
    on_pc = experiment.spec.disturbance.injected == 'on_pc'
    d_pc, d_robot = (dist, np.zeros_like(dist)) if on_pc else (np.zeros_like(dist), dist)
    poses = np.array(experiment.initial_poses if initial_poses is None else initial_poses,
                     dtype=float)
    record_every = _ratio(record_dt, dt, 'record_dt')
    control_every = 0 if rate_hz is None else _ratio(1.0 / rate_hz, dt, 'control period')
    phases = np.zeros(experiment.n) if tick_phases is None else np.asarray(tick_phases, float)
    tick_offsets = np.floor(phases * max(control_every, 1)).astype(np.int64)
    delays = np.zeros(experiment.n) if start_delays is None else np.asarray(start_delays, float)
    start_steps = np.round(delays / dt).astype(np.int64)
    total = int(round(duration / dt))
    n_rec = (total - 1) // record_every + 1
    rec_poses = np.zeros((n_rec, experiment.n, 3))
    rec_dhat = np.zeros((n_rec, experiment.n, 2))
    rec_cmd = np.zeros((n_rec, experiment.n, 2))
    dhat = np.zeros((experiment.n, 2))
    motion = np.zeros((experiment.n, 2))
    cmd = np.zeros((experiment.n, 2))
    ref = np.zeros((experiment.n, 2))
    gamma_v, gamma_w = gains.estimator_gains()
    tgt, src, wts = experiment.graph.edge_arrays()
    starts = [int(round(p.start / dt)) for p in experiment.phases] + [total]
    for phase, a, b in zip(experiment.phases, starts[:-1], starts[1:], strict=True):
        if a >= total:
            break
        _run(poses, dhat, np.ascontiguousarray(phase.targets), tgt, src, wts,
             experiment.graph.pins, gains.law_code, gains.k1, gains.k2, gains.offset,
             gamma_v, gamma_w, gains.hold_period(rate_hz), gains.observer_rate, on_pc, d_pc,
             d_robot, limits.wheel_base, limits.max_wheel_speed, limits.max_angular_rate, dt, a,
             min(b, total) - a, control_every, record_every, motion, cmd, ref, tick_offsets,
             start_steps, rec_poses, rec_dhat, rec_cmd)
    t = np.arange(n_rec) * record_every * dt
    phase_index = np.searchsorted(np.array(starts[1:-1]) * dt, t, side='right')
    return SimResult(experiment, rate_hz, gains, limits, dist, t, rec_poses, rec_dhat, rec_cmd,
                     phase_index)


def _ratio(interval, dt, what):
    steps = interval / dt
    if abs(steps - round(steps)) > 1e-6 * max(1.0, steps) or round(steps) < 1:
        raise ValueError(f'{what} ({interval} s) must be a whole multiple of dt ({dt} s)')
    return int(round(steps))
