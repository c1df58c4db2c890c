"""formation_controller: one robot's leader/follower law, in namespace /robot_<i>.

Subscribes: pose (own, PoseStamped, arena frame), /robot_<j>/formation_state of each
in-neighbour j, /formation/curve. Publishes at `rate_hz`: cmd_vel (Twist), and on every pose
its formation_state (target error e_i for out-neighbours), and every tick its
disturbance_estimate (stamped with the pose that tick used) and /diagnostics, and its robot's
top_speed whenever that changes (its wheels' gains measured: the curve server's assignment
weighs trips by it). Any missing or
stale input gives a zero Twist and a warning, never a stale command. All the maths is
core.controller.agent.AgentController.
"""

from functools import partial
import math
from types import SimpleNamespace
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Twist
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from curve_formation import diagnostics, scheduling
from curve_formation.core.controller.agent import AgentController
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.disturbance import RunTime, varied
from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.inputs import State
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.plausibility import bounded_command
from curve_formation.core.controller.safety import Avoidance, AVOIDANCE_OFF
from curve_formation.core.controller.settings import broken_rules, DEFAULT_RATE_HZ, SETTINGS
from curve_formation.core.controller.wheel_estimate import GAIN_ERROR
from curve_formation.core.formation.assignment import AssignmentError
from curve_formation.interface import robot_name
from curve_formation.nodes import messages, shared_readers, topics
from curve_formation.nodes.command_source import CommandSourceWatch
from curve_formation.nodes.estop import estop_uses, EstopHolder
from curve_formation.nodes.guard import rejections
from curve_formation.nodes.params import (
    declare_parameters,
    node_variations,
    Param,
    ParameterError,
)
from curve_formation.nodes.readiness import REPORTED, subscribe_to_curve
from curve_formation.nodes.runtime import LastMessages, now_seconds, run_node
from curve_formation.nodes.topics import Use


NODE_NAME = 'formation_controller'   # also its console script's name
# The parameters computed from several experiment keys (agents, graph, arena, disturbance;
# config.agents.agent_configs) or that only a node has; then one per controller setting,
# as controller.settings declares it.
PARAMETERS = (
    Param('index', 'int', None, "this robot's agent number i (1 = leader)", low=1),
    Param('agent_count', 'int', None, 'number of agents n in the formation', low=1),
    Param('role', 'string', 'follower', 'leader (receives from nobody) or follower',
          choices=('leader', 'follower')),
    Param('in_neighbours', 'int[]', [], 'agents j this robot receives from (empty for the '
          'leader)'),
    Param('weights', 'double[]', [], 'edge weights a_ij, one per in-neighbour (empty = all 1)'),
    Param('rate_hz', 'double', DEFAULT_RATE_HZ, 'control rate (Hz)', positive=True),
    Param('geofence', 'double[]', [], '[xmin, ymin, xmax, ymax] (m): outside it the robot is '
          'stopped; empty = no fence'),
    Param('avoidance', 'bool', False, 'safety filter on: keep bodies apart and inside the '
          "arena (core.controller.safety), from every robot's pose on /formation/robot_poses"),
    Param('arena', 'double[]', [], '[width, height] (m) of the walls the filter keeps the '
          'body inside; empty = no walls'),
    Param('pc_disturbance', 'double[]', [0.0, 0.0], 'disturbance [d_v, d_w] added to the '
          "command before the wheel limits (the paper's arena experiment); normally zero"),
    Param('disturbance_varies', 'string', '', "how pc_disturbance changes over the run's time "
          "(s since the first curve, from the curve's clock): the experiment's "
          "disturbance.varies as JSON (sines, steps, ramps); '' = constant"),
    Param('frame_id', 'string', 'arena', 'frame of poses and errors'),
    Param('leader_relay', 'double', 0.0, "s the leader's news may take to reach this robot "
          'beyond leader_timeout: its hops from the leader times a pose period and delivery '
          '(config.agents.leader_relays)', low=0.0),
    Param('pose_from_all', 'bool', False, "take this robot's pose from its row of "
          '/formation/robot_poses (a NaN row: not seen) instead of pose: the controllers of '
          'a process then share one message for all their poses; the runner sets it for '
          'grouped controllers when the poses come on /formation/robot_poses (a fake arena, '
          'a camera tracker)'),
    Param('compiled_law', 'bool', False, 'run the control step compiled by numba, as the '
          'batch simulator does (the same source): ~15x faster a tick, ~0.7 s and ~65 MB '
          'more to start; the runner sets it when every node shares one process'),
    Param(scheduling.PARAMETER, 'int', scheduling.CONTROLLERS, 'SCHED_FIFO priority (1-99) '
          "this controller's process takes at start (a group of controllers: the highest of "
          'theirs), so that a busy PC cannot delay its ticks; needs root, CAP_SYS_NICE or an '
          'rtprio limit, else a note and normal scheduling; 0 = normal scheduling (`run '
          '--realtime-priority`)', low=scheduling.NORMAL, high=scheduling.HIGHEST),
    *(Param.of(setting) for setting in SETTINGS.values()),
)


