"""Each wheel's gain (its speed per unit of command: unequal wheels, motor spread, a sagging
battery) measured from what was sent and how the robot moved.

Each command (v, w) is split into its wheels' rim speeds (left, right = v -+ b w / 2, b the
wheel base). Between two poses at least INTERVAL apart each wheel's mean speed is measured
(from the robot's forward speed and turn rate, as the latency fit measures them) and
compared with g times the mean of its commands, acting the link's latency L late through the
motors' lag tau (as told or estimated: core.controller.link_estimate), plus a disturbance
while driven that drifts as a quadratic in time over each WINDOW s (a disturbance that
changes is not read as gain): one least-squares fit per wheel, its gain shared by the
windows; a gain is told where its standard error is at most GAIN_ERROR (a wheel whose
commands vary little beyond what the drift follows tells none). Only intervals in which both
wheels are commanded at least GAIN_FLOOR of the fastest wheel speed are fitted: a slower
command may lie in the motors' dead band, which a gain would not describe.

Times in s (one clock for commands and poses), speeds in m/s.
"""

from dataclasses import dataclass, replace
import math

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.controller import motion_record as record
from curve_formation.core.controller.link_estimate import DRIFT_DEGREE
from curve_formation.core.formation.dynamics import wheel_speeds


WINDOW = 6.0        # s over which the drift is one quadratic
GAIN_FLOOR = 0.2    # share of the fastest wheel speed below which a command is not fitted
GAIN_ERROR = 0.01   # largest standard error of a gain told
MIN_INTERVALS = 20
# Shortest interval (s) between the poses a speed is measured over: a pose's time is known
# to about a millisecond (a camera's stamp, a simulated world's step), 3 % of a 30 Hz
# interval, which would blur a gain; the latency fit needs the short ones, this does not
INTERVAL = 0.15


def thinned(tp: FloatArray, poses: FloatArray, interval: float
             ) -> tuple[FloatArray, FloatArray]:
    """The poses at least `interval` s apart (each the first at or after the last kept's
    time plus interval).
    """
    keep = [0]
    for k in range(1, len(tp)):
        if tp[k] - tp[keep[-1]] >= interval - 1e-9:
            keep.append(k)
    return tp[keep], poses[keep]


@dataclass(frozen=True)
class WheelGains:
    """gains (left, right; None if not told) and their standard errors, the fit's residual
    (rms m/s) and the intervals fitted; online (OnlineGains.fit): the (latency, motors' lag)
    it was fitted through (s), and whether it told gains alone but not once they were
    traded (`doubted`: those found before are dropped too).
    """

    gains: tuple[float, float] | None
    errors: tuple[float, float] | None
    residual: float | None
    intervals: int
    through: tuple[float, float] | None = None
    doubted: bool = False


NO_GAINS = WheelGains(None, None, None, 0)


def _drift_basis(mid: FloatArray, on: FloatArray, window: float) -> FloatArray:
    """(intervals, windows * (DRIFT_DEGREE + 1)): a quadratic in time per window, while
    driven (on: the driven share of each interval).
    """
    index = np.floor((mid - mid[0]) / window).astype(int)
    columns = []
    for k in np.unique(index):
        inside = index == k
        centre = 0.5 * window + mid[0] + k * window
        tau = (mid - centre) / (0.5 * window)
        columns += [np.where(inside, on * tau ** p, 0.0) for p in range(DRIFT_DEGREE + 1)]
    return np.column_stack(columns)


def told(errors: tuple[float, float]) -> bool:
    """Whether gains with these standard errors (left, right) are told: both at most
    GAIN_ERROR (the online fit's rule, and the motor check's).
    """
    return max(errors) <= GAIN_ERROR


def gain_fit(x: FloatArray, measured: FloatArray, drift: FloatArray
             ) -> tuple[FloatArray, float, FloatArray]:
    """Least squares of measured ~ g x + drift (x, measured (n,): m/s; drift (n, m): its
    basis): (the coefficients (m + 1,): g, then the drift's; g's standard error; residuals).
    """
    basis = np.column_stack([x, drift])
    coef, *_ = np.linalg.lstsq(basis, measured, rcond=None)
    residuals = measured - basis @ coef
    own = x - drift @ np.linalg.lstsq(drift, x, rcond=None)[0]   # what tells the gain
    spread = float(own @ own)
    dof = max(len(x) - basis.shape[1], 1)
    error = (math.sqrt(float(residuals @ residuals) / dof / spread) if spread > 1e-18
             else math.inf)
    return coef, error, residuals


