"""The motors' dead band (the smallest wheel command that turns a wheel: below it the wheel
stands) measured from what was sent and how the robot moved.

Each command (v, w) is split into its wheels' speeds (left, right = v -+ b w / 2, b the
wheel base). The motors see that command plus a drift (a disturbance added on the robot, as
firmware adds it): the drift, as a command, is a piecewise-linear function of time (a knot
every KNOT s, its steps penalised so that it stays flat where nothing tells it, as while the
robot stands) fitted with each wheel's gain on the intervals whose commands are well clear
of any band (at least GAIN_FLOOR of the fastest wheel speed). Then each candidate band b
(0 to BAND_MAX of the fastest wheel speed) predicts each interval's wheel speed: its gain
times the mean of the command plus drift (delayed by the motors' lag), zero wherever that
lies within b; the band is the candidate whose predictions fit best (least squares over both
wheels, a coarse grid refined). The drift is then fitted again on every interval the band
leaves moving, and the band found again. A band is told only where
- the two agree within AGREE (a drift that changes while the robot stands, which the fit
  cannot see, moves it);
- each wheel's gain has a standard error of at most GAIN_ERROR (commands that hardly varied
  while clear of the band cannot tell a gain from a drift, and a drift wrongly fitted moves
  the band);
- it lies inside the coarse grid, below its last step;
- its residual is at most RESIDUAL_SHARE of it (a drift the fit does not follow, as a
  disturbance swinging while the robot stands, leaves a large one);
- both sides of it are seen: SIDE intervals commanded between half of it and it, and MOVED
  between it and twice it (a robot passes quickly through the commands just beyond it).

Times in s (one clock for commands and poses), speeds in m/s.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import BoolArray, FloatArray
from curve_formation.core.controller import motion_record as record
from curve_formation.core.controller.wheel_estimate import (
    GAIN_ERROR,
    GAIN_FLOOR,
    INTERVAL,
    thinned,
)
from curve_formation.core.formation.dynamics import wheel_speeds


KNOT = 2.0          # s between the drift's knots
SMOOTH = 1.0        # weight (m/s per m/s of step) of the penalty on the drift's steps
BAND_MAX = 0.25     # largest band sought, a share of the fastest wheel speed
COARSE = 26         # candidates of the first grid (0 to BAND_MAX)
FINE = 9            # candidates of the refined grid, across one coarse step either side
AGREE = 0.2         # largest share by which the band found twice may differ
RESIDUAL_SHARE = 0.15   # largest residual (rms) told, a share of the band
SIDE = 10           # fewest intervals commanded within the band (its upper half) that tell it
MOVED = 4           # fewest commanded beyond it (up to twice it), which a robot passes quickly
MIN_INTERVALS = 40


@dataclass(frozen=True)
class DeadBand:
    """band (m/s of wheel speed; None if not told), bound (m/s: the larger of the grid's
    step and the two fits' difference), the fit's residual (rms m/s), the intervals fitted.
    """

    band: float | None
    bound: float | None
    residual: float | None
    intervals: int


NO_BAND = DeadBand(None, None, None, 0)


def _hats(t: FloatArray, knots: FloatArray) -> FloatArray:
    """(len(t), len(knots)): linear interpolation between the knots, flat beyond them."""
    t = np.clip(t, knots[0], knots[-1])
    j = np.clip(np.searchsorted(knots, t, side='right') - 1, 0, len(knots) - 2)
    f = (t - knots[j]) / (knots[j + 1] - knots[j])
    out = np.zeros((len(t), len(knots)))
    rows = np.arange(len(t))
    out[rows, j], out[rows, j + 1] = 1.0 - f, f
    return out


@dataclass
class _Record:
    """One robot's intervals: the wheels' commands (2, k) at tc (latency added), driven (k,)
    and the measured wheel speeds (2, m) over [starts, ends]; usable (m,): fully driven,
    past the first commands' lag; x (2, m): the commands' means through the lag.
    """

    tc: FloatArray
    wheels: FloatArray
    driven: FloatArray
    starts: FloatArray
    ends: FloatArray
    measured: FloatArray
    usable: BoolArray
    x: FloatArray
    tau: float


@dataclass(frozen=True)
class _DriftBasis:
    """The drift's piecewise-linear basis: at_commands (commands, knots) its value at each
    command time; means (intervals, knots) its mean over each interval while driven (the
    drift is smooth beside the motors' lag: held, not lagged); steps (knots - 1, knots)
    the differences of neighbouring knots, penalised.
    """

    at_commands: FloatArray
    means: FloatArray
    steps: FloatArray


def _drift_basis(rec: _Record, knots: FloatArray) -> _DriftBasis:
    at_commands = _hats(rec.tc, knots)
    means = np.column_stack([record.held_means(rec.tc, at_commands[:, j] * rec.driven,
                                               rec.starts, rec.ends)
                             for j in range(len(knots))])
    return _DriftBasis(at_commands, means, np.diff(np.eye(len(knots)), axis=0))


def _drift(rec: _Record, k: int, fitted: BoolArray, drift: _DriftBasis
           ) -> tuple[float, FloatArray, float]:
    """Wheel k's gain, its drift as a command at each command time (zero when stopped),
    fitted on the intervals `fitted`, and the gain's relative standard error (commands
    that hardly vary cannot tell a gain from a drift).
    """
    steps = drift.steps
    basis = np.vstack([np.column_stack([rec.x[k, fitted], drift.means[fitted]]),
                       np.column_stack([np.zeros(len(steps)), SMOOTH * steps])])
    target = np.concatenate([rec.measured[k, fitted], np.zeros(len(steps))])
    coef, *_ = np.linalg.lstsq(basis, target, rcond=None)
    gain = float(coef[0])
    residuals = target - basis @ coef
    dof = max(int(fitted.sum()) - drift.means.shape[1] - 1, 1)
    # the gain's variance: the residual variance over what of the command the drift does
    # not also explain
    own = basis[:, 0] - basis[:, 1:] @ np.linalg.lstsq(basis[:, 1:], basis[:, 0],
                                                       rcond=None)[0]
    spread = float(own @ own)
    error = (math.sqrt(float(residuals @ residuals) / dof / spread) / max(abs(gain), 1e-6)
             if spread > 1e-18 else math.inf)
    if abs(gain) < 1e-6:
        return gain, np.zeros(len(rec.tc)), math.inf
    return gain, drift.at_commands @ (coef[1:] / gain) * rec.driven, error


def _delayed_means(rec: _Record, values: FloatArray) -> FloatArray:
    """Each interval's mean of a signal held from each command time, the motors' lag taken
    as a delay of tau (a band's commands are small and slow).
    """
    return record.held_means(rec.tc, values, rec.starts - rec.tau, rec.ends - rec.tau)


def _squares(rec: _Record, gains: list[float], motors: list[FloatArray], band: float
             ) -> float:
    """The residual sum of squares (m/s)^2 of the band's predictions."""
    total = 0.0
    for k in range(2):
        moved = np.where(np.abs(motors[k]) < band, 0.0, motors[k])
        residual = (rec.measured[k] - gains[k] * _delayed_means(rec, moved))[rec.usable]
        total += float(residual @ residual)
    return total


def _sides(rec: _Record, motors: list[FloatArray], band: float) -> tuple[int, int]:
    """How many usable intervals (both wheels) were commanded between half the band and
    it, and between it and twice it.
    """
    within = beyond = 0
    for motor in motors:
        size = np.abs(_delayed_means(rec, motor))[rec.usable]
        within += int(((size >= 0.5 * band) & (size < band)).sum())
        beyond += int(((size >= band) & (size < 2.0 * band)).sum())
    return within, beyond


def _best_band(rec: _Record, gains: list[float], motors: list[FloatArray], top: float
               ) -> tuple[float, float, float]:
    """(band, the fine grid's step, its sum of squares): a coarse grid then a fine one."""
    coarse = np.linspace(0.0, top, COARSE)
    squares = [_squares(rec, gains, motors, b) for b in coarse]
    best = int(np.argmin(squares))
    step = coarse[1] - coarse[0]
    fine = np.linspace(max(coarse[best] - step, 0.0), min(coarse[best] + step, top), FINE)
    fine_squares = [_squares(rec, gains, motors, b) for b in fine]
    k = int(np.argmin(fine_squares))
    return float(fine[k]), float(fine[1] - fine[0]), float(fine_squares[k])


def _clear(rec: _Record, motor: FloatArray, floor: float) -> BoolArray:
    """The usable intervals over which a wheel's command (motor: with drift, at command
    times) stays at least `floor` from zero, its lag included.
    """
    beyond = (np.abs(motor) >= floor).astype(float)
    return rec.usable & (record.held_means(rec.tc, beyond, rec.starts - 3.0 * rec.tau,
                                           rec.ends) > 0.999)


def _intervals(command_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
               poses: ArrayLike, wheel_base: float, latency: float, tau: float
               ) -> _Record | None:
    """One robot's record of intervals (estimate_dead_band's arguments); None where too
    few are usable.
    """
    tc, cmd, tp, pose = record.cleaned(command_times, commands, pose_times, poses)
    tp, pose = thinned(tp, pose, INTERVAL)
    if len(tc) < 2 or len(tp) < MIN_INTERVALS:
        return None
    tc = tc + latency
    wheels = np.stack(wheel_speeds(cmd[:, 0], cmd[:, 1], wheel_base))
    driven = record.driven_commands(cmd)
    starts, ends = tp[:-1], tp[1:]
    usable = ((starts >= tc[0] + 3.0 * tau) & (ends <= tc[-1] + 1.0)
              & (record.held_means(tc, driven, starts, ends) > 0.999))
    if usable.sum() < MIN_INTERVALS:
        return None
    return _Record(tc, wheels, driven, starts, ends,
                   np.stack(wheel_speeds(*record.measured_rates(tp, pose), wheel_base)),
                   usable, np.stack([record.lagged_means(tc, wheels[k], starts, ends, tau)
                                     for k in range(2)]), tau)


def estimate_dead_band(command_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
                       poses: ArrayLike, wheel_base: float, max_wheel_speed: float,
                       latency: float, motor_time_constant: float) -> DeadBand:
    """The motors' dead band of one robot (see the module): command_times (k,) and commands
    (k, 2; v m/s, w rad/s) as sent; pose_times (m,) and poses (m, 3) as measured; wheel_base
    (m); max_wheel_speed (m/s; the band is sought up to BAND_MAX of it, none where it is
    infinite); latency and motor_time_constant (s) as told or estimated.
    """
    if wheel_base <= 0.0 or not math.isfinite(max_wheel_speed) or max_wheel_speed <= 0.0:
        return NO_BAND
    rec = _intervals(command_times, commands, pose_times, poses, wheel_base, latency,
                     motor_time_constant)
    if rec is None:
        return NO_BAND
    mid = 0.5 * (rec.starts + rec.ends)
    knots = np.arange(mid[0], mid[-1] + KNOT, KNOT)
    if len(knots) < 2:
        return NO_BAND
    top = BAND_MAX * max_wheel_speed
    basis = _drift_basis(rec, knots)
    fitted = [_clear(rec, rec.wheels[k], GAIN_FLOOR * max_wheel_speed) for k in range(2)]
    found = []
    for _ in range(2):   # the band, then again with the drift fitted where it leaves moving
        if min(int(f.sum()) for f in fitted) < MIN_INTERVALS:
            return NO_BAND
        gains, motors, errors = [], [], []
        for k in range(2):
            gain, drift, error = _drift(rec, k, fitted[k], basis)
            gains.append(gain)
            motors.append(rec.wheels[k] + drift)
            errors.append(error)
        band, step, squares = _best_band(rec, gains, motors, top)
        found.append(band)
        if band > 0.0:
            fitted = [_clear(rec, motors[k], band) for k in range(2)]
    intervals = int(rec.usable.sum())
    residual = math.sqrt(squares / max(2 * intervals - 1, 1))
    first, band = found
    within, beyond = _sides(rec, motors, band)
    told = (0.0 < band < top - top / (COARSE - 1) and abs(band - first) <= AGREE * band
            and max(errors) <= GAIN_ERROR and residual <= RESIDUAL_SHARE * band
            and within >= SIDE and beyond >= MOVED)
    return DeadBand(band if told else None, max(step, abs(band - first)), residual,
                    intervals)


# Online: how often (s) a controller fits its motors' dead band
BAND_EVERY = 5.0


class OnlineDeadBand(record.PeriodicFit):
    """A controller's running estimate of its motors' dead band: every BAND_EVERY s the
    record it shares with its wheel gains' fit (wheel_estimate.wheel_record: the last 60 s
    of its commands at its ticks and its poses when taken) is fitted (estimate_dead_band)
    through the latency and motors' lag it holds then; a band is taken when two fits in a
    row tell bands within AGREE of each other (the later; None before). Times in s on the
    controller's clock.
    """

    def __init__(self, motion: record.MotionRecord, wheel_base: float,
                 max_wheel_speed: float) -> None:
        super().__init__(motion, BAND_EVERY, MIN_INTERVALS)
        self.wheel_base, self.max_wheel_speed = wheel_base, max_wheel_speed
        self.last: DeadBand = NO_BAND    # the last fit
        self.found: DeadBand = NO_BAND   # the fit taken
        self.taken: list[tuple[float, float]] = []   # (when, band) each band taken

    def fit(self, command_times: FloatArray, commands: FloatArray, pose_times: FloatArray,
            poses: FloatArray, latency: float, motor_time_constant: float) -> DeadBand:
        return estimate_dead_band(command_times, commands, pose_times, poses,
                                  self.wheel_base, self.max_wheel_speed, latency,
                                  motor_time_constant)

    def took(self, now: float, found: DeadBand) -> None:
        before, self.last = self.last.band, found
        if (found.band is not None and before is not None
                and abs(found.band - before) <= AGREE * found.band):
            self.found = found
            self.taken.append((now, found.band))

    @property
    def band(self) -> float | None:
        """m/s of wheel speed, as last taken, or None."""
        return self.found.band
