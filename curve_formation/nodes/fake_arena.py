"""fake_arena: every robot of an experiment as a body in one arena, standing in for Mona robots.

The world is the experiment's physics.engine, or the `physics` parameter (core.world.worlds). In
the
kinematic world each robot moves as fake_robot's does (core.formation.dynamics.DrivenUnicycle
under its
cmd_vel, with its disturbance, latency and watchdog), all of them in one world that advances in
steps of at most `physics_dt`, pushing overlapping bodies apart and bodies through a wall back
(core.world.kinematic), so robots block and push each other. In the MuJoCo world each robot is
a body with mass on two motor-driven wheels and casters, its cmd_vel turned into wheel speed
commands as its firmware would, with the experiment's imperfections; contacts come from the
engine (core.world.mujoco_world). Publishes every robot's pose on /robot_<i>/pose (or true_pose
when
a camera tracks them) and all of them on /formation/robot_poses (unless a camera tracker does),
at `rate_hz`; /diagnostics reports the contacts: how many, for how long, and the smallest gap
between two bodies. With `links`, the robots are emulated Mona robots behind their last link:
each reads wheel speeds in its wire format from a UDP port or a pseudo-terminal, as its
firmware would (with the firmware's watchdog: `command_timeout`), and answers each line 'ok' or
'err'; no cmd_vel is read (robot_bridge writes those links). Reading cmd_vel, it obeys the
e-stop as fake_robot does: every robot stands still until it is released; and a robot whose
cmd_vel has more than one publishing node stands still until one is left.
"""

import math
from types import SimpleNamespace
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Twist
import numpy as np
from rclpy.node import Node

from curve_formation import diagnostics, wire
from curve_formation.core.config.experiment import DEFAULT_POSE_RATE, Experiment, wheel_base
from curve_formation.core.controller.disturbance import RunTime
from curve_formation.core.formation.dynamics import body_from_wheels
from curve_formation.core.world.worlds import ENGINES, make_world
from curve_formation.links import robot_endpoint
from curve_formation.nodes import messages, topics
from curve_formation.nodes.command_source import CommandSourceWatch
from curve_formation.nodes.estop import EstopHolder
from curve_formation.nodes.fake_robot import (
    check_command_jitter,
    ESTOP_TOPICS,
    ROBOT_PARAMETERS,
)
from curve_formation.nodes.params import (
    declare_parameters,
    experiment_parameter,
    Param,
    ParameterError,
)
from curve_formation.nodes.robot_bridge import wire_format_parameter, WIRE_PARAMETERS
from curve_formation.nodes.runtime import LastMessages, now_seconds, run_node
from curve_formation.nodes.topics import Use


# How often the emulated robots' firmware reads its links (s).
FIRMWARE_POLL = 0.005
# (v m/s, w rad/s) of a runaway robot (fault_runaway)
RUNAWAY = (0.01, 0.0)
# Longer than this (s) between two publications of the poses is logged: the arena stalled.
LATE_POSES = 0.5


NODE_NAME = 'fake_arena'   # also its console script's name
PARAMETERS = (
    Param('experiment', 'string', None, 'experiment YAML (path or shipped name): robots, '
          'start poses, body radius, arena and disturbance'),
    Param('rate_hz', 'double', DEFAULT_POSE_RATE, 'pose publishing rate (Hz), as an overhead '
          'camera', positive=True),
    Param('physics', 'string', '', f"the world: {' or '.join(ENGINES)}; empty = the "
          "experiment's physics.engine"),
    Param('physics_dt', 'double', 0.005, 'kinematic world: longest step between two contact '
          'resolutions (s)', positive=True),
    Param('publish_robot_poses', 'bool', True, 'publish all poses on /formation/robot_poses '
          '(off when a camera tracker publishes them)'),
    Param('links', 'string[]', [], "emulated robots: each robot's link ('udp:HOST:PORT' or "
          "'pty:PATH'), read as its firmware would, wheel speeds in wire_format, instead of "
          'cmd_vel; empty = cmd_vel'),
    Param('fault_link_down', 'double[]', [], 'fault injection: [robot (0 = all), from (s), '
          'for (s)] after the first command line received that turns a wheel (not a stop or '
          'a standing command: a pre-flight and controllers waiting for a curve send those), '
          'so from when the robots first drive: the firmware hears nothing'),
    Param('fault_silent', 'int[]', [], 'fault injection: the firmware of these robots '
          '(1-based) hears nothing, ever (a dead radio or battery)'),
    Param('fault_runaway', 'int[]', [], 'fault injection: these robots (1-based) answer every '
          'line but drive on at RUNAWAY speed whatever they are told (a stuck motor driver)'),
    Param('fault_hidden', 'int[]', [], "fault injection: these robots' poses are never "
          'published (a marker face-down; NaN on /formation/robot_poses, as a dropped pose)'),
) + ROBOT_PARAMETERS + WIRE_PARAMETERS