def estimate_gains(command_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
                   poses: ArrayLike, wheel_base: float, max_wheel_speed: float,
                   latency: float, motor_time_constant: float,
                   window: float = WINDOW, untold: bool = False) -> WheelGains:
    """Each wheel's gain of one robot (see the module): command_times (k,) and commands
    (k, 2; v m/s, w rad/s) as sent; pose_times (m,) and poses (m, 3) as measured;
    wheel_base (m); max_wheel_speed (m/s; infinite: every command is fitted); latency and
    motor_time_constant (s) as told or estimated. untold: the gains fitted even where their
    errors are too large to tell them.
    """
    tc, cmd, tp, pose = record.cleaned(command_times, commands, pose_times, poses)
    tp, pose = thinned(tp, pose, INTERVAL)
    if len(tc) < 2 or len(tp) < MIN_INTERVALS or wheel_base <= 0.0:
        return NO_GAINS
    tc = tc + latency
    measured = np.stack(wheel_speeds(*record.measured_rates(tp, pose), wheel_base))
    wheels = np.stack(wheel_speeds(cmd[:, 0], cmd[:, 1], wheel_base))   # left, right
    driven = record.driven_commands(cmd)
    starts, ends = tp[:-1], tp[1:]
    x = np.stack([record.lagged_means(tc, wheels[k], starts, ends, motor_time_constant)
                  for k in range(2)])
    on = record.held_means(tc, driven, starts, ends)
    floor = GAIN_FLOOR * max_wheel_speed if math.isfinite(max_wheel_speed) else 0.0
    # the interval's commands (not their lag) all beyond the floor: none in a dead band
    lowest = np.minimum(*[np.minimum(np.abs(record.held_means(tc, wheels[k], starts - 2.0
                                                              * motor_time_constant, ends)),
                                     np.abs(x[k])) for k in range(2)])
    sel = (starts >= tc[0] + 3.0 * motor_time_constant) & (ends <= tc[-1] + 1.0) \
        & (lowest >= floor) & (on > 0.999)
    if sel.sum() < MIN_INTERVALS:
        return NO_GAINS
    mid = 0.5 * (starts[sel] + ends[sel])
    drift = _drift_basis(mid, on[sel], window)
    gains, errors, squares = [], [], 0.0
    for k in range(2):
        coef, error, residuals = gain_fit(x[k, sel], measured[k, sel], drift)
        gains.append(float(coef[0]))
        errors.append(error)
        squares += float(residuals @ residuals)
    residual = math.sqrt(squares / (2 * int(sel.sum())))
    if not told((errors[0], errors[1])) and not untold:
        return WheelGains(None, (errors[0], errors[1]), residual, int(sel.sum()))
    return WheelGains((gains[0], gains[1]), (errors[0], errors[1]), residual, int(sel.sum()))


# Online: how often (s) a controller fits its wheels' gains, over how much of the past (s)
GAINS_EVERY = 5.0
GAINS_SPAN = 60.0
LAG_MOVED = 0.005   # s the motors' lag may move from the one gains were fitted through


def wheel_record(rate_hz: float) -> record.MotionRecord:
    """The last GAINS_SPAN s of a controller's commands (at rate_hz) and poses, which the
    online fits of its wheels read (OnlineGains, dead_band_estimate.OnlineDeadBand).
    """
    return record.MotionRecord(int(rate_hz * GAINS_SPAN) + 2, GAINS_SPAN)


class OnlineGains(record.PeriodicFit):
    """A controller's running estimate of its wheels' gains: every GAINS_EVERY s its
    wheel_record (its commands at its ticks, its poses when taken) is fitted
    (estimate_gains) through the latency and motors' lag it holds then; the gains are those
    of the last fit that told them (None before), with their errors. Times in s on the
    controller's clock.
    """

    def __init__(self, motion: record.MotionRecord, wheel_base: float,
                 max_wheel_speed: float) -> None:
        super().__init__(motion, GAINS_EVERY, MIN_INTERVALS)
        self.wheel_base, self.max_wheel_speed = wheel_base, max_wheel_speed
        self.found: WheelGains = NO_GAINS   # the last fit that told gains
        self.taken: list[tuple[float, tuple[float, float]]] = []   # (when, gains) each fit
        # (latency, motors' lag) s: how far each may be off, traded one for the other (the
        # estimates' bounds: RobotModel sets it before each update; 0, 0: as told;
        # infinite: not known yet, and no gains are told)
        self.trade = (0.0, 0.0)

    def fit(self, command_times: FloatArray, commands: FloatArray, pose_times: FloatArray,
            poses: FloatArray, latency: float, motor_time_constant: float) -> WheelGains:
        """estimate_gains through the latency and lag held, its errors widened by how far
        the gains move with them traded by `trade` either way (a lag 20 ms long, its latency
        as short, had made a robot's gains 4 % high with errors of 1.2 %): told only if
        they stay within GAIN_ERROR.
        """
        through = (latency, motor_time_constant)
        found = replace(estimate_gains(command_times, commands, pose_times, poses,
                                       self.wheel_base, self.max_wheel_speed, latency,
                                       motor_time_constant), through=through)
        late, lag = self.trade
        if found.gains is None or (late <= 0.0 and lag <= 0.0):
            return found
        if not math.isfinite(lag):   # the lag estimated, its bound not known yet
            return replace(found, gains=None)
        assert found.errors is not None
        moved = np.zeros(2)
        for way in (-1.0, 1.0):
            traded = estimate_gains(command_times, commands, pose_times, poses,
                                    self.wheel_base, self.max_wheel_speed,
                                    max(latency + way * late, 0.0),
                                    max(motor_time_constant - way * lag, 0.0), untold=True)
            if traded.gains is not None:
                moved = np.maximum(moved, np.abs(np.subtract(traded.gains, found.gains)))
        errors = (float(np.hypot(found.errors[0], moved[0])),
                  float(np.hypot(found.errors[1], moved[1])))
        # told on its own but not once traded: the lag and latency are now known to be too
        # uncertain for gains, those found before them too (took drops them)
        doubted = not told(errors)
        return replace(found, gains=None if doubted else found.gains, errors=errors,
                       doubted=doubted)

    def took(self, now: float, found: WheelGains) -> None:
        if found.gains is not None:
            self.found = found
            self.taken.append((now, found.gains))
        elif found.doubted:
            self.found = NO_GAINS

    def moved(self, latency: float, motor_time_constant: float) -> None:
        """The latency and the motors' lag (s) held now: gains fitted through a lag more
        than LAG_MOVED s away are dropped until a fit tells them again (a robot's lag first
        taken 20 ms long, then corrected, had kept gains 5 % high from it).
        """
        through = self.found.through
        if through is not None and abs(motor_time_constant - through[1]) > LAG_MOVED:
            self.found = NO_GAINS

    @property
    def gains(self) -> tuple[float, float] | None:
        """(left, right) as last told, or None."""
        return self.found.gains
