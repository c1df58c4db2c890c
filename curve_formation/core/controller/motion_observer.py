"""The observer law's memory between a controller's ticks: which motion it measures (from
the pose of the last command's tick, or a later one that answers the current estimate),
what was commanded over it (the command acting, or what the commands realised through a
latency and the motors' lag), and the estimate a command uses (carried ahead at its rate,
second order). The update itself is observer.observer_update, as the batch simulator makes
it.

Poses in the arena frame (m, rad); times in s on the controller's clock; commands in m/s and
rad/s.
"""

from collections import deque

from curve_formation.core.base.shapes import Command, Pose
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.commands_sent import CommandsSent
from curve_formation.core.controller.inputs import MAX_PREDICTION, Sent
from curve_formation.core.controller.observer import carried_estimate, observer_update
from curve_formation.core.formation.dynamics import (
    body_from_wheels,
    measured_velocity,
    wheel_speeds,
)


# The poses an observer keeps to begin a motion at (a second at 30 Hz), and the shortest
# motion (s) it measures from a later start than the last tick's pose.
RECENT_POSES = 32
MIN_OBSERVED = 0.05


class MotionObserver:
    """One controller's observer state; `updates` counts its updates so far."""

    def __init__(self, config: AgentConfig) -> None:
        self.config = config
        # the last poses (stamp, when taken on the controller's clock, pose), where a motion
        # that answers the estimate may begin (answering_start)
        self.recent_poses: deque[tuple[float, float, Pose]] = deque(maxlen=RECENT_POSES)
        # the pose and stamp of the previous command's tick and that tick's time; the last
        # command where the disturbance enters (before a PC-injected disturbance, else as
        # sent), what the safety filter changed, whether the wheel limits cut it
        self.anchor: tuple[Pose, float, float] | None = None
        self.reference: Command = (0.0, 0.0)
        self.shift: Command = (0.0, 0.0)
        self.limited = False
        self.idle = False   # the last command's wheels all within the dead band
        # observer.ray_growth's state: (factor, last right, last left wheel speed m/s)
        self.ray: tuple[float, float, float] = (1.0, 0.0, 0.0)
        # observer_order 2: how fast the estimate changes (per s), and the updates since the
        # wheel limits last cut a command
        self.rate: tuple[float, float] = (0.0, 0.0)
        self.tracking = 0
        # the updates so far, and when the last one's motion ended (None: none since the
        # robot last stopped)
        self.updates = 0
        self.observed_until: float | None = None
        # when the estimate's disturbance held: the middle of the motion it was learnt from
        self.estimated_at = 0.0

    def pose_seen(self, stamp: float, taken: float, pose: Pose) -> None:
        """A pose of the robot stamped `stamp`, taken at `taken` (the controller's clock)."""
        self.recent_poses.append((stamp, taken, pose))

    def commanded(self, v: float, w: float, reference: Command, shift: Command,
                  limited: bool, measured: Pose, stamp: float, now: float) -> None:
        """The command (v, w) sent at `now` from the pose `measured` stamped `stamp`, with
        agent_command's reference, shift and limited.
        """
        self.anchor = (measured, stamp, now)
        self.reference = self._dead_band_reference(v, w, *reference)
        self.shift = shift
        self.limited = limited

    def stopped(self) -> None:
        """The robot was stopped: nothing is learnt from the time it stands."""
        self.anchor = None
        self.observed_until = None
        self.reference = self.shift = (0.0, 0.0)
        self.limited = False
        self.ray = (1.0, 0.0, 0.0)

    def sent(self, at: float, v: float, w: float, stopped: bool) -> Sent:
        """The record of the command (v, w) sent at `at` (stopped: a stop)."""
        return Sent(at, v, w, self.reference, self.shift, self.limited,
                    not stopped and not self.idle, self.updates)

    def estimate_used(self, dhat: list[float], now: float, latency: float,
                      period: float) -> Command:
        """The estimate a command sent at `now` compensates: carried from the middle of the
        motion it was learnt from (a pose's age counts) to the middle of the period the
        command holds for, once it acts (observer.carried_estimate).
        """
        ahead_by = min(max(now + latency + period / 2.0 - self.estimated_at, 0.0),
                       period + latency + MAX_PREDICTION)
        return carried_estimate(dhat[0], dhat[1], *self.rate, self.tracking, ahead_by,
                                self.config.law)

    def update(self, dhat: list[float], pose: Pose, stamp: float, ended: float,
               sent: CommandsSent, latency: float, tau: float) -> None:
        """Move dhat (in place) towards (motion measured since the last tick - command) / k2.

        pose: the robot's latest, stamped `stamp`, taken at `ended`; latency and tau (s):
        the commands' latency and the motors' lag, as told or estimated. The motion is the
        constant (v, w) that carries the previous tick's pose to it over the difference of
        their stamps; the command is the one sent at the previous tick, or with a command
        latency, a motor time constant or a motion that began before the previous tick (a
        pose older than the time between poses) what the commands realised over that motion;
        nothing is learnt while the motors were off. With a command latency, or a pose taken
        before the previous tick (a camera's frame older than a period), the observer waits
        for a motion made wholly under commands sent after its last update (their
        `estimate`), and blends over the time since that update: no delay enters the
        estimate's loop (docs/control-laws.md). Without a newer pose nothing is updated.
        """
        if self.anchor is None:
            return
        (x0, y0, th0), stamp0, ticked = self.anchor
        elapsed = stamp - stamp0
        if elapsed <= 0.0:
            return
        # A pose taken before the last tick cannot show that tick's command: waiting for one
        # that can keeps the pose's age out of the estimate's loop as it keeps the latency.
        waits = latency > 0.0 or ended < ticked
        acting = self._acting_over(sent, latency, tau, elapsed, ended, ticked, waits)
        if acting is None or not acting.driven:
            return
        if waits and acting.estimate < self.updates:
            # the motion does not answer the current estimate yet: its part from the first
            # pose that can, if one is held
            later = self._answering_start(sent, latency, ended - elapsed, ended)
            if later is None:
                return
            (x0, y0, th0), stamp0 = later
            elapsed = stamp - stamp0
            acting = self._acting_over(sent, latency, tau, elapsed, ended, ticked, waits)
            if acting is None or not acting.driven or acting.estimate < self.updates:
                return
        measured_v, measured_w = measured_velocity(x0, y0, th0, *pose, elapsed)
        self.estimated_at = ended - elapsed / 2.0
        if waits and self.observed_until is not None:   # blended over the time since the last
            elapsed = max(elapsed, ended - self.observed_until)
        self.observed_until = ended
        (dhat_v, dhat_w, rate_v, rate_w, growth, last_right, last_left,
         self.tracking) = observer_update(dhat[0], dhat[1], *self.rate, *self.ray,
                                          self.tracking, measured_v, measured_w,
                                          *acting.reference, *acting.shift, acting.limited,
                                          self.config.law, self.config.limits, elapsed)
        dhat[:] = (dhat_v, dhat_w)
        self.rate = (rate_v, rate_w)
        self.ray = (growth, last_right, last_left)
        self.updates += 1

    def _acting_over(self, sent: CommandsSent, latency: float, tau: float, elapsed: float,
                     ended: float, ticked: float, waits: bool) -> Sent | None:
        """What was commanded over the motion of `elapsed` s ending at `ended` that the
        observer measures at the tick after `ticked`.
        """
        # A motion that began before the last tick (its first pose older than that tick) was
        # partly made under the command before: the commands are weighed by how long each
        # acted in it, and whether the limits cut is the last tick's command's, as when the
        # motion is wholly its own (the search along its ray is that command's).
        mixed = ended - elapsed < ticked - 1e-9
        if tau > 0.0 or waits:
            return sent.realised(ended, elapsed, latency, tau, self.updates)
        if mixed:
            acting = sent.realised(ended, elapsed, latency, tau, self.updates)
            last = sent.acting(ticked, latency)
            if acting is not None and last is not None:
                acting = acting._replace(limited=last.limited)
            return acting
        return sent.acting(ticked, latency)

    def _answering_start(self, sent: CommandsSent, latency: float, begins: float,
                         ends: float) -> tuple[Pose, float] | None:
        """A later start (pose, stamp) for a motion from `begins` to `ends` that began
        before the first command sent after the last update acted: the first pose taken from
        then on, at least MIN_OBSERVED before the end; None if the motion needs none or no
        such pose is held.
        """
        answering = sent.first_acting_after(self.updates, latency)
        if answering is None or begins >= answering - 1e-9:
            return None
        for stamp, taken, pose in self.recent_poses:
            if taken >= answering - 1e-9:
                return (pose, stamp) if taken <= ends - MIN_OBSERVED else None
        return None

    def _dead_band_reference(self, v: float, w: float, ref_v: float, ref_w: float
                             ) -> Command:
        """The observer's reference for the command (v, w) sent: with a dead band
        (min_wheel_speed), less what the wheels commanded below it will not do, so that a
        robot standing still under a command too small to move it is not taken for a
        disturbance holding it back. Both wheels in the band: the motors are idle (nothing is
        learnt from that period, as when stopped).
        """
        cfg = self.config
        self.idle = False
        if cfg.min_wheel_speed <= 0.0 or cfg.limits.wheel_base <= 0.0:
            return ref_v, ref_w
        left, right = wheel_speeds(v, w, cfg.limits.wheel_base)
        still_right = abs(right) < cfg.min_wheel_speed
        still_left = abs(left) < cfg.min_wheel_speed
        self.idle = still_right and still_left
        moved_v, moved_w = body_from_wheels(0.0 if still_left else left,
                                            0.0 if still_right else right,
                                            cfg.limits.wheel_base)
        return ref_v + moved_v - v, ref_w + moved_w - w
