"""The motor check's fits (core.controller.motor_probe): each wheel's gain, drift, the
delay and the motors' lag from the sweep (fit_sweep), the dead band from a pass of the
crossings (pass_band), and each wheel's gain and its standard error again over the whole
check (check_gains). Speeds across a gap in the poses are not measured (held_up).

A wheel's speed is measured from the poses over SPAN s (spans: the forward speed -+ half the
wheel base times the turn rate) and modelled as its gain times its command plus a drift (a
disturbance added on the robot, as firmware adds it), zero while that lies within the band
(a hard cut-off, as the MuJoCo motors have it). Times in s (one clock for commands and
poses), speeds in m/s of rim.
"""

from dataclasses import dataclass
import math

import numpy as np

from curve_formation.core.base.shapes import BoolArray, FloatArray, IntArray
from curve_formation.core.controller import motion_record as record
from curve_formation.core.controller.wheel_estimate import gain_fit
from curve_formation.core.formation.dynamics import wheel_speeds


BAND_MAX = 0.25        # largest band sought, a share of the fastest wheel speed
BAND_STEP = 0.002      # the band grid's step, a share of the fastest wheel speed
COARSE = 5             # band steps in a step of the first, coarse, grid
TIE = 0.02             # share of the best fit's squares within which bands fit alike
DELAYS = np.arange(0.0, 0.505, 0.01)    # s: latency and pose age sought
LAGS = np.arange(0.0, 0.1205, 0.01)      # s: motor lags sought in the sweep's fit
MOVING = 0.2           # share of U from which a wheel's measured speed counts as moving
SHIFTS = np.arange(-0.1, 0.1001, 0.005)  # s: a pass's model's shift in time, left free
MIN_SAMPLES = 20
SPAN = 0.15            # s: the shortest interval a wheel's speed is measured over
FINE = 0.002           # s: the time step of a pass's model
DRIFT_POINTS = 4       # fewest measures of a drift a line is fitted through
CLEAR = 0.25           # s a wheel moves clear of the band before it is fitted (its motor's lag)
HELD = 2.5             # pose intervals over this many times their median: a process held up
DRIFT_KNOTS = 4.0      # s between the knots of the whole check's drift (a cubic spline)
MOVING_CHECK = 0.08    # share of the fastest wheel speed from which a wheel moves, band aside
BEYOND = 1.2           # times the band a modelled wheel's command clears it by


@dataclass(frozen=True)
class SweepFit:
    """The sweep's fit: delay, lag (s), gains (2,), drift (2, 2: each wheel's a line in time
    about `at`: its value and rate, m/s and m/s^2), residual (rms m/s).
    """

    delay: float
    lag: float
    gains: FloatArray
    drift: FloatArray
    at: float
    residual: float

    def drift_at(self, k: int, t: FloatArray) -> FloatArray:
        """Wheel k's drift (m/s, as a command) at times t (s)."""
        return self.drift[k, 0] + self.drift[k, 1] * (t - self.at)