TOPICS = (
    Use('sub', topics.CMD_VEL, "each robot's velocity command; with more than one publishing "
        'node, that robot stands still until one is left', '<i>'),
    Use('pub', topics.POSE, f'each pose at rate_hz (on {topics.TRUE_POSE} instead with '
        'pose_topic), while it has a reader', '<i>'),
    Use('pub', topics.ROBOT_POSES, 'every pose in one message (x, y, theta per robot), with '
        'publish_robot_poses'),
    Use('sub', topics.CURVE, "with the experiment's disturbance.varies: the run's time, from "
        "the curve's clock"),
    Use('pub', topics.DIAGNOSTICS, 'contacts: count, total time (s), smallest gap between '
        'two bodies (m); with MuJoCo also robot-wall contacts and the largest push (N); 1 Hz'),
) + ESTOP_TOPICS


class FakeArena(Node):
    """All robots of an experiment as bodies that cannot overlap."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.params = declare_parameters(self, PARAMETERS)
        experiment = experiment_parameter(p.experiment)
        spec = experiment.spec
        check_command_jitter(p)
        try:
            self.world = make_world(experiment, p.physics or None, p.command_latency,
                                    p.command_timeout, p.physics_dt, p.command_jitter, p.seed)
        except ValueError as exc:   # an engine not known, or MuJoCo not installed
            raise ParameterError(f"parameter 'physics': {exc}") from None
        self.n = experiment.n
        self.radius = experiment.radius
        self.experiment = experiment
        self.run_time = RunTime()   # a disturbance that varies, over the run's time
        self.varies = bool(experiment.variations) and spec.disturbance.injected == 'on_robot'
        topics.subscription(self, topics.CURVE, lambda msg: self.run_time.heard(
            messages.curve_clock_from_msg(msg), now_seconds(self)))
        self.size = tuple(spec.arena.size) if spec.arena is not None else (0.0, 0.0)
        self.rng = np.random.default_rng(p.seed)
        self.pose_pubs = [topics.publisher(self, p.pose_topic, robot=i)
                          for i in range(1, self.n + 1)]
        self.pose_msgs = [PoseStamped() for _ in self.pose_pubs]   # filled anew each period
        self.all_pub = (topics.publisher(self, topics.ROBOT_POSES)
                        if p.publish_robot_poses else None)
        self.diag_pub = topics.publisher(self, topics.DIAGNOSTICS)
        self.endpoints = self._endpoints(p, experiment)
        self.estop = None   # behind links, the robot bridges hold the e-stop
        self.sources: list[CommandSourceWatch] = []   # and watch the command sources
        if self.endpoints:
            self.create_timer(FIRMWARE_POLL, self._on_lines)
        else:
            self.estop = EstopHolder(self, robots=self.n, on_change=self._stop_held)
            for i in range(1, self.n + 1):
                reader = topics.subscription(self, topics.CMD_VEL,
                                             lambda msg, i=i: self._on_cmd(i, msg), robot=i)
                self.sources.append(CommandSourceWatch(
                    self, topics.robot_topic(i, topics.CMD_VEL), self._stop_held, reader))
        self.last_poses: float | None = None   # when poses were last published (s)
        self.create_timer(1.0 / p.rate_hz, self._on_timer)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f'{self.n} robots, bodies of radius {self.radius:g} m, arena '
                               f'{self.size[0]:g} x {self.size[1]:g} m, '
                               f'{type(self.world).__name__}')

    def _endpoints(self, p: SimpleNamespace, experiment: Experiment) -> list[Any]:
        """The emulated robots' links, with their wire format; [] to read cmd_vel."""
        if not p.links:
            return []
        if len(p.links) != self.n:
            raise ParameterError(f"parameter 'links' has {len(p.links)} entries for {self.n} "
                                 'robots')
        if len(p.fault_link_down) not in (0, 3):
            raise ParameterError("parameter 'fault_link_down' must be [robot, from, for]")
        self.format = wire_format_parameter(p)
        self.wheel_base = wheel_base(experiment)
        self.first_line: float | None = None
        try:
            return [robot_endpoint(link) for link in p.links]
        except (ValueError, OSError) as exc:
            raise ParameterError(f"parameter 'links': {exc}") from None

    def _deaf(self, i: int, now: float) -> bool:
        """Fault injection: robot i's firmware hears nothing now."""
        if i in self.params.fault_silent:
            return True
        fault = self.params.fault_link_down
        if not fault or self.first_line is None or fault[0] not in (0, i):
            return False
        return fault[1] <= now - self.first_line < fault[1] + fault[2]

    def _on_lines(self) -> None:
        """Each emulated robot's firmware: wheel speeds in, 'ok' or 'err' out."""
        now = now_seconds(self)
        for i, endpoint in enumerate(self.endpoints, 1):
            for line in endpoint.lines():
                if self._deaf(i, now):
                    continue
                said = wire.decode(self.format, line, self.params.wheel_radius)
                if (self.first_line is None and said is not None and said[0] == 'command'
                        and (said[1] != 0.0 or said[2] != 0.0)):
                    self.first_line = now
                if said is None:
                    endpoint.send(b'err\n')
                    continue
                if i in self.params.fault_runaway:
                    v, w = RUNAWAY
                elif said[0] == 'command':
                    v, w = body_from_wheels(said[1], said[2], self.wheel_base)
                else:
                    v, w = 0.0, 0.0
                self.world.command(i - 1, v, w, now)
                endpoint.send(b'ok\n')

    def _on_cmd(self, i: int, msg: Twist) -> None:
        v, w = messages.twist_from_msg(msg)
        if not (math.isfinite(v) and math.isfinite(w)):
            self.get_logger().warning(f'robot {i}: non-finite cmd_vel ignored',
                                      throttle_duration_sec=1.0)
            return
        if self.held(i):
            v, w = 0.0, 0.0
        # Taken up, at its time, by the next step of the world (the pose timer's).
        self.world.command(i - 1, v, w, now_seconds(self))

    def held(self, i: int) -> bool:
        """Robot i stands still: e-stop, or more than one node publishing its cmd_vel (with
        links, the robot bridges hold it instead).
        """
        return self.estop is not None and (self.estop.engaged or self.sources[i - 1].extra)

    def _stop_held(self, *_: Any) -> None:
        now = now_seconds(self)
        for i in range(1, self.n + 1):
            if self.held(i):
                self.world.command(i - 1, 0.0, 0.0, now)

    def advance(self, until: float) -> None:
        """Move the world up to `until` (s), saying which robots' watchdogs stopped them."""
        for i in self.world.advance(until):
            self.get_logger().warning(f'robot {i + 1}: no command for '
                                      f'{self.params.command_timeout:g} s: motors off')

    def _on_timer(self) -> None:
        now = now_seconds(self)
        if self.last_poses is not None and now - self.last_poses > LATE_POSES:
            self.get_logger().warning(f'poses published {now - self.last_poses:.2f} s after '
                                      'the last: this process was held up',
                                      throttle_duration_sec=1.0)
        self.last_poses = now
        self.advance(now)
        run_time = self.run_time.at(now)
        if self.varies and run_time is not None:   # until the next pose, as it is now
            for i, d in enumerate(self.experiment.disturbance_at(run_time)):
                self.world.disturb(i, d)
        noise = self.params.pose_noise
        poses = self.world.poses()
        if noise[0] > 0 or noise[1] > 0:
            poses = poses + self.rng.normal(0.0, [noise[0], noise[0], noise[1]], poses.shape)
        hidden = self.params.fault_hidden
        unseen = np.zeros(len(poses), bool)   # as a camera misses them: in every message
        for i, (pub, msg, (x, y, th)) in enumerate(zip(self.pose_pubs, self.pose_msgs, poses,
                                                       strict=True), 1):
            unseen[i - 1] = self.rng.random() < self.params.fault_pose_drop or i in hidden
            # built only when read: a team whose poses are read from robot_poses (grouped
            # controllers, the runner's monitor) leaves the n topics without readers
            if not unseen[i - 1] and pub.get_subscription_count():
                pub.publish(messages.pose_to_msg(x, y, th, now, self.params.frame_id, msg))
        if self.all_pub is not None:
            every = np.where(unseen[:, None], np.nan, poses)
            self.all_pub.publish(messages.robot_poses_to_msg(every, now, self.params.frame_id))

    def contact_summary(self) -> dict[str, Any]:
        """The world's contact tally so far: {'count', 'time' (s), 'smallest_gap' (m, None
        without bodies)}, and from MuJoCo also 'walls' and 'largest_push' (N).
        """
        return self.world.contact_summary()

    def _publish_diagnostics(self) -> None:
        summary = self.contact_summary()
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if summary['count'] else DiagnosticStatus.OK,
            name=self.get_fully_qualified_name(), hardware_id=diagnostics.CONTACT_REPORTER,
            message=f'{summary["count"]} contacts' if summary['count'] else 'no contact',
            values=[KeyValue(key=key, value=repr(value)) for key, value in summary.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = messages.seconds_to_stamp(now_seconds(self))
        self.diag_pub.publish(msg)

    def on_shutdown(self) -> LastMessages:
        """The final contact tally, acknowledged (1 s at most) so that a recorder has it."""
        self._publish_diagnostics()
        for endpoint in self.endpoints:
            endpoint.close()
        return [(self.diag_pub, 1.0)]


def main(args: list[str] | None = None) -> int:
    return run_node(FakeArena, args)


if __name__ == '__main__':
    raise SystemExit(main())
