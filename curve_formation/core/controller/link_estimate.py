"""How late a robot's commands act, and how slowly its motors follow them, measured from what
was sent and how the robot moved.

Commands (v, w) sent at times tc and held until the next act L s later; the robot's poses are
measured at times tp (an overhead camera's stamps). Between two poses the robot's mean forward
speed and turn rate are measured (the displacement along the mean heading, and the heading's
change, over the interval) and compared with the commands' means over the same interval
shifted by a candidate L, plus a disturbance [d_v, d_w] acting while a command drives the
motors, a quadratic in time over the fit so that one that changes is not read as latency
(fitted by least squares for each L). The latency is the L of least squared
residual; its spread over windows of a few seconds tells the jitter (and the estimate's own
noise). A robot whose commands hardly change tells nothing: then no latency is given.

The motors' first-order lag (time constant tau) is fitted the same way, over a grid of
(L, tau) at once: a lag rounds each change of the commands off where a latency only shifts
it, so a robot whose commands change every tick tells the two apart (estimate_latency with
motor_time_constant None, OnlineLink with estimate_motor).

Times in s (one clock for commands and poses), speeds in m/s and rad/s.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.controller.motion_record import (
    cleaned,
    driven_commands,
    held_means,
    lag_knots,
    LagMeans,
    measured_rates,
    MotionRecord,
)


LAGS = np.arange(-0.1, 0.6001, 0.0025)   # candidate latencies (s; below 0: the robot acts
# before the commands are dated, the recorder got them late)
WINDOW = 4.0   # s of poses per window for the spread
# Least variation of the commanded speed (m/s) and turn rate (rad/s, scaled by TURN_SCALE)
# across a window for its latency to count: a steady command has none to tell.
MIN_EXCITATION = 1e-3
TURN_SCALE = 0.04   # m: turn rates weigh as a point 4 cm from the axle moves
TRIMMED = 0.05      # share of a fit's intervals of largest residual left out of it
DRIFT_DEGREE = 2    # the disturbance over a fit: a polynomial in time of this degree


@dataclass(frozen=True)
class LinkEstimate:
    """latency (s, None if not observable), spread (s: std of the windows' latencies),
    windows (how many told a latency), residual (rms m/s of the fit at the latency),
    motor_time_constant (s: the motors' lag the fit took, as told or as estimated with the
    latency; None if it was to be estimated and nothing told one), motor_spread (s: std of
    the windows' motor lags; None unless estimated).
    """

    latency: float | None
    spread: float | None
    windows: int
    residual: float | None
    motor_time_constant: float | None = None
    motor_spread: float | None = None


def _residuals(tp: FloatArray, v_meas: FloatArray, w_meas: FloatArray,
               means: tuple[LagMeans, LagMeans, FloatArray], tau: float = 0.0,
               knots: tuple[FloatArray, FloatArray] | None = None) -> FloatArray:
    """(len(lags),) sum of squared residuals of the fit at each lag, its largest TRIMMED
    share of intervals left out (a lost command leaves the intervals it should have driven
    fitting no lag). Every lag at once: rows are lags, columns the intervals between the
    poses tp. means: _interval_means of these intervals and lags; tau: the motors' time
    constant (s), through which the commands act; knots: the lag's output at each command
    (motion_record.lag_knots) of v and w, where the caller has them.
    """
    mv, mw, on = means
    kv, kw = (None, None) if knots is None else knots
    v, w = mv.through(tau, kv), mw.through(tau, kw)
    rv, rw = v_meas - v, (w_meas - w) * TURN_SCALE
    # the disturbance acting while driven, drifting over the fit as a polynomial of degree
    # DRIFT_DEGREE in time (a disturbance that changes is not read as latency): least
    # squares in each channel, every lag at once
    mid = 0.5 * (tp[:-1] + tp[1:])
    span = max(0.5 * float(mid[-1] - mid[0]), 1e-9)
    tau_k = (mid - 0.5 * (mid[0] + mid[-1])) / span
    basis = on[:, None, :] * (tau_k[None, None, :] ** np.arange(DRIFT_DEGREE + 1)[None, :,
                                                                                   None])
    gram = np.einsum('lai,lbi->lab', basis, basis) + 1e-12 * np.eye(DRIFT_DEGREE + 1)
    fitted = []
    for r in (rv, rw):
        coef = np.linalg.solve(gram, np.einsum('lai,li->la', basis, r)[..., None])[..., 0]
        fitted.append(r - np.einsum('la,lai->li', coef, basis))
    squared = fitted[0] ** 2 + fitted[1] ** 2
    kept = squared.shape[1] - int(TRIMMED * squared.shape[1])
    return np.partition(squared, kept - 1, axis=1)[:, :kept].sum(axis=1)


def _interval_means(tc: FloatArray, commands: FloatArray, driven: FloatArray, tp: FloatArray,
                    lags: FloatArray) -> tuple[LagMeans, LagMeans, FloatArray]:
    """What _residuals needs of the commands over the intervals between the poses tp, every
    lag at once, whatever the motors' lag: v's and w's LagMeans and the driven share.
    """
    starts = tp[None, :-1] - lags[:, None]
    ends = tp[None, 1:] - lags[:, None]
    return (LagMeans(tc, commands[:, 0], starts, ends), LagMeans(tc, commands[:, 1], starts, ends),
            held_means(tc, driven, starts, ends))


def _best_lag(residuals: FloatArray, lags: FloatArray) -> float:
    """The lag of least residual, refined by a parabola through it and its neighbours."""
    k = int(np.argmin(residuals))
    if 0 < k < len(lags) - 1:
        a, b, c = residuals[k - 1:k + 2]
        curvature = a - 2 * b + c
        if curvature > 0:
            return float(lags[k] + 0.5 * (a - c) / curvature * (lags[1] - lags[0]))
    return float(lags[k])


def _best_pair(surface: FloatArray, lags: FloatArray, taus: FloatArray
               ) -> tuple[float, float]:
    """(lag, tau) of least residual over the surface (len(taus), len(lags)), each refined
    by a parabola along its own axis through the least and its neighbours.
    """
    k, j = np.unravel_index(int(np.argmin(surface)), surface.shape)
    lag = _best_lag(surface[k], lags) if len(lags) > 1 else float(lags[0])
    tau = _best_lag(surface[:, j], taus) if len(taus) > 1 else float(taus[0])
    return lag, max(tau, 0.0)


class _Fit:
    """The intervals between a robot's poses that its commands cover at every candidate lag,
    ready to be fitted window by window.
    """

    def __init__(self, tc: FloatArray, cmd: FloatArray, tp: FloatArray, pose: FloatArray,
                 lags: FloatArray) -> None:
        self.tc, self.cmd, self.tp, self.lags = tc, cmd, tp, lags
        self.driven = driven_commands(cmd)
        self.v_meas, self.w_meas = measured_rates(tp, pose)
        self.inside = (tp[:-1] - lags.max() >= tc[0]) & (tp[1:] <= tc[-1] + 1.0)
        self._knots: dict[float, tuple[FloatArray, FloatArray]] = {}   # by motor lag tau

    def knots(self, tau: float) -> tuple[FloatArray, FloatArray] | None:
        """The motors' lag output at each command, of v and w (lag_knots; None for tau 0),
        computed once a tau for every window.
        """
        if tau <= 0.0:
            return None
        if tau not in self._knots:
            self._knots[tau] = (lag_knots(self.tc, self.cmd[:, 0], tau),
                                lag_knots(self.tc, self.cmd[:, 1], tau))
        return self._knots[tau]

    def _window(self, begin: float, end: float) -> IntArray | None:
        """The indices of the intervals from begin to end (s); None if fewer than 5, or if
        the commands in force then hardly change.
        """
        tp = self.tp
        sel = self.inside & (tp[:-1] >= begin) & (tp[1:] < end)
        if sel.sum() < 5 or not _excited(self.tc, self.cmd, begin - self.lags.max(), end):
            return None
        return np.flatnonzero(sel)

    def residuals(self, begin: float, end: float, lags: FloatArray | None = None,
                  tau: float = 0.0) -> tuple[FloatArray, int] | None:
        """The residual curve over the lags of the intervals from begin to end (s), the
        commands acting through the motors' lag tau (s), and their count; None as _window.
        """
        idx = self._window(begin, end)
        if idx is None:
            return None
        tp = self._poses(idx)
        means = _interval_means(self.tc, self.cmd, self.driven, tp,
                                self.lags if lags is None else lags)
        return _residuals(tp, self.v_meas[idx], self.w_meas[idx], means, tau,
                          self.knots(tau)), len(idx)

    def _poses(self, idx: IntArray) -> FloatArray:
        return np.append(self.tp[idx], self.tp[idx[-1] + 1])

    def surface(self, begin: float, end: float, taus: FloatArray
                ) -> tuple[FloatArray, int] | None:
        """The residuals (len(taus), len(lags)) over the lags for each motor time constant
        in taus (s), of the intervals from begin to end, and their count; None as _window.
        """
        idx = self._window(begin, end)
        if idx is None:
            return None
        tp = self._poses(idx)
        means = _interval_means(self.tc, self.cmd, self.driven, tp, self.lags)
        return np.array([_residuals(tp, self.v_meas[idx], self.w_meas[idx], means, float(tau),
                                    self.knots(float(tau)))
                         for tau in taus]), len(idx)


# Candidate motor time constants (s) where the motors' lag is estimated with the latency:
# offline (estimate_latency) on a fine grid, online on a coarse one refined by the parabola
MOTOR_LAGS = np.arange(0.0, 0.2001, 0.005)
ONLINE_MOTOR_LAGS = np.arange(0.0, 0.1401, 0.02)


def estimate_latency(command_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
                     poses: ArrayLike, lags: ArrayLike = LAGS, window: float = WINDOW,
                     motor_time_constant: float | None = 0.0,
                     motor_lags: ArrayLike = MOTOR_LAGS) -> LinkEstimate:
    """The latency of one robot's commands (see the module): command_times (k,) and commands
    (k, 2) as sent; pose_times (m,) and poses (m, 3) as measured (x, y m; theta rad);
    motor_time_constant (s): the motors' first-order lag, through which each command acts
    (told: limits.motor_time_constant), so that the lag is not read as latency; None: it is
    estimated with the latency, over motor_lags (s).
    """
    tc, cmd, tp, pose = cleaned(command_times, commands, pose_times, poses)
    lags = np.asarray(lags, float)
    estimating = motor_time_constant is None
    taus = np.asarray(motor_lags if estimating else [motor_time_constant], float)
    if len(tc) < 2 or len(tp) < 3:
        return LinkEstimate(None, None, 0, None)
    fit = _Fit(tc, cmd, tp, pose, lags)
    pairs, total = [], np.zeros((len(taus), len(lags)))
    for begin in np.arange(tp[0], tp[-1], window):
        found = fit.surface(begin, begin + window, taus)
        if found is not None and _clear(*found):
            pairs.append(_best_pair(found[0], lags, taus))
            total += found[0]
    if not pairs:
        return LinkEstimate(None, None, 0, None,
                            None if estimating else motor_time_constant)
    lats, motors = np.array(pairs).T
    if estimating:   # the windows' fits summed: a camera's noise blurs the lag in any one
        latency, tau = _best_pair(total, lags, taus)
    else:   # the windows' median: a window whose disturbance changed (the fit holds it
        # constant) does not pull it, as it would a fit over the whole run
        latency, tau = float(np.median(lats)), float(taus[0])
    whole = fit.residuals(-np.inf, np.inf, np.array([latency]), tau)
    residual = None if whole is None else math.sqrt(float(whole[0][0]) / whole[1])
    return LinkEstimate(latency, float(np.std(lats)), len(pairs), residual, tau,
                        float(np.std(motors)) if estimating else None)


def _clear(residuals: FloatArray, count: int) -> bool:
    """Whether the fit over `count` intervals tells one latency: its least residual below the
    typical one by more than the noise would make it vary (a standard deviation of a sum of
    count squared Gaussian residuals); a robot that stood still fits every lag alike.
    """
    typical, best = float(np.median(residuals)), float(residuals.min())
    return typical > 0.0 and typical - best > best * math.sqrt(2.0 / count)


def _excited(tc: FloatArray, cmd: FloatArray, begin: float, end: float,
             least: float = MIN_EXCITATION) -> bool:
    """Whether the commands in force between begin and end (s) change by at least `least`
    (m/s; turn rates scaled by TURN_SCALE): enough to time.
    """
    sel = (tc >= begin) & (tc <= end)
    if sel.sum() < 2:
        return False
    v, w = cmd[sel, 0], cmd[sel, 1] * TURN_SCALE
    return bool(max(np.ptp(v), np.ptp(w)) >= least)


# Online: candidate latencies on a coarser grid (refined by the parabola), how often (s) a
# controller fits (more often until it has taken a first value) and over how much of the
# past (s), over how long (s) the fits are remembered, how many estimates in a row must agree
# and within what (s) before one is taken.
ONLINE_LAGS = np.arange(0.0, 0.5001, 0.01)
ONLINE_EVERY = 1.0
ONLINE_FIRST_EVERY = 0.5
ONLINE_SPAN = 6.0
ONLINE_MEMORY = 50.0
AGREEING = 3
AGREEMENT = 0.02


MOTOR_AGREEMENT = 0.01   # s: the motor lags of the AGREEING estimates, as AGREEMENT
WINDOWS = 30       # fits alone whose spread is reported (OnlineLink.bounds): the last 30 s
MIN_WINDOWS = 5    # fewest fits alone a spread is reported from
# Least variation of the commands (m/s, as MIN_EXCITATION) over ONLINE_SPAN for a fit that
# estimates the motors' lag: a robot creeping about its target at a few mm/s does so in its
# motors' dead band and command steps, which a lag fits better than the motors' response.
MOTOR_EXCITATION = 5e-3


class OnlineLink(MotionRecord):
    """A controller's running estimate of its command latency and, with `estimate_motor`,
    of its motors' lag. Every ONLINE_EVERY s (every ONLINE_FIRST_EVERY s until a first value
    is taken: the value it starts from is the one most likely wrong) the last ONLINE_SPAN s
    of commands and poses are fitted (as estimate_latency fits a window) and the fit's
    residual surface over (motor lag, latency), weighted by the time since the fit before, is
    added to those before it, which fade over ONLINE_MEMORY s: the estimate is the least of
    the sum, a least-squares fit over the run's last minute, so one large command change
    (whose own delay is one draw of the jitter) does not decide it, and overlapping windows
    that repeat the same data are not taken for agreement. New values are taken only when
    AGREEING estimates in a row lie within AGREEMENT (the latencies) and MOTOR_AGREEMENT (the
    motor lags) of each other (their medians), so one that wanders is not. Times in s on the
    controller's clock. initial: the latency to start from; estimate_latency False: it is
    held (only the motors' lag is fitted); motor_time_constant (s): the motors' lag, held
    unless estimate_motor, then where the estimate starts from.
    """

    def __init__(self, initial: float, rate_hz: float, motor_time_constant: float = 0.0,
                 estimate_latency: bool = True, estimate_motor: bool = False) -> None:
        from collections import deque
        super().__init__(int(rate_hz * (ONLINE_SPAN + ONLINE_LAGS.max() + 1.0)) + 2,
                         ONLINE_SPAN)
        self.latency = initial
        self.motor_time_constant = motor_time_constant
        self.lags = ONLINE_LAGS if estimate_latency else np.array([initial])
        self.taus = ONLINE_MOTOR_LAGS if estimate_motor else np.array([motor_time_constant])
        self.recent: deque[tuple[float, float]] = deque(maxlen=AGREEING)
        self.next_at: float | None = None
        self.cadence = ONLINE_EVERY   # s from the last fit to the next
        self.total: FloatArray | None = None   # the remembered residual surface
        self.taken: list[tuple[float, float]] = []   # (when, latency) of each value taken
        self.motor_taken: list[tuple[float, float]] = []   # (when, motor lag) likewise
        # (latency, motor lag) of each of the last WINDOWS fits alone (s): their spread
        # tells how far one window's data may place them (bounds)
        self.windows: deque[tuple[float, float]] = deque(maxlen=WINDOWS)
        # (latency, motor lag) s: how far the last WINDOWS fits alone scatter about their
        # median, robustly (window_spread); None before MIN_WINDOWS fits
        self.bounds: tuple[float, float] | None = None

    def update(self, now: float) -> float:
        """The latency to use from `now` on (s; motor_time_constant likewise): new estimates
        every cadence s.
        """
        if self.next_at is None:
            self.next_at = now + self.cadence
        if now < self.next_at or len(self.commands) < 2 or len(self.poses) < 3:
            return self.latency
        weight = self.cadence / ONLINE_EVERY   # each second of the run weighs alike
        fade = math.exp(-self.cadence / ONLINE_MEMORY)
        self.cadence = ONLINE_EVERY if self.taken or self.motor_taken else ONLINE_FIRST_EVERY
        self.next_at = now + self.cadence
        sent = np.array(self.commands)
        least = MOTOR_EXCITATION if len(self.taus) > 1 else MIN_EXCITATION
        if not _excited(sent[:, 0], sent[:, 1:], -np.inf, np.inf, least):
            return self.latency   # the fit below would tell nothing either: spare it
        seen = np.array(self.poses)
        tc, cmd, tp, pose = cleaned(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:])
        found = _Fit(tc, cmd, tp, pose, self.lags).surface(-np.inf, np.inf, self.taus)
        if found is None or not _clear(*found):
            return self.latency
        self.total = weight * found[0] if self.total is None else (
            fade * self.total + weight * found[0])
        self.windows.append(_best_pair(found[0], self.lags, self.taus))
        self.bounds = window_spread(self.windows)
        self.recent.append(_best_pair(self.total, self.lags, self.taus))
        if len(self.recent) < AGREEING:
            return self.latency
        lats, taus = np.array(self.recent).T
        if np.ptp(lats) <= AGREEMENT and np.ptp(taus) <= MOTOR_AGREEMENT:
            latency, tau = float(np.median(lats)), float(np.median(taus))
            if abs(latency - self.latency) > 1e-3:
                self.latency = latency
                self.taken.append((now, latency))
            if abs(tau - self.motor_time_constant) > 1e-3:
                self.motor_time_constant = tau
                self.motor_taken.append((now, tau))
        return self.latency


def window_spread(windows: Sequence[tuple[float, float]]) -> tuple[float, float] | None:
    """(latency, motor lag) s: how far fits alone (`windows`, each from ONLINE_SPAN s of
    data) scatter about their median, robustly (1.4826 times the median absolute deviation:
    a standard deviation that a few windows with little in them do not decide); None for
    fewer than MIN_WINDOWS. The estimate, from all of them, came out within it on most
    robots of arena_demo's MuJoCo world. Not a bound on a bias that every window shares (a
    servo's delay taken as latency: docs/link.md).
    """
    if len(windows) < MIN_WINDOWS:
        return None
    found = np.array(windows)
    spread = 1.4826 * np.median(np.abs(found - np.median(found, axis=0)), axis=0)
    return float(spread[0]), float(spread[1])


def replay_online(tick_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
                  poses: ArrayLike, initial: float, rate_hz: float,
                  motor_time_constant: float = 0.0, estimate_latency: bool = True,
                  estimate_motor: bool = False) -> OnlineLink:
    """OnlineLink(initial, rate_hz, motor_time_constant, estimate_latency, estimate_motor)
    fed as a controller feeds it: before each tick (tick_times (k,), s) the poses taken by
    then (pose_times (m,), poses (m, 3): x, y m, theta rad), then the tick's update, then
    its command (commands (k, 2): v m/s, w rad/s as sent). Returns it, with every value it
    took in `taken` and `motor_taken` (none: it kept its initial values throughout).
    """
    ticks = np.asarray(tick_times, float)
    sent = np.asarray(commands, float).reshape(-1, 2)
    seen_at = np.asarray(pose_times, float)
    seen = np.asarray(poses, float).reshape(-1, 3)
    online = OnlineLink(initial, rate_hz, motor_time_constant, estimate_latency,
                        estimate_motor)
    k = 0
    for at, (v, w) in zip(ticks, sent, strict=True):
        while k < len(seen_at) and seen_at[k] <= at:
            online.seen(seen_at[k], *seen[k])
            k += 1
        online.update(at)
        online.sent(at, v, w)
    return online