def spans(tp: FloatArray, poses: FloatArray, wheel_base: float, span: float = SPAN
          ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(starts, ends, speeds (2, n)): each wheel's mean rim speed (m/s) from each pose to the
    first at least `span` s later (overlapping intervals: a camera's noise is in the poses,
    so a longer interval measures a speed better), but for those across a gap in the poses
    or starting within CLEAR s after one (held_up).
    """
    ends_at = np.searchsorted(tp, tp + span - 1e-9)
    first = np.flatnonzero(ends_at < len(tp))
    first = first[~held_up(tp, tp[first], tp[ends_at[first]])]
    pairs = np.empty(2 * len(first), dtype=int)
    pairs[0::2], pairs[1::2] = first, ends_at[first]
    with np.errstate(divide='ignore', invalid='ignore'):   # the gaps between pairs: dropped
        forward, turn = record.measured_rates(tp[pairs], poses[pairs])
    speeds = np.stack(wheel_speeds(forward[0::2], turn[0::2], wheel_base))
    return tp[first], tp[ends_at[first]], speeds


def pose_gaps(tp: FloatArray) -> IntArray:
    """The indices k of the steps tp[k] -> tp[k + 1] (s, in order) longer than HELD times
    their median: a process held up.
    """
    steps = np.diff(tp)
    if not len(steps):
        return np.zeros(0, dtype=int)
    return np.flatnonzero(steps > HELD * np.median(steps))


def held_up(tp: FloatArray, starts: FloatArray, ends: FloatArray) -> BoolArray:
    """Which intervals [starts, ends] (s) span a gap in the poses taken at tp (s, in order)
    longer than HELD times their median interval, or start within CLEAR s after one: a
    robot's process held up (its wheels go on with the command it had, then take the ones
    queued at once; a gap under motor_probe.GAP runs no sweep again), and its motors' lag
    after.
    """
    gap = pose_gaps(tp)
    if not len(gap):
        return np.zeros(len(starts), dtype=bool)
    before, after = tp[gap], tp[gap + 1]   # each gap's last pose before it, first after
    spanning = (ends[:, None] > before) & (starts[:, None] < after + CLEAR)
    return np.asarray(spanning.any(axis=1), dtype=bool)


def fit_sweep(tc: FloatArray, wheels: FloatArray, starts: FloatArray, ends: FloatArray,
              measured: FloatArray, amplitude: float) -> SweepFit | None:
    """Each wheel's gain and drift (a line in time) where it clearly moves, over the grid of
    delays and lags: tc (k,) command times, wheels (2, k) their wheel commands (m/s), the
    wheels' speeds measured (2, n) over [starts, ends] (n,). Where a wheel moves is first
    judged from its measured speed, then again from the first fit's model (a camera's noise
    would otherwise choose the samples).
    """
    first = _sweep_over_grid(tc, wheels, starts, ends, measured, amplitude, None)
    if first is None:
        return None
    return _sweep_over_grid(tc, wheels, starts, ends, measured, amplitude, first)


def _sweep_over_grid(tc: FloatArray, wheels: FloatArray, starts: FloatArray,
                     ends: FloatArray, measured: FloatArray, amplitude: float,
                     model: SweepFit | None) -> SweepFit | None:
    """fit_sweep's grid: each wheel moving where its measured speed (model None) or the
    model's is at least MOVING of the amplitude.
    """
    mid = 0.5 * (starts + ends)
    at = float(mid.mean()) if len(mid) else 0.0
    judged = (measured if model is None else
              np.stack([_modelled(model, k, tc, wheels[k], starts, ends, mid) for k in range(2)]))
    # clear of the band: moving, as measured, CLEAR s before and after (a motor's lag as it
    # leaves the band, an interval that ends in it: the fit has no band)
    clear = np.stack([moving_about(starts, np.abs(measured[k]) >= 0.5 * MOVING * amplitude,
                                   CLEAR) for k in range(2)])
    driven = record.driven_commands(wheels.T)
    n = len(starts)
    shifted_starts = (starts[None, :] - DELAYS[:, None]).ravel()   # every delay at once
    shifted_ends = (ends[None, :] - DELAYS[:, None]).ravel()
    best: tuple[float, float, float, FloatArray, FloatArray] | None = None
    for lag in LAGS:
        # the drift acts while driven: it too comes through the lag
        steady = (record.held_means(tc, driven, shifted_starts - 3.0 * lag, shifted_ends)
                  > 0.999).reshape(len(DELAYS), n)
        totals = np.zeros(len(DELAYS))
        coefs = np.zeros((2, len(DELAYS), 4))
        for k in range(2):
            means = record.lagged_means(tc, wheels[k], shifted_starts, shifted_ends,
                                        float(lag)).reshape(len(DELAYS), n)
            weight = ((np.abs(judged[k]) >= MOVING * amplitude) & clear[k] & steady).astype(float)
            count = weight.sum(axis=1)
            basis = np.stack([means, *np.broadcast_to(
                [np.ones(n), mid - at, np.sign(judged[k])], (len(DELAYS), 3, n)
            ).transpose(1, 0, 2)], axis=2)   # (delays, n, 4)
            target = measured[k]
            # least squares of each delay by its normal equations (4 unknowns)
            normal = np.einsum('dn,dni,dnj->dij', weight, basis, basis)
            projected = np.einsum('dn,dni,n->di', weight, basis, target)
            usable = count >= MIN_SAMPLES
            # the pseudo-inverse: a wheel that moved one way only has its sign column equal
            # to the constant one, whose share of the offset it leaves undecided
            coefs[k] = (np.linalg.pinv(normal, rcond=1e-12) @ projected[..., None])[..., 0]
            squares = weight @ (target * target) - np.einsum('di,di->d', coefs[k], projected)
            totals += np.where(usable, np.maximum(squares, 0.0) / np.maximum(count, 1.0),
                               math.inf)
        d = int(np.argmin(totals))
        if best is None or totals[d] < best[0]:
            gains = coefs[:, d, 0].copy()
            drift = np.zeros((2, 2))
            for k in range(2):
                drift[k] = coefs[k, d, 1:3] / gains[k] if gains[k] else 0.0
            best = (float(totals[d]), float(DELAYS[d]), float(lag), gains, drift)
    if best is None or not math.isfinite(best[0]) or min(best[3]) <= 0.0:
        return None
    return SweepFit(best[1], best[2], best[3], best[4], at, math.sqrt(best[0] / 2.0))


def moving_about(starts: FloatArray, moving: BoolArray, within: float) -> BoolArray:
    """Which intervals (their starts (n,), s, in order) moved, as did every interval that
    starts up to `within` s before or after them.
    """
    still = np.concatenate([[0], np.cumsum(~moving)])
    first = np.searchsorted(starts, starts - within)
    last = np.searchsorted(starts, starts + within, side='right')
    return moving & (still[last] - still[first] == 0)


def _modelled(model: SweepFit, k: int, tc: FloatArray, wheel: FloatArray, starts: FloatArray,
              ends: FloatArray, mid: FloatArray) -> FloatArray:
    """Wheel k's speeds (m/s) over the intervals as the sweep's fit has them (no band)."""
    means = record.lagged_means(tc, wheel, starts - model.delay, ends - model.delay,
                                model.lag)
    return model.gains[k] * (means + model.drift_at(k, mid))


def _lagged(u: FloatArray, step: float, lag: float) -> FloatArray:
    """u sampled every `step` s through a first-order lag of `lag` s (held between samples),
    starting at rest on u's first value.
    """
    if lag <= 0.0:
        return u
    # imported here: scipy.signal takes 0.3 s to import, for a motor check only
    from scipy.signal import lfilter
    keep = math.exp(-step / lag)
    return lfilter([1.0 - keep], [1.0, -keep], u, zi=[keep * u[0]])[0]


def drift_curve(points: FloatArray, at: FloatArray) -> FloatArray:
    """A wheel's drift (m/s) at times `at` (s) from the points (n, 2: s, m/s) measured
    about them: a quadratic through at least DRIFT_POINTS + 2, a line through fewer, at
    least 2, else their mean (0 without any).
    """
    if len(points) >= 2:
        degree = 2 if len(points) >= DRIFT_POINTS + 2 else 1
        origin = float(points[:, 0].mean())
        coef = np.polyfit(points[:, 0] - origin, points[:, 1], degree)
        return np.polyval(coef, at - origin)
    return np.full(len(at), float(points[:, 1].mean()) if len(points) else 0.0)


def pass_band(starts: FloatArray, ends: FloatArray, measured: FloatArray, gain: float,
              wheel: tuple[FloatArray, FloatArray], drift: FloatArray, delay: float,
              lag: float, max_wheel_speed: float) -> float | None:
    """The band (m/s) of one pass of one wheel: each interval's mean speed modelled as gain
    times its command (wheel: (command times, wheel commands), held, `delay` s late) plus
    its drift (drift_curve through the points `drift`), zero within the band, through the
    motors' `lag` (s); a small shift in time (SHIFTS) left free. measured (n,): the wheel's
    speeds over [starts, ends] (n,) within the pass.
    """
    if len(starts) < MIN_SAMPLES:
        return None
    fine = np.arange(starts[0] + SHIFTS[0] - 3.0 * lag - FINE, ends[-1] + SHIFTS[-1] + FINE,
                     FINE)
    times, commands = wheel
    held = commands[np.clip(np.searchsorted(times, fine - delay, side='right') - 1, 0, None)]
    motor = held + drift_curve(drift, fine)
    shifted_starts = (starts[None, :] - SHIFTS[:, None]).ravel()
    shifted_ends = (ends[None, :] - SHIFTS[:, None]).ravel()
    def squares(band: float) -> float:
        speed = gain * _lagged(np.where(np.abs(motor) < band, 0.0, motor), FINE, lag)
        area = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1])) * FINE])
        means = ((np.interp(shifted_ends, fine, area) - np.interp(shifted_starts, fine, area))
                 / (shifted_ends - shifted_starts)).reshape(len(SHIFTS), -1)
        return float(((means - measured[None, :]) ** 2).sum(axis=1).min())

    # a coarse grid (COARSE steps), then BAND_STEP steps across a coarse step either side
    top, step = BAND_MAX * max_wheel_speed, BAND_STEP * max_wheel_speed
    coarse = np.arange(0.0, top + 1e-12, COARSE * step)
    best = float(coarse[int(np.argmin([squares(b) for b in coarse]))])
    near = np.arange(max(best - COARSE * step, 0.0), min(best + COARSE * step, top) + 1e-12, step)
    fits = np.array([squares(b) for b in near])
    # commands held a tick apart leave a band anywhere between two of their levels fitting
    # alike: the middle of the bands that fit within TIE of the best
    k = int(np.argmin(fits))
    alike = fits <= fits[k] * (1.0 + TIE) + 1e-18
    low = k - int(np.argmin(alike[k::-1])) + 1 if not alike[:k + 1].all() else 0
    high = k + int(np.argmin(alike[k:])) - 1 if not alike[k:].all() else len(near) - 1
    return float(0.5 * (near[low] + near[high]))


def check_gains(tc: FloatArray, wheels: FloatArray, starts: FloatArray, ends: FloatArray,
                measured: FloatArray, sweep: SweepFit, band: float, max_wheel_speed: float
                ) -> tuple[FloatArray, FloatArray] | None:
    """Each wheel's gain (2,) over the whole check and its standard error (2,), its drift a
    cubic spline in time (knots DRIFT_KNOTS s apart) rather than the sweep's line: where the
    wheel moves clear of the band (`band` m/s), the sweep's delay and lag taken. tc (k,),
    wheels (2, k): the commands; measured (2, n): the wheels' speeds over [starts, ends]
    (n,): they overlap, but no two that follow each other share a pose, so that a camera's
    noise in the poses is nearly independent between them (on a simulated drive, the
    errors came out 0 to 1.5 of the standard error). A drift that swings within the sweep's 3 s
    bends its line, and so its gains (3.6 % on a MuJoCo robot whose drift swings by +-20 % of
    its fastest speed; 2.6 % so). None where a wheel has fewer than MIN_SAMPLES such
    intervals.
    """
    if len(starts) < 2 * MIN_SAMPLES:
        return None
    mid = 0.5 * (starts + ends)
    begin, end = float(starts[0]), float(ends[-1])
    pieces = max(1, round((end - begin) / DRIFT_KNOTS))
    knots = np.concatenate([[begin] * 3, np.linspace(begin, end, pieces + 1), [end] * 3])
    # imported here: scipy.interpolate takes 0.3 s to import, for a motor check only
    from scipy.interpolate import BSpline
    drift = BSpline.design_matrix(np.clip(mid, begin, np.nextafter(end, begin)), knots,
                                  3).toarray()
    steady = record.held_means(tc, record.driven_commands(wheels.T),
                               starts - sweep.delay - 3.0 * sweep.lag,
                               ends - sweep.delay) > 0.999
    gains, errors = np.zeros(2), np.zeros(2)
    for k in range(2):
        means = record.lagged_means(tc, wheels[k], starts - sweep.delay, ends - sweep.delay,
                                    sweep.lag)
        # moving as measured (beyond half the band's speed), then as the first fit has it
        # (beyond the band: noise would choose the samples, and a wheel that crossed the
        # band within a few frames is seen moving throughout)
        judged, least = measured[k], 0.5 * band * sweep.gains[k]
        for _ in range(2):
            least = max(least, MOVING_CHECK * max_wheel_speed)
            use = moving_about(starts, np.abs(judged) >= least, CLEAR) & steady
            if use.sum() < MIN_SAMPLES:
                return None
            coef, errors[k], _ = gain_fit(means[use], measured[k][use], drift[use])
            gains[k] = coef[0]
            judged = np.column_stack([means, drift]) @ coef
            least = BEYOND * band * gains[k]
    return gains, errors