def agent_config(p: SimpleNamespace) -> AgentConfig:
    """AgentConfig from validated parameters (core.config.parameters.node_parameters gives
    them from one); ParameterError on inconsistent ones, naming the parameter. The rules
    between settings are controller.settings.RULES, as an experiment file is held to.
    """
    if p.index > p.agent_count:
        raise ParameterError(f"parameter 'index' ({p.index}) exceeds 'agent_count' "
                             f'({p.agent_count})')
    weights = p.weights or [1.0] * len(p.in_neighbours)
    if len(weights) != len(p.in_neighbours):
        raise ParameterError(f"parameter 'weights' has {len(weights)} entries but "
                             f"'in_neighbours' has {len(p.in_neighbours)}")
    if any(w <= 0 for w in weights):
        raise ParameterError(f"parameter 'weights' must all be > 0, got {weights}")
    bad = [j for j in p.in_neighbours if not 1 <= j <= p.agent_count or j == p.index]
    if bad or len(set(p.in_neighbours)) != len(p.in_neighbours):
        raise ParameterError(f"parameter 'in_neighbours' {p.in_neighbours} must be distinct "
                             f'agents 1..{p.agent_count} other than this one ({p.index})')
    if (p.role == 'leader') != (not p.in_neighbours):
        raise ParameterError(f"parameter 'role' is {p.role!r} but 'in_neighbours' is "
                             f'{p.in_neighbours}: the leader receives from nobody, a follower '
                             'from at least one agent')
    for setting in SETTINGS.values():
        problem = setting.problem(getattr(p, setting.parameter))
        if setting.kind == 'double[]' and len(getattr(p, setting.parameter)) != 2:
            problem = 'expected a pair [a, b]'
        if problem is not None:
            raise ParameterError(f'parameter {setting.parameter!r}: {problem}')
    values = {key: getattr(p, setting.parameter) for key, setting in SETTINGS.items()}
    for key, problem in broken_rules({**values, 'controller.rate_hz': p.rate_hz,
                                      'avoidance.on': p.avoidance}):
        raise ParameterError(f'parameter {SETTINGS[key].parameter!r}: {problem}')
    if len(p.pc_disturbance) != 2:
        raise ParameterError("parameter 'pc_disturbance' must be [d_v, d_w]")
    fence = p.geofence or None
    if fence is not None and (len(fence) != 4 or fence[0] >= fence[2] or fence[1] >= fence[3]):
        raise ParameterError(f"parameter 'geofence' must be [xmin, ymin, xmax, ymax] with "
                             f'xmin < xmax and ymin < ymax, got {p.geofence}')
    limits = WheelLimits(p.wheel_base, p.max_wheel_speed, p.max_angular_rate,
                         p.max_linear_accel, p.max_angular_accel)
    return AgentConfig(
        avoidance=_avoidance(p),
        index=p.index, agent_count=p.agent_count,
        neighbours=tuple(zip(p.in_neighbours, weights, strict=True)), pinning=p.pinning,
        gains=Gains(p.k1, p.k2, p.offset, law=p.law, adaptation=tuple(p.adaptation),
                    observer_rate=p.observer_rate, sampled_heading=p.heading == 'sampled',
                    tail_radius=p.tail_radius, tail_gain=p.tail_gain, reverse=p.reverse,
                    observer_growth=p.observer_growth, observer_order=p.observer_order),
        limits=limits,
        rate_hz=p.rate_hz, pose_timeout=p.pose_timeout, neighbour_timeout=p.neighbour_timeout,
        pc_disturbance=tuple(p.pc_disturbance), leader_timeout=p.leader_timeout,
        leader_relay=p.leader_relay,
        geofence=None if fence is None else tuple(fence), predict_pose=p.predict_pose,
        command_latency=p.command_latency, feed_forward=p.feed_forward, compiled=p.compiled_law,
        min_wheel_speed=p.min_wheel_speed, motor_time_constant=p.motor_time_constant,
        estimate_latency=p.estimate_latency, estimate_motors=p.estimate_motors,
        motor_check=p.motor_check)


