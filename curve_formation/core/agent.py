"""One robot's controller, free of ROS: what a formation_controller node runs each tick.

Inputs arrive as plain numbers with stamps in seconds (any common clock): the active curve,
the robot's own pose (arena frame, m and rad), its in-neighbours' target errors and the e-stop.
Each tick either computes a command with the paper's local law, or stops the robot (zero
velocity, at once: stopping is never rate-limited) and says why: e-stop, no curve yet, own
pose stale, outside the geofence, no news from the leader, a neighbour missing, stale or on
another curve. While stopped the disturbance estimate is frozen, so it does not wind up, and
with an acceleration limit the robot ramps up again from rest.

Leader heartbeat: the leader's state carries its pose stamp; every follower forwards the newest
leader stamp it has received from any in-neighbour. Since the leader reaches every agent, each
agent learns within a few hops when the leader is gone (and stops after `leader_timeout`), and
learns again when it is back: no stop can lock itself in through a cycle of followers.
"""

from dataclasses import dataclass, field
import math
from typing import Optional

import numpy as np

from curve_formation.core.assignment import AssignmentError, check_assumptions
from curve_formation.core.control import (
    agent_input,
    body_velocity,
    follower_feedback,
    Gains,
    inside_fence,
    leader_feedback,
    limit_acceleration,
    NO_LIMITS,
    observer_input,
    observer_step,
    offset_point,
    saturate,
    WheelLimits,
)


def is_stale(stamp, now, timeout):
    """True when an input stamped `stamp` (s, None if never received) is older than timeout."""
    return stamp is None or now - stamp > timeout


def all_finite(*values):
    return all(math.isfinite(v) for v in values)


@dataclass(frozen=True)
class AgentConfig:
    """Static settings of one agent (index 1-based; agent 1 is the leader)."""

    index: int
    agent_count: int
    neighbours: tuple = ()          # ((j, a_ij), ...) in-neighbours, empty for the leader
    pinning: float = 0.0            # a follower's weight b on its own error (DirectedGraph)
    gains: Gains = Gains(1.0, 1.0, 0.01)
    limits: WheelLimits = NO_LIMITS
    rate_hz: float = 10.0
    pose_timeout: float = 0.5       # s
    neighbour_timeout: float = 0.5  # s
    leader_timeout: float = 1.0     # s without news from the leader (followers)
    geofence: Optional[tuple] = None  # (xmin, ymin, xmax, ymax), arena frame (m)
    max_linear_accel: float = math.inf   # m/s^2
    max_angular_accel: float = math.inf  # rad/s^2
    pc_disturbance: tuple = (0.0, 0.0)  # added to the command before the limits (m/s, rad/s)

    @property
    def is_leader(self):
        """The leader is the agent that receives from nobody."""
        return not self.neighbours


@dataclass
class Tick:
    """Outcome of one control step. v, w (m/s, rad/s) are what to send; 0, 0 when stopped."""

    v: float = 0.0
    w: float = 0.0
    stopped: Optional[str] = None
    error: Optional[tuple] = None     # own e_i (m), published for out-neighbours
    error_stamp: Optional[float] = None
    curve_id: Optional[int] = None
    dhat: tuple = (0.0, 0.0)
    feedback: Optional[tuple] = None
    neighbour_stamps: tuple = ()      # ((j, stamp s), ...) of the in-neighbour states used


@dataclass(frozen=True)
class State:
    """What an agent tells its out-neighbours.

    error e_i (m), curve id, pose stamp (s), and the newest leader stamp it knows (s, None
    before any news).
    """

    error: tuple
    curve_id: int
    stamp: float
    leader_stamp: Optional[float]


@dataclass
class _Neighbour:
    error: tuple = (0.0, 0.0)
    curve_id: Optional[int] = None
    stamp: Optional[float] = None


