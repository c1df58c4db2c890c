"""A motor check: a robot turns in place for about 8 s before it first drives, so that its
controller learns each wheel's gain and the motors' dead band at once, instead of waiting for
the formation's commands to cross them (controller.motor_check).

The robot's wheels are commanded opposite speeds (left -u, right +u: it turns on the spot,
never leaving its disc). Each wheel is measured from the poses (its rim speed over SPAN s:
the forward speed -+ half the wheel base times the turn rate) and modelled as its gain times
its command plus a drift (a disturbance added on the robot, as firmware adds it), zero while
that lies within the band (a hard cut-off, as the MuJoCo motors have it).
- Sweep (SWEEP_SECONDS): u goes 0 -> +U -> -U -> 0, U a share SWEEP_SHARE of the fastest wheel
  speed (within the turn limit). Where a wheel clearly moves, one least-squares fit per wheel
  (gain, drift as a line in time) over a grid of delays (the link's latency and the pose's
  age) and motor lags gives its gain, its drift, the delay and the lag
  (core.controller.motor_check_fit.fit_sweep).
- Crossings (CROSS_SECONDS): each wheel's command is centred on where its drift leaves it
  standing and swept slowly through +-A there (A = CROSS_SHARE of the fastest wheel speed),
  up, then down between the first pass's commands. The drift is followed while the wheel
  moves (its speed less what its commands ask, once clear of the band for CLEAR s) and
  carried on as a line while it stands, so that a swinging drift keeps the band within
  reach. Each pass's band is the one whose model (the commands sent, the drift followed as a
  curve through the pass, the sweep's gain, delay and lag, a small shift left free) fits its
  measured speeds best (motor_check_fit.pass_band).
Each wheel's gain is then fitted again over the whole check, its drift a spline in time
(motor_check_fit.check_gains: a drift that swings within the sweep bends its line).
The band is the mean over both wheels and both passes; a band within the largest of the
grid's step, the commands' levels apart (a quarter of a tick's step: 0.6 % of the fastest
wheel speed at 10 Hz) and half the wheels' difference is told as none (0); its bound that, or
half a wheel's passes' difference where larger.
Each stage (the sweep, the up pass, the down pass) is run again (REPEATS in all at most)
where a gap of more than GAP s in its poses or its ticks shows a process held up (the
camera's, the robot's, this controller's, as a loaded machine holds one): a robot then moves
as no command says, and standing still through a crossing it looks as if in a band. A
shorter gap in the poses (motor_check_fit.held_up) is left out of the fits, and runs a pass
again (its wheel may cross its band there).
Times in s (the controller's clock), speeds in m/s of rim.
"""

from dataclasses import dataclass, field
import math

import numpy as np

from curve_formation.core.base.shapes import Command, FloatArray
from curve_formation.core.controller import motion_record as record
from curve_formation.core.controller.motor_check_fit import (
    BAND_STEP,
    check_gains,
    CLEAR,
    DRIFT_POINTS,
    fit_sweep,
    MIN_SAMPLES,
    MOVING,
    pass_band,
    pose_gaps,
    SPAN,
    spans,
    SweepFit,
)
from curve_formation.core.controller.wheel_estimate import told
from curve_formation.core.formation.dynamics import body_from_wheels, wheel_speeds


SWEEP_SECONDS = 3.0
SWEEP_SHARE = 0.8      # of the fastest wheel speed: beyond the band and a drift of 0.5
CROSS_SECONDS = 5.0    # two passes of 2.5 s
CHECK_SECONDS = SWEEP_SECONDS + CROSS_SECONDS
CROSS_SHARE = 0.3      # of the fastest wheel speed: bands up to about BAND_MAX are crossed
DRIFT_WINDOW = 1.0     # s of the crossings' drift measures a line is fitted through
SETTLE = 0.4           # s at each pass's start left out (the jump to it, through the link)
GAP = 0.15             # s: a longer gap in poses or ticks disturbs a stage (a process held up)
REPEATS = 3            # stages a check runs again at most
REACH = 0.6            # passes either side of a pass's middle whose drift measures it is fitted to