def _avoidance(p: SimpleNamespace) -> Avoidance:
    """The safety filter's settings from the parameters (core.controller.safety.Avoidance)."""
    if not p.avoidance:
        return AVOIDANCE_OFF
    if len(p.arena) not in (0, 2) or (p.arena and min(p.arena) <= 0):
        raise ParameterError(f"parameter 'arena' must be [width, height] > 0 or empty, got "
                             f'{p.arena}')
    width, height = p.arena or (0.0, 0.0)
    return Avoidance(True, p.radius, p.avoidance_margin, p.avoidance_rate, p.passing,
                     p.passing_range or 2.0 * p.radius, float(width), float(height),
                     p.avoidance_drift)


TOPICS = (
    Use('sub', topics.POSE, 'own pose, arena frame (unless pose_from_all)'),
    Use('sub', topics.STATE, "each in-neighbour's state: e_x, e_y, curve_id, leader_age (in a "
        'node_group, a neighbour of the same process hands it over, not through DDS)', '<j>'),
    Use('sub', topics.CURVE, 'the active curve'),
    Use('sub', topics.ROBOT_POSES, "every robot's pose (x, y, theta per robot), for the "
        'safety filter (with avoidance) and with pose_from_all its own'),
    Use('pub', topics.CMD_VEL, 'velocity command at rate_hz'),
    Use('pub', topics.STATE, 'own state on every pose, for out-neighbours (names e_x, e_y, '
        'curve_id, leader_age); in a node_group, on DDS only while read outside its process'),
    Use('pub', topics.TICK, 'every tick while it has a subscriber: the command sent (v, w) and '
        'the stamps of the inputs it came from (own pose, each in-neighbour state), to trace or '
        'replay a command'),
    Use('pub', topics.ESTIMATE),
    Use('pub', topics.DIAGNOSTICS, 'driving or why stopped; curve id, s_i, estimate, rejected '
        "inputs; its robot as told or estimated (latency, motors' lag, wheel gains, dead band), "
        'each with <name>_bound and <name>_from (told, online, check)'),
    REPORTED,
) + estop_uses('true: a zero command at once and at every tick until released (latched here, '
               'whoever sent it)')


def all_poses(node: Node, msg: JointState) -> tuple[np.ndarray, float] | None:
    """(every robot's pose (n, 3), stamp s) of a /formation/robot_poses message, or None
    (logged on `node`) if it holds none.
    """
    try:
        return messages.robot_poses_from_msg(msg)
    except messages.MessageError as exc:
        node.get_logger().warning(f'robot poses refused: {exc}', throttle_duration_sec=1.0)
        return None


def reason_kind(reason: str | None) -> str | None:
    """Why a robot is stopped, without the numbers: 'own pose stale' of 'own pose stale
    (0.61 s old)'; None while driving.
    """
    return None if reason is None else reason.split(' (')[0]


