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


# The share of its limits (the larger of its fastest wheel's and its turn's) from which the
# law's command, as it nears them, is scaled up to what the wheels can give (RobotModel.
# realised): a robot whose wheels are faster than nominal then drives as fast as they let it
# where the law asks for its fastest (sending each wheel its command divided by its gain
# alone held such robots to the nominal speed: arena_demo's checked robots settled up to 6 %
# later than without the gains; docs/link.md).
FULL_FROM = 0.9
# What each estimate's bound is (RobotModel.estimates): the latency's and the motors' lag's,
# how far the online fits alone scatter (link_estimate.OnlineLink.bounds); the wheel
# gains', GAIN_BOUND standard errors of their fit (a gain came out within 3 of them where
# tested); the dead band's, its fit's (the grid's step or its two fits' difference).
GAIN_BOUND = 3.0


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
            self.wheels.trade = self._trade()
            self.wheels.moved(self.latency, self.motor_time_constant)
            self.wheels.update(now, self.latency, self.motor_time_constant)
        if self.band is not None:
            self.band.update(now, self.latency, self.motor_time_constant)
            if self.band.band is not None and self.checked_band is None:
                self.min_wheel_speed = self.band.band

    def _trade(self) -> tuple[float, float]:
        """(latency, motors' lag) s: how far the wheel gains' fit lets them be traded, one
        longer and the other shorter (the fits trade them: docs/link.md): the lag's bound
        where estimated online (link_estimate.OnlineLink.bounds), the latency moved as far
        where it is estimated too; (0, 0) where the lag is told; infinite while it is
        estimated but not yet taken with a bound.
        """
        link = self.link
        if link is None or len(link.taus) <= 1:   # the lag told
            return 0.0, 0.0
        if not link.motor_taken or link.bounds is None:
            return math.inf, math.inf
        lag = link.bounds[1]
        return (lag if len(link.lags) > 1 else 0.0), lag

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
        less), scaled down (curvature kept) only where that would pass max_wheel_speed or
        max_angular_rate; (v, w) itself otherwise, and for the motor check's commands
        (`checking`), which measure the wheels as they are. The motion is realised's: any
        use of the wheels' spare speed is decided there, once.
        """
        if checking:
            return v, w
        cv, cw, _, over = self._divided(v, w)
        scale = 1.0 / over if over > 1.0 else 1.0
        return cv * scale, cw * scale

    def realised(self, v: float, w: float, reference: Command, shift: Command
                 ) -> tuple[float, float, Command, Command]:
        """The motion (v m/s, w rad/s) the wheels give for the law's (v, w), as far as the
        estimated gains tell, scaled (curvature kept): down to what keeps the divided
        command (compensated) within the limits, and from FULL_FROM of the limits on, as
        the law's command nears them, up to exactly those limits, so that wheels faster
        than nominal are used to the full where the law asks for its fastest without a jump
        in the commands. The observer's `reference` and the safety filter's `shift`
        (agent_command's) each with that change added, so that the observer expects what
        the wheels give. Without gains, or unscaled, all as they were.
        """
        _, _, asked, over = self._divided(v, w)
        if over <= 0.0:   # no gains, no motion or no limits
            return v, w, reference, shift
        room = 1.0 / over   # the largest scale within the limits
        ramp = min(max((asked - FULL_FROM) / (1.0 - FULL_FROM), 0.0), 1.0)
        scale = min(1.0 + ramp * (room - 1.0), room)
        if scale == 1.0:
            return v, w, reference, shift
        dv, dw = v * scale - v, w * scale - w
        return (v + dv, w + dw, (reference[0] + dv, reference[1] + dw),
                (shift[0] + dv, shift[1] + dw))

    def _divided(self, v: float, w: float) -> tuple[float, float, float, float]:
        """(cv, cw, asked, over) for the motion (v, w): the command with each wheel's
        divided by its gain; `asked`, the motion's share of the limits (the larger of the
        fastest wheel's share of max_wheel_speed and |w|'s of max_angular_rate); `over`,
        the command's share of them (above 1: past them; 0 with no limits). (v, w, 0, 0)
        without gains or with no motion.
        """
        gains = self.wheel_gains
        if gains is None or (v == 0.0 and w == 0.0):
            return v, w, 0.0, 0.0
        limits = self.limits
        left, right = wheel_speeds(v, w, limits.wheel_base)
        asked = max(_share(max(abs(left), abs(right)), limits.max_wheel_speed),
                    _share(abs(w), limits.max_angular_rate))
        left, right = left / gains[0], right / gains[1]
        cv, cw = body_from_wheels(left, right, limits.wheel_base)
        over = max(_share(max(abs(left), abs(right)), limits.max_wheel_speed),
                   _share(abs(cw), limits.max_angular_rate))
        return cv, cw, asked, over

    def estimates(self) -> dict[str, object]:
        """What this controller holds of its robot, for reports: for each of
        command_latency (s), motor_time_constant (s), wheel_gains ([left, right]) and
        dead_band (m/s of wheel speed), its value, `<name>_bound` (+- the same units, GAIN_BOUND's
        comment; None where told or unknown) and `<name>_from`: 'told' (the experiment's, or
        its default), 'online' (estimated while driving), 'check' (the motor check's) or
        None (no value: wheel gains and dead band unknown).
        """
        link = self.link
        bounds = None if link is None else link.bounds
        out: dict[str, object] = {
            'command_latency': float(self.latency),
            'command_latency_bound': None,
            'command_latency_from': 'told',
            'motor_time_constant': float(self.motor_time_constant),
            'motor_time_constant_bound': None,
            'motor_time_constant_from': 'told'}
        if link is not None and link.taken and bounds is not None:
            out.update(command_latency_bound=bounds[0], command_latency_from='online')
        if link is not None and link.motor_taken and bounds is not None:
            out.update(motor_time_constant_bound=bounds[1], motor_time_constant_from='online')
        check = self.trusted_check
        gains, errors, source = self._gains_found()
        out.update(wheel_gains=None if gains is None else [float(g) for g in gains],
                   wheel_gains_bound=None if errors is None
                   else [GAIN_BOUND * float(e) for e in errors], wheel_gains_from=source)
        band, bound, source = None, None, None
        learnt = None if self.band is None else self.band.found
        if self.told_band:
            band, source = self.min_wheel_speed, 'told'
        elif check is not None and check.band is not None and (
                check.band or learnt is None or learnt.band is None):   # a check's 0: none
            band, bound, source = check.band, check.bound, 'check'
        elif learnt is not None and learnt.band is not None:
            band, bound, source = learnt.band, learnt.bound, 'online'
        out.update(dead_band=None if band is None else float(band),
                   dead_band_bound=None if bound is None else float(bound),
                   dead_band_from=source)
        return out

    @property
    def wheel_gains(self) -> tuple[float, float] | None:
        """(left, right) as estimated online, else as the motor check found them where
        trusted (trusted_check), or None.
        """
        return self._gains_found()[0]

    @property
    def top_speed(self) -> float:
        """m/s: the robot's fastest straight drive, its slower wheel's gain (wheel_gains;
        1 where none are known) times max_wheel_speed; NaN without a finite wheel limit.
        """
        limit = self.limits.max_wheel_speed
        if not 0.0 < limit < math.inf:
            return math.nan
        gains = self.wheel_gains
        return limit * (1.0 if gains is None else min(gains))

    def _gains_found(self) -> tuple[tuple[float, float] | None,
                                    tuple[float, float] | None, str | None]:
        """(gains, their standard errors, 'online' or 'check'): wheel_gains' with where they
        came from; (None, None, None) without any.
        """
        online = None if self.wheels is None else self.wheels.found
        if online is not None and online.gains is not None:
            return online.gains, online.errors, 'online'
        check = self.trusted_check
        if check is not None:
            return check.gains, check.gain_errors, 'check'
        return None, None, None


def _share(value: float, limit: float) -> float:
    """value over limit, or 0 where the limit is none (0 or infinity)."""
    return value / limit if 0.0 < limit < math.inf else 0.0