@dataclass(frozen=True)
class ProbeResult:
    """What a motor check found: gains (left, right speed per unit of command; None if not
    fitted), band (m/s; 0.0 where none was seen, None if not fitted), bound (m/s), the
    sweep's delay and lag (s) and its residual (rms m/s).
    """

    gains: tuple[float, float] | None
    band: float | None
    bound: float | None
    delay: float | None
    lag: float | None
    residual: float | None
    repeated: int = 0   # stages run again: a gap in its poses or ticks disturbed them
    # the gains' standard errors (left, right: speed per unit of command) over the whole
    # check (check_gains); None where only the sweep's fit has them (not used then)
    gain_errors: tuple[float, float] | None = None

    @property
    def trusted(self) -> bool:
        """Whether its gains, and its band measured from the same poses, are used: their
        standard errors known and told (wheel_estimate.told; a camera's noise can leave a
        check's gains 10 % off and its band 3 times the drawn one).
        """
        return self.gain_errors is not None and told(self.gain_errors)


NOT_FITTED = ProbeResult(None, None, None, None, None, None)
SWEEP, UP, DOWN = 'sweep', 'up', 'down'   # the check's stages, in order
STAGE_SECONDS = {SWEEP: SWEEP_SECONDS, UP: 0.5 * CROSS_SECONDS, DOWN: 0.5 * CROSS_SECONDS}


def sweep_command(t: float, amplitude: float) -> float:
    """u (m/s) of the sweep at t s after its start: 0 -> +A -> -A -> 0 in SWEEP_SECONDS."""
    quarter = SWEEP_SECONDS / 4.0
    if t < quarter:
        return amplitude * t / quarter
    if t < 3.0 * quarter:
        return amplitude * (1.0 - (t - quarter) / quarter)
    return amplitude * (-1.0 + (t - 3.0 * quarter) / quarter)


def cross_offset(t: float, amplitude: float, period: float) -> float:
    """The crossings' offset (m/s) at t s after their start: -A -> +A, then +A -> -A less
    half of what it moves in a control `period` (s), so that the second pass's commands lie
    between the first's; every other tick a quarter of that further, so that the levels the
    commands hold for a tick lie a quarter of its step apart over both passes.
    """
    half = CROSS_SECONDS / 2.0
    step = 2.0 * amplitude * period / half   # m/s the offset moves in a tick
    dither = 0.25 * step * (int(math.floor(t / period + 0.5)) % 2)
    if t < half:
        return amplitude * (-1.0 + 2.0 * t / half) + dither
    return amplitude * (1.0 - 2.0 * (t - half) / half) - 0.5 * step - dither