class FormationController(Node):
    """Thin ROS layer over core.controller.agent.AgentController."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.params = declare_parameters(self, PARAMETERS)
        self.config = agent_config(self.params)
        self.controller = AgentController(self.config)
        self.variations = node_variations(self.params.disturbance_varies,
                                          self.config.agent_count)
        self.run_time = RunTime()
        self.rejections = rejections(self)
        self.source = CommandSourceWatch(self, topics.CMD_VEL,
                                         lambda *_: self._publish_diagnostics())
        self.pose_topic = self.resolve_topic_name(topics.POSE)
        self._last_reason: str | None = None
        self._checking = False   # the last tick was the motor check's (controller.motor_check)
        self.cmd_pub = topics.publisher(self, topics.CMD_VEL)
        self.state_pub = topics.publisher(self, topics.STATE)
        self.estimate_pub = topics.publisher(self, topics.ESTIMATE)
        self.tick_pub = topics.publisher(self, topics.TICK)
        self.speed_pub = topics.publisher(self, topics.TOP_SPEED)
        self._top_speed: float | None = None   # m/s, as last published
        self.state_msg = None   # the state message, filled anew for every pose
        self.diag_pub = topics.publisher(self, topics.DIAGNOSTICS)
        if not self.params.pose_from_all:
            topics.subscription(self, topics.POSE, self._on_pose)
        # ready for the first curve once the motor check (if any) is done: it runs before
        subscribe_to_curve(self, self._on_curve, waits=lambda: self.controller.robot.checking)
        # Stopped until the e-stop state is heard: one that starts while the formation is
        # stopped must not move first.
        self.controller.set_estop(True, 'e-stop state not heard yet')
        self.estop = EstopHolder(self, robot_name(self.config.index), self.config.agent_count,
                                 self._on_estop)
        for j, _ in self.config.neighbours:   # in this process: handed over (shared_readers)
            shared_readers.subscribe_robot(self, topics.STATE, j,
                                           partial(self._on_neighbour, j))
        # every robot's latest poses (n, 3), their stamp and when received, for the safety
        # filter at the next tick
        self.others_msg: tuple[np.ndarray, float, float] | None = None
        if self.config.avoidance.on or self.params.pose_from_all:
            # decoded once for a group's controllers, through one subscription
            shared_readers.subscribe(self, topics.ROBOT_POSES, self._on_all_poses,
                                     all_poses)
        self.create_timer(1.0 / self.config.rate_hz, self._on_timer)
        self.create_timer(1.0, self._publish_diagnostics)
        role = 'leader' if self.config.is_leader else (
            f'follower of {[j for j, _ in self.config.neighbours]}')
        self.get_logger().info(f'agent {self.config.index}/{self.config.agent_count}, {role}, '
                               f'{self.config.rate_hz:g} Hz')

    def _on_curve(self, msg: Float64MultiArray) -> None:
        before = (self.controller.curve_id, self.controller.s)
        try:
            curve, curve_id = messages.curve_from_msg(msg)
            clock = messages.curve_clock_from_msg(msg)
            self.run_time.heard(clock, now_seconds(self))
            self.controller.set_curve(curve, curve_id, messages.agent_parameters_from_msg(msg),
                                      messages.curve_rate_from_msg(msg), now_seconds(self),
                                      None if clock is None else clock.valid_at)
        except (messages.MessageError, AssignmentError, ValueError) as exc:
            self.get_logger().error(f'curve refused, keeping the previous one: {exc}')
            return
        if (curve_id, self.controller.s) != before:   # not a moving curve's renewal
            self.get_logger().info(f'curve {curve_id} ({curve.basis.describe()}), '
                                   f's_i = {self.controller.s:.4f}')

    def _on_pose(self, msg: PoseStamped) -> None:
        self._own_pose(*messages.pose_from_msg(msg))

    def _own_pose(self, x: float, y: float, theta: float, stamp: float) -> None:
        if not self.controller.on_pose(x, y, theta, stamp, now_seconds(self)):
            self.rejections.reject(self.pose_topic, self.controller.rejection)
            return
        state = self.controller.state()
        if state is not None:
            self.publish_state(state)

    def publish_state(self, state: State) -> None:
        """Tell the out-neighbours this robot's state (on every accepted pose)."""
        self.state_msg = messages.state_to_msg(state, self.params.frame_id, self.state_msg)
        shared_readers.publish_robot(self.state_pub, self.state_msg)

    def _on_neighbour(self, j: int, msg: JointState) -> None:
        try:
            ex, ey, curve_id, stamp, leader_age = messages.state_from_msg(msg)
            accepted = self.controller.on_neighbour(j, ex, ey, curve_id, stamp, leader_age,
                                                    now_seconds(self))
        except messages.MessageError as exc:
            accepted = self.controller.reject(f'state of neighbour {j}: {exc}')
        if not accepted:
            self.rejections.reject(topics.robot_topic(j, topics.STATE),
                                   self.controller.rejection)

    def _on_all_poses(self, given: tuple[np.ndarray, float]) -> None:
        poses, stamp = given
        # (a message of another team's size says nothing of this robot: its pose goes stale)
        if self.params.pose_from_all and len(poses) == self.config.agent_count:
            own = poses[self.config.index - 1]
            if np.isfinite(own).all():   # a NaN row: not seen in this frame
                self._own_pose(float(own[0]), float(own[1]), float(own[2]), stamp)
        if self.config.avoidance.on:   # the latest only, taken at the tick (10 Hz)
            self.others_msg = (poses, stamp, now_seconds(self))

    def _take_others(self) -> None:
        latest, self.others_msg = self.others_msg, None
        if latest is not None and not self.controller.on_others(*latest):
            self.get_logger().warning(f'robot poses refused: expected {self.config.agent_count}'
                                      ' robots', throttle_duration_sec=1.0)

    def _on_estop(self, engaged: bool) -> None:
        """The e-stop changed: engaged, a zero command goes out now, not at the next tick."""
        self.controller.set_estop(engaged)
        if engaged:
            self.cmd_pub.publish(Twist())

    def _on_timer(self) -> None:
        now = now_seconds(self)
        run_time = self.run_time.at(now)
        if self.variations and run_time is not None:   # the emulated disturbance as it varies
            self.controller.pc_disturbance = varied(self.config.pc_disturbance, self.variations,
                                                    self.config.index - 1, run_time)
        try:
            self._take_others()
            tick = self.controller.tick(now)
        except Exception as exc:  # noqa: BLE001 - whatever it was, the robot is stopped
            self.cmd_pub.publish(Twist())
            self.get_logger().error(f'tick failed, robot stopped: {type(exc).__name__}: {exc}',
                                    throttle_duration_sec=5.0)
            return
        # Within the wheel limits already where the experiment states them; bounded all the
        # same where it does not (core.controller.plausibility.DEFAULT_MAX_SPEED, _TURN_RATE).
        self.cmd_pub.publish(messages.twist_to_msg(*bounded_command(tick.v, tick.w)))
        if self.tick_pub.get_subscription_count():   # built only when read (camera runs, bags)
            self.tick_pub.publish(messages.tick_to_msg(tick, now))
        # Stamped with the pose this tick used, so pose-to-command latency can be measured.
        used = tick.error_stamp if tick.error_stamp is not None else now
        self.estimate_pub.publish(messages.estimate_to_msg(tick.dhat, used))
        # Logged when the reason changes, not its numbers ('pose stale (0.61 s old)'): a
        # reason whose age grows every tick would log, and publish diagnostics, every tick.
        if reason_kind(tick.stopped) != reason_kind(self._last_reason):
            if tick.stopped:
                self.get_logger().warning(f'stopped: {tick.stopped}')
            elif self._last_reason is not None:
                self.get_logger().info('driving')
            self._last_reason = tick.stopped
            self._publish_diagnostics()
        else:
            self._last_reason = tick.stopped
        if tick.checking != self._checking:
            self._checking = tick.checking
            check = self.controller.robot.check
            if tick.checking:
                self.get_logger().info('motor check: turning in place')
            elif check is not None and check.done:   # else stopped: it starts again
                self.get_logger().info(f'motor check done: {self._checked()}')
            self._publish_diagnostics()
        self._publish_top_speed()

    def _publish_top_speed(self) -> None:
        """The robot's top speed (RobotModel.top_speed) on top_speed whenever it changes, from
        when its motor check (if any) is done: the curve server waits for that one.
        """
        robot = self.controller.robot
        speed = robot.top_speed
        if robot.checking or math.isnan(speed) or speed == self._top_speed:
            return
        self._top_speed = speed
        self.speed_pub.publish(Float64(data=speed))

    def _checked(self) -> str:
        """What the motor check found, in a line."""
        found = self.controller.robot.check.result if self.controller.robot.check else None
        if found is None or found.gains is None:
            return 'nothing fitted (too few poses while it turned?)'
        band = ('none seen' if not found.band
                else f'{found.band:.5f} +- {found.bound:.5f} m/s')
        again = (f', {found.repeated} stage(s) run again (a gap in poses or ticks)'
                 if found.repeated else '')
        errors = found.gain_errors
        gains = (f'wheel gains {found.gains[0]:.4f} {found.gains[1]:.4f}'
                 + ('' if errors is None else f' +- {errors[0]:.4f} {errors[1]:.4f}'))
        if not found.trusted:
            gains += (f' (neither they nor the band used: their standard errors over '
                      f'{GAIN_ERROR:g}; noisy poses? the online fits may tell them)')
        return f'{gains}, dead band {band}, delay {found.delay:.2f} s{again}'

    def _check_state(self) -> str:
        """The motor check for /diagnostics: what it found, 'under way', or '-' (none)."""
        check = self.controller.robot.check
        if check is None or (not check.done and not self._checking):
            return '-'
        return self._checked() if check.done else 'under way'

    def _publish_diagnostics(self) -> None:
        c = self.controller
        status = DiagnosticStatus(
            level=(DiagnosticStatus.WARN if self._last_reason or self.source.extra
                   else DiagnosticStatus.OK),
            name=f'{self.get_fully_qualified_name()}',
            message=(f'stopped: {self._last_reason}' if self._last_reason
                     else 'motor check' if self._checking else 'driving'),
            hardware_id=robot_name(self.config.index),
            values=[KeyValue(key='curve_id', value=str(c.curve_id)),
                    KeyValue(key='s', value=f'{c.s}'),
                    KeyValue(key='dhat', value=f'{c.dhat[0]:.6g} {c.dhat[1]:.6g}'),
                    # the robot as told or estimated, each with its bound and source
                    *(KeyValue(key=key, value=text)
                      for key, text in diagnostics.estimate_values(c.robot.estimates())),
                    # what the motor check found (_checked), 'under way', or '-': none
                    KeyValue(key='motor_check', value=self._check_state()),
                    KeyValue(key='rejected_inputs', value=str(c.rejected)),
                    KeyValue(key='rejected_messages', value=self.rejections.summary()),
                    KeyValue(key='last_rejection', value=self.rejections.last),
                    KeyValue(key='command_publishers', value=', '.join(self.source.names)),
                    KeyValue(key='filtered_ticks', value=str(c.filtered))])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(msg)

    def on_shutdown(self) -> LastMessages:
        """Leave the robot stopped: a zero command, acknowledged (1 s at most), and the last
        ticks (0.25 s at most), so that a recorder misses none of them.
        """
        self.cmd_pub.publish(Twist())
        return [(self.cmd_pub, 1.0), *((publisher, 0.25) for publisher in
                                       (self.tick_pub, self.state_pub, self.estimate_pub))]


def main(args: list[str] | None = None) -> int:
    return run_node(FormationController, args, priority_parameter=scheduling.PARAMETER)


if __name__ == '__main__':
    raise SystemExit(main())
