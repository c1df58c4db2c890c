"""fake_arena: every robot of an experiment as a body in one arena, standing in for Mona robots.

Each robot moves as fake_robot's does (core.dynamics.DrivenUnicycle under its cmd_vel, with
its disturbance, latency and watchdog), but all of them in one world: the world advances in
steps of at most `physics_dt` and after each step bodies that overlap are pushed apart and
bodies through a wall put back (core.bodies.separate, the batch simulator's code), so robots
block and push each other as real ones do. Publishes every robot's pose on /robot_<i>/pose
(or true_pose when a camera tracks them) and all of them on /formation/robot_poses (unless a
camera tracker does), at `rate_hz`; /diagnostics reports the contacts: how many, for how long,
and the smallest gap between two bodies. With `links`, the robots are emulated Mona robots
behind their last link: each reads wheel speeds in its wire format from a UDP port or a
pseudo-terminal, as its firmware would (with the firmware's watchdog: `command_timeout`), and
answers each line 'ok' or 'err'; no cmd_vel is read (robot_bridge writes those links).
Reading cmd_vel, it obeys the e-stop as fake_robot does: every robot stands still until it is
released; and a robot whose cmd_vel has more than one publishing node stands still until one
is left.
"""

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node

from curve_formation.core import metrics, wire
from curve_formation.core.dynamics import DrivenUnicycle
from curve_formation.links import robot_endpoint
from curve_formation.nodes import messages, topics
from curve_formation.nodes.command_source import CommandSourceWatch
from curve_formation.nodes.estop import EstopHolder
from curve_formation.nodes.fake_robot import ESTOP_TOPICS, ROBOT_PARAMETERS
from curve_formation.nodes.params import (
    declare_parameters,
    experiment_parameter,
    Param,
    ParameterError,
)
from curve_formation.nodes.robot_bridge import wire_format_parameter, WIRE_PARAMETERS
from curve_formation.nodes.runtime import now_seconds, run_node
from curve_formation.nodes.topics import Use


# How often the emulated robots' firmware reads its links (s).
FIRMWARE_POLL = 0.005


NODE_NAME = 'fake_arena'   # also its console script's name
PARAMETERS = (
    Param('experiment', 'string', None, 'experiment YAML (path or shipped name): robots, '
          'start poses, body radius, arena and disturbance'),
    Param('rate_hz', 'double', 30.0, 'pose publishing rate (Hz), as an overhead camera',
          positive=True),
    Param('physics_dt', 'double', 0.005, 'longest step between two contact resolutions (s)',
          positive=True),
    Param('publish_robot_poses', 'bool', True, 'publish all poses on /formation/robot_poses '
          '(off when a camera tracker publishes them)'),
    Param('links', 'string[]', [], "emulated robots: each robot's link ('udp:HOST:PORT' or "
          "'pty:PATH'), read as its firmware would, wheel speeds in wire_format, instead of "
          'cmd_vel; empty = cmd_vel'),
    Param('fault_link_down', 'double[]', [], 'fault injection: [robot (0 = all), from (s), '
          'for (s)] after the first line received: the firmware hears nothing'),
) + ROBOT_PARAMETERS + WIRE_PARAMETERS

TOPICS = (
    Use('sub', topics.CMD_VEL, "each robot's velocity command; with more than one publishing "
        'node, that robot stands still until one is left', '<i>'),
    Use('pub', topics.POSE, f'each pose at rate_hz (on {topics.TRUE_POSE} instead with '
        'pose_topic)', '<i>'),
    Use('pub', topics.ROBOT_POSES, 'every pose in one message (x, y, theta per robot), with '
        'publish_robot_poses'),
    Use('pub', topics.DIAGNOSTICS, 'contacts: count, total time (s), smallest gap between '
        'two bodies (m); 1 Hz'),
) + ESTOP_TOPICS