@dataclass
class MotorProbe:
    """One robot's motor check, run by its controller before it first drives: command(t)
    gives what to send while it lasts (None once done), seen() and sent() record the poses
    taken and the commands sent; `result` once done. wheel_base (m), max_wheel_speed (m/s),
    max_angular_rate (rad/s) as the limits say.
    """

    wheel_base: float
    max_wheel_speed: float
    max_angular_rate: float = math.inf
    period: float = 0.1   # s between the controller's ticks
    result: ProbeResult | None = None
    commands: list[tuple[float, float, float]] = field(default_factory=list)
    poses: list[tuple[float, float, float, float]] = field(default_factory=list)
    _sweep: SweepFit | None = None   # the sweep's fit, once made
    # (stage, when it began: s) of the stages begun, in order; a disturbed one is run again
    _stages: list[tuple[str, float]] = field(default_factory=list)
    # each wheel's drift as the crossings measured it: [(s at the wheels, m/s), ...]
    _drifts: tuple[list[tuple[float, float]], list[tuple[float, float]]] = field(
        default_factory=lambda: ([], []))
    _followed_to: float = -math.inf   # s: the last pose _follow_drift read
    # s: since when each wheel has moved without a break, as _follow_drift measured it
    _moving_since: list[float] = field(default_factory=lambda: [math.inf, math.inf])

    @property
    def amplitude(self) -> float:
        """U (m/s): SWEEP_SHARE of the fastest wheel speed, within the turn limit."""
        return min(SWEEP_SHARE * self.max_wheel_speed,
                   0.5 * self.max_angular_rate * self.wheel_base)

    @property
    def crossing(self) -> float:
        """A (m/s) of the crossings: CROSS_SHARE of the fastest wheel speed."""
        return CROSS_SHARE * self.max_wheel_speed

    @property
    def done(self) -> bool:
        return self.result is not None

    @property
    def started(self) -> float | None:
        """When the check began (s), None before (or since a restart)."""
        return self._stages[0][1] if self._stages else None

    def restart(self) -> None:
        """Forget a check that was interrupted (a stop): the next command starts it again."""
        self._sweep = None
        self._stages.clear()
        self._drifts, self._followed_to = ([], []), -math.inf
        self._moving_since = [math.inf, math.inf]
        self.commands.clear()
        self.poses.clear()

    def seen(self, taken: float, x: float, y: float, theta: float) -> None:
        if self.started is not None and not self.done:
            self.poses.append((taken, x, y, theta))

    def sent(self, now: float, v: float, w: float) -> None:
        if self.started is not None and not self.done:
            self.commands.append((now, v, w))

    def command(self, now: float) -> Command | None:
        """(v, w) to send at `now` (m/s, rad/s) while the check lasts; None once done."""
        if self.done:
            return None
        if not self._stages:
            self._stages.append((SWEEP, now))
        stage, begun = self._stages[-1]
        if now - begun >= STAGE_SECONDS[stage]:
            following = self._next_stage(stage, begun)
            if following is None:
                return None
            stage, begun = following, now
            self._stages.append((stage, begun))
        t = now - begun
        if stage == SWEEP:
            u = sweep_command(t, self.amplitude)
            return body_from_wheels(-u, u, self.wheel_base)
        left, right = self._crossing_wheels(now, t if stage == UP else t + STAGE_SECONDS[UP])
        return body_from_wheels(left, right, self.wheel_base)

    def _next_stage(self, stage: str, begun: float) -> str | None:
        """The stage after `stage` (begun at `begun` s, now over): the same again where a
        gap in its poses or ticks disturbed it (REPEATS at most), else the next, the sweep
        fitted on the way; None once the check is done (`result` set).
        """
        if self.repeats < REPEATS and self._disturbed(stage, begun, begun + STAGE_SECONDS[stage]):
            return stage
        if stage == SWEEP:
            self._sweep = self._fit_sweep(begun)
            if self._sweep is None:   # none fitted ends the check
                self.result = NOT_FITTED
                return None
            return UP
        if stage == UP:
            return DOWN
        self.result = self._fit_crossings()
        return None

    @property
    def repeats(self) -> int:
        """How many stages were run again."""
        return len(self._stages) - len({stage for stage, _ in self._stages})

    def _disturbed(self, stage: str, begin: float, end: float) -> bool:
        """Whether from `begin` to `end` (s) the poses taken or the commands sent have a gap
        longer than GAP: a process held up (the camera's, the robot's, this controller's)
        moves a robot as no command says, which a pass would take for a band. In a pass, a
        shorter gap in the poses too (HELD of their interval, motor_check_fit.held_up): the
        pass's fit leaves out the speeds about it, where its wheel may cross its band.
        """
        poses, ticks = (np.sort([row[0] for row in rows]) for rows in (self.poses, self.commands))
        poses, ticks = (times[(times >= begin) & (times <= end)] for times in (poses, ticks))
        if any(np.diff(np.concatenate([[begin], times])).max() > GAP for times in (poses, ticks)):
            return True
        return stage != SWEEP and len(pose_gaps(poses)) > 0

    def _crossing_wheels(self, now: float, t: float) -> tuple[float, float]:
        """Each wheel's command in the crossings at `now`, t s after they began: its centre
        (minus its drift as followed, _follow_drift) plus the offset (left -, right +: a
        turn), within the fastest wheel speed.
        """
        assert self._sweep is not None
        self._follow_drift()
        acts = now + self._sweep.delay
        offset = cross_offset(t, self.crossing, self.period)
        top = self.max_wheel_speed
        return (float(np.clip(-self._drift_at(0, acts) - offset, -top, top)),
                float(np.clip(-self._drift_at(1, acts) + offset, -top, top)))

    def _drift_at(self, k: int, at: float) -> float:
        """Wheel k's drift (m/s, as a command) at the wheels at `at` (s): a line through what
        the crossings measured over the last DRIFT_WINDOW s, where at least DRIFT_POINTS;
        else the last measured carried on at the sweep's rate; else the sweep's line.
        """
        assert self._sweep is not None
        sweep = self._sweep
        seen = np.array(self._drifts[k]).reshape(-1, 2)
        if not len(seen):
            return float(sweep.drift_at(k, np.array([at]))[0])
        recent = seen[seen[:, 0] >= seen[-1, 0] - DRIFT_WINDOW]
        if len(recent) >= DRIFT_POINTS:
            rate, value = np.polyfit(recent[:, 0] - seen[-1, 0], recent[:, 1], 1)
            return float(value + rate * (at - seen[-1, 0]))
        return float(seen[-1, 1] + sweep.drift[k, 1] * (at - seen[-1, 0]))

    def _follow_drift(self) -> None:
        """Each wheel's drift (m/s, as a command) from its speed over the last SPAN s of
        poses less what its commands ask for, where it moves (a swinging drift would carry
        the band out of the crossings' reach), kept in _drifts at the interval's middle.
        """
        assert self._sweep is not None
        sweep = self._sweep
        if len(self.poses) < 2 or len(self.commands) < 2:
            return
        seen = np.array(self.poses[-int(SPAN * 120) - 2:])
        last = seen[-1]
        earlier = np.flatnonzero(seen[:, 0] <= last[0] - SPAN + 1e-9)
        if not len(earlier) or last[0] <= self._followed_to:
            return
        self._followed_to = float(last[0])
        pair = seen[[earlier[-1], -1]]
        forward, turn = record.measured_rates(pair[:, 0], pair[:, 1:])
        speeds = wheel_speeds(float(forward[0]), float(turn[0]), self.wheel_base)
        sent = np.array(self.commands[-60:])
        wheels = np.stack(wheel_speeds(sent[:, 1], sent[:, 2], self.wheel_base))
        start, end = np.array([pair[0, 0] - sweep.delay]), np.array([pair[1, 0] - sweep.delay])
        mid = 0.5 * float(pair[0, 0] + pair[1, 0])
        for k in range(2):
            if abs(speeds[k]) < MOVING * self.crossing * sweep.gains[k]:
                self._moving_since[k] = math.inf
                continue
            self._moving_since[k] = min(self._moving_since[k], mid)
            if mid - self._moving_since[k] >= CLEAR:   # its motor has left the band behind
                asked = record.lagged_means(sent[:, 0], wheels[k], start, end, sweep.lag)[0]
                self._drifts[k].append((mid, speeds[k] / sweep.gains[k] - asked))

    def _arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The commands (times (k,), wheels (2, k)) and the poses (times (m,), (m, 3)), all
        of them, cleaned (motion_record.cleaned).
        """
        sent = np.array(self.commands).reshape(-1, 3)
        seen = np.array(self.poses).reshape(-1, 4)
        tc, cmd, tp, pose = record.cleaned(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:])
        return tc, np.stack(wheel_speeds(cmd[:, 0], cmd[:, 1], self.wheel_base)), tp, pose

    def _speeds(self, tp: FloatArray, pose: FloatArray, begin: float, end: float
                ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """motor_check_fit.spans of the poses (tp (m,) s, pose (m, 3)) taken from begin to
        end (s).
        """
        keep = (tp >= begin) & (tp <= end)
        return spans(tp[keep], pose[keep], self.wheel_base)

    def _fit_sweep(self, begun: float) -> SweepFit | None:
        """The sweep begun at `begun` (s), fitted."""
        tc, wheels, tp, pose = self._arrays()
        inside = ((tp >= begun) & (tp <= begun + SWEEP_SECONDS)).sum()
        if len(tc) < 2 or inside < MIN_SAMPLES:
            return None
        return fit_sweep(tc, wheels, *self._speeds(tp, pose, begun, begun + SWEEP_SECONDS),
                         self.amplitude)

    def _fit_crossings(self) -> ProbeResult:
        """The band from the last up pass and the last down pass (module doc)."""
        sweep = self._sweep
        assert sweep is not None
        half = STAGE_SECONDS[UP]
        last = dict(self._stages)   # each stage's last run
        tc, wheels, tp, pose = self._arrays()
        gains = (float(sweep.gains[0]), float(sweep.gains[1]))
        passes = []   # (starts, ends, measured (2, n), its middle s) of each pass
        for begun in (last[UP], last[DOWN]):
            passes.append((*self._speeds(tp, pose, begun + SETTLE, begun + half),
                           begun + 0.5 * half))
        bands, apart = [], 0.0
        for k in range(2):
            drifts = np.array(self._drifts[k]).reshape(-1, 2)
            up, down = (pass_band(starts, ends, measured[k], gains[k], (tc, wheels[k]),
                                  drifts[np.abs(drifts[:, 0] - middle) <= REACH * half],
                                  sweep.delay, sweep.lag, self.max_wheel_speed)
                        for starts, ends, measured, middle in passes)
            if up is None or down is None:
                return ProbeResult(gains, None, None, sweep.delay, sweep.lag, sweep.residual,
                                   self.repeats)
            bands.append(0.5 * (up + down))
            apart = max(apart, 0.5 * abs(up - down))
        band = 0.5 * (bands[0] + bands[1])
        levels = 0.5 * self.crossing * self.period / half   # the commands' levels apart
        bound = max(BAND_STEP * self.max_wheel_speed, levels, 0.5 * abs(bands[0] - bands[1]))
        if band <= bound:   # not told apart from none
            band = 0.0
        whole = check_gains(tc, wheels, *self._speeds(tp, pose, last[SWEEP], last[DOWN] + half),
                            sweep, band, self.max_wheel_speed)
        errors = None
        if whole is not None:
            gains = (float(whole[0][0]), float(whole[0][1]))
            errors = (float(whole[1][0]), float(whole[1][1]))
        return ProbeResult(gains, band, max(bound, apart), sweep.delay, sweep.lag,
                           sweep.residual, self.repeats, errors)


def replay_check(command_times: FloatArray, commands: FloatArray, pose_times: FloatArray,
                 poses: FloatArray, wheel_base: float, max_wheel_speed: float,
                 max_angular_rate: float = math.inf, period: float = 0.1,
                 tolerance: float = 0.05) -> ProbeResult | None:
    """A recorded motor check's result: the commands (k,) s and (k, 2) (v m/s, w rad/s)
    as sent and the poses (m,) s and (m, 3) as taken, replayed through a MotorProbe from the
    first command that drives (or the one before it: the sweep's first is a standstill).
    None where no check is recorded there: the sweep's commands differ from the probe's by
    more than `tolerance` of its amplitude, or it ends early.
    """
    driving = np.flatnonzero(np.abs(commands).max(axis=1) > 0.0) if len(commands) else None
    if driving is None or not len(driving):
        return None
    for first in (driving[0] - 1, driving[0]):
        if first >= 0:
            found = _replayed(command_times[first:], commands[first:], pose_times, poses,
                              MotorProbe(wheel_base, max_wheel_speed, max_angular_rate, period),
                              tolerance)
            if found is not None:
                return found
    return None


def _replayed(command_times: FloatArray, commands: FloatArray, pose_times: FloatArray,
              poses: FloatArray, probe: MotorProbe, tolerance: float) -> ProbeResult | None:
    """replay_check from the first of the commands given."""
    seen = 0
    for t, (v, w) in zip(command_times, commands, strict=True):
        while seen < len(pose_times) and pose_times[seen] <= t:
            probe.seen(float(pose_times[seen]), *map(float, poses[seen]))
            seen += 1
        wanted = probe.command(float(t))
        if wanted is None:
            return probe.result
        if t - (probe.started or t) < SWEEP_SECONDS:
            asked = np.subtract(wheel_speeds(*wanted, probe.wheel_base),
                                wheel_speeds(v, w, probe.wheel_base))
            if np.abs(asked).max() > tolerance * probe.amplitude:
                return None
        probe.sent(float(t), float(v), float(w))
    return None