@dataclass
class AgentController:
    """Local law of one agent with its estimator; feed it inputs, call tick() at rate_hz."""

    config: AgentConfig
    dhat: list = field(default_factory=lambda: [0.0, 0.0])

    def __post_init__(self):
        self.curve = None
        self.curve_id = None
        self.s = None
        self.target = None
        self.pose = None
        self.pose_stamp = None
        self.neighbours = {j: _Neighbour() for j, _ in self.config.neighbours}
        self.rejected = 0
        self.leader_stamp = None
        self.estop = False
        self.last_command = (0.0, 0.0)
        # Observer law: the pose and stamp of the previous command's tick, and that command
        # where the disturbance enters (before a PC-injected disturbance, else as sent).
        self.anchor = None
        self.reference = (0.0, 0.0)

    def set_curve(self, curve, curve_id, s_all):
        """Adopt a new curve; raises ValueError (AssignmentError) if it breaks the assumptions.

        s_all (n,): every agent's parameter as the sender (the curve server) assigned them;
        a curve without them is refused: agents never derive s_i themselves.
        """
        n = self.config.agent_count
        if s_all is None:
            raise AssignmentError("the curve carries no agent parameters s_i (the curve "
                                  "server's curves do)")
        if len(s_all) != n:
            raise AssignmentError(f'the curve assigns {len(s_all)} agent parameters, this '
                                  f'team has {n} agents')
        s_all = np.array(s_all, dtype=float)
        check_assumptions(curve.basis, s_all)
        self.curve, self.curve_id = curve, int(curve_id)
        self.s = float(s_all[self.config.index - 1])
        self.target = tuple(curve.points([self.s])[0])

    def on_pose(self, x, y, theta, stamp):
        """Own pose (arena frame). Returns False (and ignores it) if not finite."""
        if not all_finite(x, y, theta, stamp):
            self.rejected += 1
            return False
        self.pose, self.pose_stamp = (x, y, theta), stamp
        if self.config.is_leader:
            self.leader_stamp = stamp
        return True

    def on_neighbour(self, j, ex, ey, curve_id, stamp, leader_stamp=None):
        """In-neighbour j's error e_j (m) w.r.t. curve_id, and the newest leader stamp it knows.

        Returns False (and ignores the message) if j is not an in-neighbour or a value is not
        finite.
        """
        values = (ex, ey, stamp) + (() if leader_stamp is None else (leader_stamp,))
        if j not in self.neighbours or not all_finite(*values):
            self.rejected += 1
            return False
        self.neighbours[j] = _Neighbour((ex, ey), int(curve_id), stamp)
        if leader_stamp is not None and (self.leader_stamp is None
                                         or leader_stamp > self.leader_stamp):
            self.leader_stamp = leader_stamp
        return True

    def set_estop(self, engaged):
        """Engage (True) or release (False) the e-stop."""
        self.estop = bool(engaged)

    def state(self):
        """This agent's State for its out-neighbours, or None before it has pose and curve."""
        error = self.own_error()
        if error is None:
            return None
        return State(error, self.curve_id, self.pose_stamp, self.leader_stamp)

    def own_error(self):
        """e_i = xb_i - G(s_i) xi (m) from the latest pose, or None."""
        if self.pose is None or self.target is None:
            return None
        bx, by = offset_point(*self.pose, self.config.gains.offset)
        return bx - self.target[0], by - self.target[1]

    def tick(self, now):
        """One control step at time `now` (s)."""
        cfg = self.config
        if self.estop:
            return self._stop('e-stop engaged')
        if self.curve is None:
            return self._stop('no curve received yet')
        if is_stale(self.pose_stamp, now, cfg.pose_timeout):
            return self._stop('no pose received yet' if self.pose_stamp is None else
                              f'own pose stale ({now - self.pose_stamp:.2f} s old)')
        if not inside_fence(self.pose[0], self.pose[1], cfg.geofence):
            return self._stop(f'outside the geofence at ({self.pose[0]:.3f}, '
                              f'{self.pose[1]:.3f}) m')
        ex, ey = self.own_error()
        base = Tick(error=(ex, ey), error_stamp=self.pose_stamp, curve_id=self.curve_id)
        if cfg.is_leader:
            fx, fy = leader_feedback(ex, ey)
        else:
            if is_stale(self.leader_stamp, now, cfg.leader_timeout):
                return self._stop('no news from the leader yet' if self.leader_stamp is None
                                  else f'no news from the leader for '
                                  f'{now - self.leader_stamp:.2f} s', base)
            for j, nb in self.neighbours.items():
                if nb.stamp is None:
                    return self._stop(f'no state from neighbour {j} yet', base)
                if is_stale(nb.stamp, now, cfg.neighbour_timeout):
                    return self._stop(f'neighbour {j} stale ({now - nb.stamp:.2f} s old)', base)
                if nb.curve_id != self.curve_id:
                    return self._stop(f'neighbour {j} is on curve {nb.curve_id}, this robot on '
                                      f'{self.curve_id}', base)
            fx, fy = follower_feedback(ex, ey, [nb.error for nb in self.neighbours.values()],
                                       [w for _, w in cfg.neighbours], cfg.pinning)
            base.neighbour_stamps = tuple((j, nb.stamp) for j, nb in self.neighbours.items())
        gains = cfg.gains
        period = 1.0 / cfg.rate_hz
        hold = gains.hold_period(cfg.rate_hz)
        if gains.law == 'observer':
            self._observe()
            v, w = observer_input(fx, fy, self.pose[2], self.dhat[0], self.dhat[1], gains.k1,
                                  gains.k2, gains.offset, hold, cfg.limits.wheel_base,
                                  cfg.limits.max_wheel_speed, cfg.limits.max_angular_rate)
        else:
            v, w, ddv, ddw = agent_input(fx, fy, ex, ey, self.pose[2], self.dhat[0],
                                         self.dhat[1], gains.k1, gains.k2, gains.offset,
                                         *gains.estimator_gains(), hold)
            self.dhat[0] += period * ddv
            self.dhat[1] += period * ddw
        law_command = (v, w)
        v, w = limit_acceleration(v + cfg.pc_disturbance[0], w + cfg.pc_disturbance[1],
                                  *self.last_command, period, cfg.max_linear_accel,
                                  cfg.max_angular_accel)
        # The wheel limits come last: whatever the ramp, no wheel exceeds its speed limit.
        v, w = saturate(v, w, cfg.limits.wheel_base, cfg.limits.max_wheel_speed,
                        cfg.limits.max_angular_rate)
        self.anchor = (self.pose, self.pose_stamp)
        self.reference = law_command if any(cfg.pc_disturbance) else (v, w)
        self.last_command = (v, w)
        base.v, base.w, base.dhat, base.feedback = v, w, tuple(self.dhat), (fx, fy)
        return base

    def _observe(self):
        """Observer law: move dhat towards (motion measured since the last tick - command) / k2.

        The motion is the constant (v, w) that carries the previous tick's pose to the current
        one over the difference of their stamps; without a newer pose nothing is updated.
        """
        if self.anchor is None:
            return
        (x0, y0, th0), stamp0 = self.anchor
        elapsed = self.pose_stamp - stamp0
        if elapsed <= 0.0:
            return
        measured = body_velocity(x0, y0, th0, *self.pose, elapsed)
        blend = 1.0 - math.exp(-self.config.gains.observer_rate * elapsed)
        self.dhat[:] = observer_step(*self.dhat, *measured, *self.reference,
                                     self.config.gains.k2, blend)

    def _stop(self, reason, base=None):
        tick = base or Tick()
        self.anchor = None
        tick.v, tick.w, tick.stopped, tick.dhat = 0.0, 0.0, reason, tuple(self.dhat)
        self.last_command = (0.0, 0.0)
        return tick