class FakeArena(Node):
    """All robots of an experiment as bodies that cannot overlap."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        p = self.params = declare_parameters(self, PARAMETERS)
        experiment = experiment_parameter(p.experiment)
        spec = experiment.spec
        on_robot = spec.disturbance.injected == 'on_robot'
        self.robots = [DrivenUnicycle(pose, d if on_robot else (0.0, 0.0), p.command_latency,
                                      p.command_timeout)
                       for pose, d in zip(experiment.initial_poses, experiment.disturbance,
                                          strict=True)]
        self.n = experiment.n
        self.radius = experiment.radius
        self.size = tuple(spec.arena.size) if spec.arena is not None else (0.0, 0.0)
        self.touching = np.zeros((self.n, self.n), bool)
        if self.radius > 0:
            separate(np.zeros((0, 3)), 0.0, 0.0, 0.0, self.touching[:0, :0])   # compile now
        self.contacts = 0
        self.contact_time = 0.0
        self.smallest_gap = math.inf
        self.clearance = -math.inf   # the smallest gap, or twice a body's room to a wall (m)
        self.time = None
        self.rng = np.random.default_rng(p.seed)
        self.pose_pubs = [topics.publisher(self, p.pose_topic, robot=i)
                          for i in range(1, self.n + 1)]
        self.pose_msgs = [PoseStamped() for _ in self.pose_pubs]   # filled anew each period
        self.all_pub = (topics.publisher(self, topics.ROBOT_POSES)
                        if p.publish_robot_poses else None)
        self.diag_pub = topics.publisher(self, topics.DIAGNOSTICS)
        self.endpoints = self._endpoints(p, experiment)
        self.estop = None   # behind links, the robot bridges hold the e-stop
        self.sources = []   # and watch the command sources
        if self.endpoints:
            self.create_timer(FIRMWARE_POLL, self._on_lines)
        else:
            self.estop = EstopHolder(self, robots=self.n, on_change=self._stop_held)
            self.sources = [CommandSourceWatch(self, topics.robot_topic(i, topics.CMD_VEL),
                                               self._stop_held)
                            for i in range(1, self.n + 1)]
            for i in range(1, self.n + 1):
                topics.subscription(self, topics.CMD_VEL, lambda msg, i=i: self._on_cmd(i, msg),
                                    robot=i)
        self.create_timer(1.0 / p.rate_hz, self._on_timer)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f'{self.n} robots, bodies of radius {self.radius:g} m, arena '
                               f'{self.size[0]:g} x {self.size[1]:g} m')

    def _endpoints(self, p, experiment):
        """The emulated robots' links, with their wire format; [] to read cmd_vel."""
        if not p.links:
            return []
        if len(p.links) != self.n:
            raise ParameterError(f"parameter 'links' has {len(p.links)} entries for {self.n} "
                                 'robots')
        if len(p.fault_link_down) not in (0, 3):
            raise ParameterError("parameter 'fault_link_down' must be [robot, from, for]")
        self.format = wire_format_parameter(p)
        self.wheel_base = experiment.limits.wheel_base or wire.MONA_WHEEL_BASE
        self.first_line = None
        try:
            return [robot_endpoint(link) for link in p.links]
        except (ValueError, OSError) as exc:
            raise ParameterError(f"parameter 'links': {exc}") from None

    def _deaf(self, i, now):
        """Fault injection: robot i's firmware hears nothing now."""
        fault = self.params.fault_link_down
        if not fault or self.first_line is None or fault[0] not in (0, i):
            return False
        return fault[1] <= now - self.first_line < fault[1] + fault[2]

    def _on_lines(self):
        """Each emulated robot's firmware: wheel speeds in, 'ok' or 'err' out."""
        now = now_seconds(self)
        for i, endpoint in enumerate(self.endpoints, 1):
            for line in endpoint.lines():
                if self.first_line is None:
                    self.first_line = now
                if self._deaf(i, now):
                    continue
                said = wire.decode(self.format, line, self.params.wheel_radius)
                if said is None:
                    endpoint.send(b'err\n')
                    continue
                if said[0] == 'command':
                    v, w = wire.body_velocity(said[1], said[2], self.wheel_base)
                else:
                    v, w = 0.0, 0.0
                self.robots[i - 1].drive(v, w, now, advance=False)
                endpoint.send(b'ok\n')

    def _on_cmd(self, i, msg):
        v, w = messages.twist_from_msg(msg)
        if not (math.isfinite(v) and math.isfinite(w)):
            self.get_logger().warning(f'robot {i}: non-finite cmd_vel ignored',
                                      throttle_duration_sec=1.0)
            return
        if self.held(i):
            v, w = 0.0, 0.0
        # Taken up, at its time, by the next step of the world (the pose timer's).
        self.robots[i - 1].drive(v, w, now_seconds(self), advance=False)

    def held(self, i):
        """Robot i stands still: e-stop, or more than one node publishing its cmd_vel (with
        links, the robot bridges hold it instead).
        """
        return self.estop is not None and (self.estop.engaged or self.sources[i - 1].extra)

    def _stop_held(self, *_):
        now = now_seconds(self)
        for i, robot in enumerate(self.robots, 1):
            if self.held(i):
                robot.drive(0.0, 0.0, now, advance=False)

    def advance(self, until):
        """Move every robot up to `until` (s), resolving contacts every physics_dt; in one
        step while no two bodies, nor a body and a wall, can meet before then at the fastest
        speed commanded (nothing to resolve on the way).
        """
        if self.time is None:
            self.time = until
        while self.time < until:
            step = min(self.params.physics_dt, until - self.time)
            if self._apart_over(until - self.time):
                step = until - self.time
            self.time += step
            for i, robot in enumerate(self.robots):
                if robot.advance(self.time):
                    self.get_logger().warning(f'robot {i + 1}: no command for '
                                              f'{self.params.command_timeout:g} s: motors off')
            self._touch(step)

    def _apart_over(self, span):
        """Whether no contact can happen in the next `span` s: the bodies' smallest gap and
        twice their room to the walls exceed twice the fastest robot's travel.
        """
        if self.radius <= 0:
            return True
        speed = max(robot.top_speed(self.time + span) for robot in self.robots)
        return self.clearance > 2.0 * speed * span

    def _touch(self, step):
        if self.radius <= 0:
            return
        poses = np.array([r.pose for r in self.robots])
        new, now, gap = separate(poses, self.radius, self.size[0], self.size[1],
                                 self.touching)
        self.contacts += new
        self.contact_time += step if now else 0.0
        self.smallest_gap = min(self.smallest_gap, gap)
        self.clearance = -math.inf if now else gap
        for axis, size in enumerate(self.size):   # walls: 0 <= x <= width, 0 <= y <= height
            if size > 0:
                room = np.minimum(poses[:, axis], size - poses[:, axis]) - self.radius
                self.clearance = min(self.clearance, 2.0 * float(room.min()))
        for robot, pose in zip(self.robots, poses, strict=True):
            robot.pose = tuple(pose)

    def _on_timer(self):
        now = now_seconds(self)
        self.advance(now)
        noise = self.params.pose_noise
        poses = np.array([r.pose for r in self.robots])
        if noise[0] > 0 or noise[1] > 0:
            poses = poses + self.rng.normal(0.0, [noise[0], noise[0], noise[1]], poses.shape)
        for pub, msg, (x, y, th) in zip(self.pose_pubs, self.pose_msgs, poses, strict=True):
            if self.rng.random() >= self.params.fault_pose_drop:
                pub.publish(messages.pose_to_msg(x, y, th, now, self.params.frame_id, msg))
        if self.all_pub is not None:
            self.all_pub.publish(messages.robot_poses_to_msg(poses, now, self.params.frame_id))

    def contact_summary(self):
        """{'count', 'time' (s), 'smallest_gap' (m, None without bodies)} so far."""
        return {'count': self.contacts, 'time': self.contact_time,
                'smallest_gap': self.smallest_gap if math.isfinite(self.smallest_gap)
                else None}

    def _publish_diagnostics(self):
        summary = self.contact_summary()
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if summary['count'] else DiagnosticStatus.OK,
            name=self.get_fully_qualified_name(), hardware_id=metrics.CONTACT_REPORTER,
            message=f'{summary["count"]} contacts' if summary['count'] else 'no contact',
            values=[KeyValue(key=key, value=repr(value)) for key, value in summary.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = messages.seconds_to_stamp(now_seconds(self))
        self.diag_pub.publish(msg)

    def on_shutdown(self):
        """The final contact tally, acknowledged (1 s at most) so that a recorder has it."""
        self._publish_diagnostics()
        self.diag_pub.wait_for_all_acked(Duration(seconds=1.0))
        for endpoint in self.endpoints:
            endpoint.close()


def separate(poses, radius, width, height, touching):
    """core.bodies.separate as the batch simulator compiles it (imported on first use)."""
    from curve_formation.core.simulator import separate as compiled
    return compiled(poses, radius, width, height, touching)


def main(args=None):
    return run_node(FakeArena, args)


if __name__ == '__main__':
    raise SystemExit(main())
