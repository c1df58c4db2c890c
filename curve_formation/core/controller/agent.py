"""One robot's controller, free of ROS: what a formation_controller node runs each tick.

Inputs arrive as plain numbers with stamps in seconds: the active curve, the robot's own pose
(arena frame, m and rad), its in-neighbours' target errors and the e-stop. How old an input is,
is judged by when it was received on this controller's clock (`received`; the stamp when not
given): stamps come from other hosts' clocks (the camera PC's, the neighbours'), which on lab
PCs without time sync can differ by more than any timeout. Stamps serve only differences
between samples of one source (the observer's elapsed time).
Each tick either computes a command with the paper's local law, or stops the robot (zero
velocity, at once) and says why: e-stop, no curve yet, own pose stale, outside the geofence,
no news from the leader, a neighbour missing, stale or on another curve; stopped, the
estimate is frozen. A motor check, where told, comes first, curve or not
(controller.motor_check: it turns in place; core.controller.motor_probe). Leader heartbeat:
every state carries the age of its sender's newest news of the leader, so a follower learns
when the leader is gone (core.controller.neighbourhood).
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import Command, FloatArray, Point, Pose
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.commands_sent import CommandsSent
from curve_formation.core.controller.curve_targets import (
    curve_targets,
    CurveTargets,
    error_on,
    moving_share,
)
from curve_formation.core.controller.driving import drive_direction, REVERSE_HYSTERESIS
from curve_formation.core.controller.gains import OBSERVER
from curve_formation.core.controller.inputs import (
    all_finite,
    is_stale,
    Neighbour,
    NO_OTHERS,
    receipt,
    shares_clock,
    State,
    Tick,
)
from curve_formation.core.controller.limits import inside_fence
from curve_formation.core.controller.motion_observer import MotionObserver
from curve_formation.core.controller.neighbourhood import Neighbourhood, NO_ERRORS
from curve_formation.core.controller.others import OtherRobots
from curve_formation.core.controller.plausibility import (
    error_problem,
    jump_problem,
    plausible_box,
    position_problem,
)
from curve_formation.core.controller.robot_model import RobotModel
from curve_formation.core.controller.safety import STOPPED, with_latency
from curve_formation.core.controller.step import agent_step, target_error
from curve_formation.core.formation.curves import Curve


def compiled_step(config: AgentConfig) -> Callable[..., Any]:
    """step.agent_step compiled (core.base.jit.compiled) and called once with the argument
    types of config's ticks, so that no tick waits for numba.
    """
    from curve_formation.core.base.jit import compiled, one_compiler_at_a_time
    k = len(config.neighbours)
    with one_compiler_at_a_time(agent_step):   # a team's processes share one compilation
        step = compiled(agent_step)
        step(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, np.zeros((k, 2)), np.arange(k),
             np.ones(k), 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *config.pc_disturbance,
             config.law, config.limits, NO_OTHERS, config.index - 1, config.avoidance, 0.0)
    return step


@dataclass
class AgentController:
    """Local law of one agent with its estimator; feed it inputs, call tick() at rate_hz."""

    config: AgentConfig
    dhat: list[float] = field(default_factory=lambda: [0.0, 0.0])

    def __post_init__(self) -> None:
        cfg = self.config
        self.curve: Curve | None = None
        self.curve_id: int | None = None
        self.curve_rate: Curve | None = None   # a moving curve's coefficient rate (1/s)
        self.s: float | None = None
        self.target: Point | None = None   # this agent's, carried to where it is used
        # every agent's target and its velocity on the current curve, as it held when dated,
        # and on the one before it, which converts a neighbour's error on the curve before
        # into one on this (_neighbour_error)
        self.curve_targets: CurveTargets | None = None
        self.previous_targets: CurveTargets | None = None
        self.pose: Pose | None = None
        self.pose_stamp: float | None = None
        self.pose_received: float | None = None   # s, this controller's clock (as every
        self.neighbourhood = Neighbourhood(cfg)   # *_received): states, news of the leader
        self.rejected = 0
        self.rejection = ''   # why the last input was rejected
        self.box = plausible_box(cfg.geofence)   # where a measured pose may lie (m)
        self.other_robots = OtherRobots()   # every robot's pose, for the safety filter
        self.filtered = 0           # ticks whose command the safety filter changed
        self.pose_dated: float | None = None   # when the own pose was taken, by its StampClock
        self.estop = False
        self.estop_reason = 'e-stop engaged'
        self.last_command: Command = (0.0, 0.0)
        self.observer = MotionObserver(self.config)   # the observer law's memory
        # +1: the law steers the point ahead of the axle, -1: the one behind it (reversing,
        # driving.drive_direction, chosen whenever the robot's pose comes); first_pose: the
        # next pose is a new curve's first, where the choice takes the sooner way outright
        self.front = 1.0
        self.first_pose = True
        self.robot = RobotModel(cfg)   # latency, motors' lag, wheel gains: told or estimated
        # The motions commanded (Sent), back to pose_timeout plus the latency: predict_pose's
        self.sent = CommandsSent(self.robot.commands_kept)   # and the observer's
        self.step = compiled_step(cfg) if cfg.compiled else agent_step
        # added to the command before the limits (m/s, rad/s): the config's, or as it varies
        self.pc_disturbance: Command = cfg.pc_disturbance

    def set_curve(self, curve: Curve, curve_id: int,
                  s_all: Sequence[float] | FloatArray | None, rate: Curve | None = None,
                  received: float = 0.0, valid_at: float | None = None) -> None:
        """Adopt a new curve; raises ValueError (AssignmentError) if it breaks the assumptions.

        s_all (n,): every agent's parameter as the sender (the curve server) assigned them;
        a curve without them is refused: agents never derive s_i themselves. rate: a moving
        curve's coefficient rate (1/s), received at `received` (s, this controller's clock)
        and holding at `valid_at` (s, the sender's clock; CurveClock): the target is carried
        forward from valid_at where the two clocks agree (within leader_timeout), else from
        its receipt, for at most leader_timeout, and its velocity added to the command
        (feed_forward).
        """
        dated = (valid_at if valid_at is not None
                 and abs(received - valid_at) <= self.config.leader_timeout else received)
        targets = curve_targets(curve, curve_id, s_all, rate, self.config.agent_count, dated,
                                self.curve_targets)
        self.first_pose = self.first_pose or int(curve_id) != self.curve_id
        self.curve, self.curve_id, self.curve_rate = curve, int(curve_id), rate
        if self.curve_targets is not None and self.curve_targets.curve_id != targets.curve_id:
            self.previous_targets = self.curve_targets
        self.curve_targets = targets
        self.s = float(targets.s[self.config.index - 1])
        self.target = targets.at(self.config.index, dated)

    @property
    def curve_received(self) -> float:
        """When the current curve held (s, this controller's clock; set_curve); 0 before."""
        return 0.0 if self.curve_targets is None else self.curve_targets.dated

    @property
    def ahead(self) -> Point:
        """This agent's target's velocity on the current curve (m/s; zero on a still one)."""
        if self.curve_targets is None:
            return 0.0, 0.0
        vx, vy = self.curve_targets.velocities[self.config.index - 1]
        return float(vx), float(vy)

    def _move_target(self, now: float) -> bool:
        """Carry a moving curve's target to `now` (s); False if the curve is too old."""
        if self.curve_rate is None or self.curve_targets is None:
            return True
        if now - self.curve_targets.dated > self.config.leader_timeout:
            return False
        self.target = self.curve_targets.at(self.config.index, now)
        return True

    def on_pose(self, x: float, y: float, theta: float, stamp: float,
                received: float | None = None) -> bool:
        """Own pose (arena frame) taken at `stamp` (s, its source's clock), received at
        `received` (s, this controller's clock; default: stamp). Returns False (and ignores it,
        saying why in `rejection`) if not finite or not believable (controller.plausibility:
        outside the arena and more, or further from the last pose than the robot can drive).
        """
        at = receipt(stamp, received)
        problem = ('not finite' if not all_finite(x, y, theta, stamp, at)
                   else position_problem(x, y, self.box))
        if problem is None and self.pose is not None and self.pose_stamp is not None:
            problem = jump_problem((self.pose[0], self.pose[1], self.pose_stamp), x, y, stamp,
                                   self.config.limits.max_wheel_speed)
        if problem is not None:
            return self.reject(f'own pose {problem}')
        self.pose, self.pose_stamp, self.pose_received = (x, y, theta), stamp, at
        self.observer.pose_seen(stamp, self._taken_at(stamp, at), (x, y, theta))
        self.pose_dated = self.neighbourhood.own_pose(stamp, at)
        self.robot.seen(self._taken_at(stamp, at), x, y, theta)
        if self.config.gains.reverse and self.target is not None:   # the point steered
            self.front = drive_direction(self.front, x, y, theta, *self.target, self.dhat[0],
                                         self.dhat[1], self.config.law, self.config.limits,
                                         0.0 if self.first_pose else REVERSE_HYSTERESIS)
            self.first_pose = False
        return True

    def on_neighbour(self, j: int, ex: float, ey: float, curve_id: int, stamp: float,
                     leader_age: float | None = None, received: float | None = None) -> bool:
        """In-neighbour j's error e_j (m) w.r.t. curve_id, from its pose at `stamp` (s, its
        clock), the age of its newest news of the leader (s), received at `received` (s, this
        controller's clock; default: stamp).

        Returns False (and ignores the message, saying why in `rejection`) if j is not an
        in-neighbour, a value is not finite or the error is larger than the arena.
        """
        at = receipt(stamp, received)
        values = (ex, ey, stamp, at) + (() if leader_age is None else (leader_age,))
        if j not in self.neighbourhood.neighbours:
            return self.reject(f'state of agent {j}, not an in-neighbour')
        if not all_finite(*values):
            return self.reject(f'state of neighbour {j} not finite')
        problem = error_problem(ex, ey, self.box)
        if problem is not None:
            return self.reject(f'state of neighbour {j}: {problem}')
        self.neighbourhood.heard(j, (ex, ey), curve_id, stamp, at, leader_age)
        return True

    def on_others(self, poses: ArrayLike, stamp: float, received: float | None = None) -> bool:
        """Every robot's pose (n, 3; arena frame; NaN rows: not seen) at `stamp` (s), received
        at `received` (s, this controller's clock; default: stamp), for the safety filter.
        Returns False (and ignores it) if it does not hold n rows.
        """
        given = np.asarray(poses, dtype=float)
        at = receipt(stamp, received)
        if given.shape != (self.config.agent_count, 3) or not all_finite(stamp, at):
            self.rejected += 1
            return False
        self.other_robots.update(given, self._taken_at(stamp, at), at)
        return True

    @property
    def others(self) -> FloatArray:
        """Every robot's latest pose (n, 3), for the safety filter (empty before any)."""
        return self.other_robots.poses

    def others_ahead(self, at: float) -> FloatArray:
        """Every robot's pose (n, 3) carried from when it was taken to `at` (s, this
        controller's clock) at its recent velocity, for the safety filter when commands act a
        latency after they leave (OtherRobots.ahead).
        """
        return self.other_robots.ahead(at, self.latency, self.config.limits.max_wheel_speed)

    def reject(self, why: str) -> bool:
        """Count a rejected input and keep why; False (what the on_* methods return)."""
        self.rejected += 1
        self.rejection = why
        return False

    def set_estop(self, engaged: bool, reason: str = 'e-stop engaged') -> None:
        """Engage (True) or release (False) the e-stop; `reason`: why stopped, as reported."""
        self.estop = bool(engaged)
        self.estop_reason = reason

    def state(self) -> State | None:
        """This agent's State for its out-neighbours, or None before it has pose and curve."""
        error = self.own_error()
        if (error is None or self.curve_id is None or self.pose_stamp is None
                or self.pose_dated is None):
            return None
        return State(error, self.curve_id, self.pose_stamp,
                     self.neighbourhood.leader_age(self.pose_dated))

    @property
    def leader_heard(self) -> float | None:
        """When the newest news of the leader was made (s, this controller's clock)."""
        return self.neighbourhood.leader_heard

    @leader_heard.setter
    def leader_heard(self, when: float | None) -> None:
        self.neighbourhood.leader_heard = when

    def _neighbour_error(self, j: int, nb: Neighbour) -> Point | None:
        """Neighbour j's error on this robot's curve: as sent, or, sent on the curve before
        (j has not had the new one yet, for a tick or two after a switch), its point measured
        against its target on this curve instead (xb_j = e_j + its old target), both targets
        where they were when j's pose was taken. None if on any other curve.
        """
        if nb.curve_id == self.curve_id:
            return nb.error
        old, new = self.previous_targets, self.curve_targets
        if (old is None or new is None or nb.curve_id != old.curve_id or nb.stamp is None
                or nb.received is None):
            return None
        return error_on(nb.error, j, old, new, self._taken_at(nb.stamp, nb.received))

    def own_error(self) -> Point | None:
        """e_i = xb_i - G(s_i) xi (m) from the latest pose (a moving curve's target taken
        when the pose came), or None.
        """
        if self.pose is None or self.target is None:
            return None
        if self.pose_received is not None and self.pose_stamp is not None:
            self._move_target(self._taken_at(self.pose_stamp, self.pose_received))
        return self._error_at(self.pose, self.target)

    def _taken_at(self, stamp: float, received: float) -> float:
        """When a pose was taken (s, this controller's clock): its stamp where the pose's
        source shares this clock (the pose is 0 to config.shared_clock s old by it), else its
        receipt.
        """
        return stamp if shares_clock(received - stamp, self.config.shared_clock) else received

    def _error_at(self, pose: Pose, target: Point) -> Point:
        return target_error(*pose, self.front, *target, self.config.gains.offset)

    def tick(self, now: float) -> Tick:
        """One control step at time `now` (s, this controller's clock)."""
        self.robot.update(now)
        tick = self._tick(now)   # the motion wanted, as the observer and predictions read it
        self.observer.log_sent(self.sent, now, tick.v, tick.w, tick.stopped is not None)
        tick.v, tick.w = self.robot.compensated(tick.v, tick.w, tick.checking)   # to the motors
        self.robot.sent(now, tick.v, tick.w)
        return tick

    @property
    def latency(self) -> float:
        """s from a command leaving to the wheels: as told, or as estimated online."""
        return self.robot.latency

    @property
    def motor_time_constant(self) -> float:
        """s: the motors' lag, as told, or as estimated online (estimate_motors)."""
        return self.robot.motor_time_constant

    def predicted(self, pose: Pose, stamp: float, received: float, now: float) -> Pose:
        """The pose taken at `stamp` (received at `received`) carried forward to when this
        tick's command reaches the wheels, `now` plus the command latency, by the commands
        acting since and the estimated drift (CommandsSent.predicted; arena frame).
        """
        law = self.config.law
        # the robot moves by its command plus the disturbance while driven (motors off at 0)
        drift = (0.0, 0.0) if law.on_pc else (law.k2 * self.dhat[0], law.k2 * self.dhat[1])
        return self.sent.predicted(pose, stamp, received, now, self.latency,
                                   self.config.shared_clock, drift)

    def _stale_input(self, now: float) -> str | None:
        """Why this tick must stop the robot before its law runs (e-stop, no curve, own pose
        missing, stale or outside the geofence); None if it may run.
        """
        cfg = self.config
        if self.estop:
            return self.estop_reason
        if (self.curve is None or self.target is None) and not self.robot.checking:
            return 'no curve received yet'   # the motor check needs none: it runs before
        pose, received = self.pose, self.pose_received
        if pose is None or self.pose_stamp is None or received is None:
            return 'no pose received yet'
        if is_stale(received, now, cfg.pose_timeout):
            return f'own pose stale ({now - received:.2f} s old)'
        if not inside_fence(pose[0], pose[1], cfg.geofence):
            return f'outside the geofence at ({pose[0]:.3f}, {pose[1]:.3f}) m'
        return None

    def _neighbour_errors(self, now: float) -> FloatArray | str:
        """The in-neighbours' errors (k, 2) on this robot's curve, or why the robot must stop
        (no news from the leader, a neighbour missing, stale or on another curve).
        """
        why = self.neighbourhood.leader_silent(now)
        if why is not None:
            return why
        errors: list[Point] = []
        for j, nb in self.neighbourhood.neighbours.items():
            why = self.neighbourhood.silent(j, now)
            if why is not None:
                return why
            error = self._neighbour_error(j, nb)
            if error is None:
                return f'neighbour {j} is on curve {nb.curve_id}, this robot on {self.curve_id}'
            errors.append(error)
        return np.array(errors, dtype=float) if errors else NO_ERRORS

    def _tick(self, now: float) -> Tick:
        cfg = self.config
        why = self._stale_input(now)
        if why is not None:
            return self._stop(why)
        assert self.pose is not None and self.pose_stamp is not None
        assert self.pose_received is not None
        pose, stamp = self.pose, self.pose_stamp   # pose: as measured, until predicted
        if self.robot.checking:   # the motor check: the law and its estimate wait
            command = self.robot.check_command(now, self.last_command, 1.0 / cfg.rate_hz)
            if command is not None:
                self.last_command = command
                return Tick(*command, error=self.own_error(), error_stamp=stamp,
                            curve_id=self.curve_id, dhat=(self.dhat[0], self.dhat[1]),
                            checking=True)
        if self.target is None:   # a motor check just done before any curve
            return self._stop('no curve received yet')
        aim = now   # when the target is taken: with the pose predicted, when this command acts
        if cfg.predict_pose:
            pose = self.predicted(pose, stamp, self.pose_received, now)
            aim = now + self.latency
        if not self._move_target(aim):
            return self._stop(f'moving curve not renewed for {now - self.curve_received:.2f} s')
        base = Tick(error=self._error_at(pose, self.target), error_stamp=stamp,
                    curve_id=self.curve_id)
        errors = self._neighbour_errors(now)
        if isinstance(errors, str):
            return self._stop(errors, base)
        if not cfg.is_leader:
            base.neighbour_stamps = self.neighbourhood.stamps()
        if cfg.avoidance.on and is_stale(self.other_robots.received, now, cfg.pose_timeout):
            return self._stop('no poses of the other robots yet'
                              if self.other_robots.received is None
                              else f"other robots' poses stale "
                              f'({now - self.other_robots.received:.2f} s old)', base)
        law, hood = cfg.law, self.neighbourhood
        if law.code == OBSERVER:
            self.observer.update(self.dhat, self.pose, stamp,
                                 self._taken_at(stamp, self.pose_received), self.sent,
                                 self.latency, self.motor_time_constant)
        period = 1.0 / cfg.rate_hz
        ahead = (0.0, 0.0)
        if cfg.feed_forward:
            moving = moving_share(aim, period, self.curve_received)
            ahead = (self.ahead[0] * moving, self.ahead[1] * moving)
        used = self.observer.estimate_used(self.dhat, now, self.latency, period)
        (v, w, ref_v, ref_w, shift_v, shift_w, dhat_v, dhat_w, _, _, code, limited, _, _, fx,
         fy) = self.step(
            *pose, self.front, *self.target, errors, hood.sources, hood.weights, hood.pin,
            *ahead, self.dhat[0], self.dhat[1], *used,
            *self.last_command, *self.pc_disturbance, law, cfg.limits,
            self.others_ahead(aim) if cfg.predict_pose and self.latency > 0.0 else self.others,
            cfg.index - 1, with_latency(cfg.avoidance, period, self.latency),
            self.robot.min_wheel_speed)
        self.dhat[:] = (dhat_v, dhat_w)
        # what the wheels give where their gains cut it (as the filter: a change after the law)
        v, w, ref, shift = self.robot.realised(v, w, (ref_v, ref_w), (shift_v, shift_w))
        if code == STOPPED:
            return self._stop('safety filter: no motion keeps the robots apart', base)
        self.filtered += code != 0
        self.observer.commanded(v, w, ref, shift, limited, self.pose, stamp, now,
                                self.robot.min_wheel_speed)
        self.last_command = (v, w)
        base.v, base.w, base.dhat, base.feedback = v, w, (self.dhat[0], self.dhat[1]), (fx, fy)
        base.pose = pose
        base.filtered = code != 0
        return base

    @property
    def updates(self) -> int:
        """The observer's updates so far."""
        return self.observer.updates

    def _stop(self, reason: str, base: Tick | None = None) -> Tick:
        """Stop the robot (zero velocity) for `reason`; base: the tick's outcome so far."""
        self.robot.stopped()
        tick = base or Tick()
        self.observer.stopped()
        tick.v, tick.w, tick.stopped = 0.0, 0.0, reason
        tick.dhat = (self.dhat[0], self.dhat[1])
        self.last_command = (0.0, 0.0)
        return tick
