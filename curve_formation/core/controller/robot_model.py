"""What a controller knows of its link and its robot: the commands' latency and the motors'
lag, each as told or as estimated online (controller.estimate_latency, estimate_motors;
core.controller.link_estimate), each wheel's gain as estimated online
(core.controller.wheel_estimate) and the motors' dead band, as told or estimated online
(core.controller.dead_band_estimate); the motor check's gains and band before any of those
(controller.motor_check: core.controller.motor_probe). Times in s on the controller's clock.
"""

import math

from curve_formation.core.base.shapes import Command
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.dead_band_estimate import OnlineDeadBand
from curve_formation.core.controller.limits import limit_acceleration, saturate, timed_by
from curve_formation.core.controller.link_estimate import ONLINE_LAGS, OnlineLink
from curve_formation.core.controller.motor_probe import MotorProbe, ProbeResult
from curve_formation.core.controller.wheel_estimate import OnlineGains, wheel_record
from curve_formation.core.formation.dynamics import body_from_wheels, wheel_speeds


def commands_kept(rate_hz: float, pose_timeout: float, longest: float) -> int:
    """How many commands sent a controller keeps at rate_hz (Hz): as far back as a pose may
    be (pose_timeout, s) plus the longest the latency may be (s).
    """
    return int(math.ceil(rate_hz * (pose_timeout + longest))) + 2


class RobotModel:
    """latency (s: a command's delay to the wheels), motor_time_constant (s), wheel_gains
    ((left, right) speed per unit of command, or None), min_wheel_speed (m/s: the motors'
    dead band, 0: none known), kept up to date from the commands sent (sent) and the poses
    taken (seen) where estimated.
    """

    def __init__(self, cfg: AgentConfig) -> None:
        self.latency = cfg.command_latency
        self.motor_time_constant = cfg.motor_time_constant
        estimate_motor = cfg.estimate_motors and cfg.motor_time_constant <= 0.0   # told wins
        self.link = (OnlineLink(self.latency, cfg.rate_hz, cfg.motor_time_constant,
                                cfg.estimate_latency, estimate_motor)
                     if cfg.estimate_latency or estimate_motor else None)
        self.limits = cfg.limits
        # the commands and poses the wheels' fits share (gains, dead band)
        motion = (wheel_record(cfg.rate_hz)
                  if cfg.estimate_motors and cfg.limits.wheel_base > 0.0 else None)
        limits = self.limits
        self.wheels = (None if motion is None
                       else OnlineGains(motion, limits.wheel_base, limits.max_wheel_speed))
        self.min_wheel_speed = cfg.min_wheel_speed
        self.band = (OnlineDeadBand(motion, limits.wheel_base, limits.max_wheel_speed)
                     if motion is not None and cfg.min_wheel_speed <= 0.0   # told wins
                     and math.isfinite(limits.max_wheel_speed) else None)
        self.told_band = cfg.min_wheel_speed > 0.0
        self.check = (MotorProbe(limits.wheel_base, limits.max_wheel_speed,
                                 limits.max_angular_rate, 1.0 / cfg.rate_hz)
                      if cfg.motor_check and timed_by(limits) else None)
        self.records = [r for r in (self.link, motion, self.check) if r is not None]
        # how many commands sent a controller keeps: as far back as a pose may be
        # (pose_timeout) plus the longest the latency may be
        longest = (max(cfg.command_latency, float(ONLINE_LAGS.max()))
                   if cfg.estimate_latency else cfg.command_latency)
        self.commands_kept = commands_kept(cfg.rate_hz, cfg.pose_timeout, longest)

    def seen(self, taken: float, x: float, y: float, theta: float) -> None:
        """The robot's pose (m, rad) taken at `taken`."""
        for record in self.records:
            record.seen(taken, x, y, theta)

    def update(self, now: float) -> None:
        """Before a tick at `now`: the estimates due by then."""
        if self.link is not None:
            self.latency = self.link.update(now)
            self.motor_time_constant = self.link.motor_time_constant
        if self.wheels is not None:
            self.wheels.update(now, self.latency, self.motor_time_constant)
        if self.band is not None:
            self.band.update(now, self.latency, self.motor_time_constant)
            if self.band.band is not None and self.checked_band is None:
                self.min_wheel_speed = self.band.band

    @property
    def checking(self) -> bool:
        """True while the motor check is due or under way."""
        return self.check is not None and not self.check.done

    def check_command(self, now: float, last: Command, period: float) -> Command | None:
        """The motor check's command (v m/s, rad/s) at `now`, within the turn and wheel
        limits and, from the `last` sent `period` s before, the acceleration limits; None
        once it is done (its band then taken where none is told).
        """
        assert self.check is not None
        command = self.check.command(now)
        if command is None:
            band = self.checked_band
            if band is not None and not self.told_band:
                self.min_wheel_speed = band
            return None
        limits = self.limits
        v, w = saturate(*command, limits.wheel_base, limits.max_wheel_speed,
                        limits.max_angular_rate)
        return limit_acceleration(v, w, *last, period, limits.max_linear_accel,
                                  limits.max_angular_accel)

    def stopped(self) -> None:
        """The robot was stopped: a motor check under way starts again when it may move."""
        if self.check is not None and self.checking:
            self.check.restart()

    @property
    def trusted_check(self) -> ProbeResult | None:
        """What the motor check found, once done and trusted (ProbeResult.trusted); else None."""
        found = None if self.check is None else self.check.result
        return found if found is not None and found.trusted else None

    @property
    def checked_band(self) -> float | None:
        """m/s: the band the motor check found, where trusted (None: no check, none fitted,
        none seen or not trusted).
        """
        found = self.trusted_check
        return found.band if found is not None and found.band else None

    def sent(self, now: float, v: float, w: float) -> None:
        """The command (v m/s, w rad/s) sent at `now`."""
        for record in self.records:
            record.sent(now, v, w)

    def compensated(self, v: float, w: float, checking: bool = False) -> Command:
        """(v, w) to send (m/s, rad/s) for the motion (v, w): with wheel_gains estimated,
        each wheel's command divided by its gain (a wheel that turns 3 % fast is asked 3 %
        less), both wheels scaled down together where that would pass max_wheel_speed or
        max_angular_rate; (v, w) itself otherwise, and for the motor check's commands
        (`checking`), which measure the wheels as they are.
        """
        gains = self.wheel_gains
        if gains is None or checking or (v == 0.0 and w == 0.0):
            return v, w
        limits = self.limits
        left, right = wheel_speeds(v, w, limits.wheel_base)
        left, right = left / gains[0], right / gains[1]
        v, w = body_from_wheels(left, right, limits.wheel_base)
        over = max(max(abs(left), abs(right)) / limits.max_wheel_speed
                   if limits.max_wheel_speed > 0.0 else 0.0,
                   abs(w) / limits.max_angular_rate if limits.max_angular_rate > 0.0 else 0.0)
        return (v / over, w / over) if over > 1.0 else (v, w)

    @property
    def wheel_gains(self) -> tuple[float, float] | None:
        """(left, right) as estimated online, else as the motor check found them where
        trusted (trusted_check), or None.
        """
        online = None if self.wheels is None else self.wheels.gains
        found = self.trusted_check
        return online if online is not None or found is None else found.gains
