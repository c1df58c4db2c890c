"""fake_robot: a Mona stand-in for tests and demos, in namespace /robot_<i>.

Moves as a unicycle under the latest cmd_vel plus its constant (physical) input disturbance and
publishes pose (PoseStamped, arena frame) at `rate_hz`, like an overhead camera. Commands are
piecewise constant, so the motion is integrated exactly up to each command change and each
publication: no integration step. A zero command means motors off: the robot stands still
(the disturbance acts on a driven input only), and so does a command older than
`command_timeout` (a robot-side watchdog, as a driver should have). While the e-stop is
engaged, and while its cmd_vel has more than one publishing node (nodes/command_source.py),
it stands still whatever cmd_vel says (nodes/estop.py). Options: Gaussian pose
noise, a fixed command latency, dropped poses (fault injection), and a disturbance that varies
over the run's time (`disturbance_varies`, dated by the curve messages' clock).
"""

import math
from types import SimpleNamespace
from typing import Any

from geometry_msgs.msg import Twist
import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from curve_formation.core.config.experiment import DEFAULT_POSE_RATE
from curve_formation.core.controller.disturbance import RunTime, varied
from curve_formation.core.formation.dynamics import DrivenUnicycle
from curve_formation.interface import robot_name
from curve_formation.nodes import messages, topics
from curve_formation.nodes.command_source import CommandSourceWatch
from curve_formation.nodes.estop import estop_uses, EstopHolder
from curve_formation.nodes.params import (
    declare_parameters,
    node_variations,
    Param,
    ParameterError,
)
from curve_formation.nodes.runtime import now_seconds, run_node
from curve_formation.nodes.topics import Use


# How a simulated robot moves and is seen (fake_robot, and every robot of fake_arena).
ROBOT_PARAMETERS = (
    Param('pose_noise', 'double[]', [0.0, 0.0], 'std of Gaussian noise on a published pose: '
          'position (m) and heading (rad)'),
    Param('command_latency', 'double', 0.0, 'delay before a command takes effect (s)',
          low=0.0),
    Param('command_jitter', 'double', 0.0, "each command's delay varies by up to this much "
          'either way (s, uniform; never before the command before it), as over Wi-Fi',
          low=0.0),
    Param('command_timeout', 'double', 1.0, 'motors off when the last command is older than '
          'this (s); 0 = keep the last command forever', low=0.0),
    Param('fault_pose_drop', 'double', 0.0, 'fault injection: probability of not publishing '
          'a pose', low=0.0, high=1.0),
    Param('seed', 'int', 0, 'seed of the pose noise and drops'),
    Param('frame_id', 'string', 'arena', 'frame of the published poses'),
    Param('pose_topic', 'string', topics.POSE, f"per-robot topic of the published pose: "
          f"'{topics.POSE}', or '{topics.TRUE_POSE}' when a camera tracks the robots",
          choices=(topics.POSE, topics.TRUE_POSE)),
)

NODE_NAME = 'fake_robot'   # also its console script's name
PARAMETERS = (
    Param('index', 'int', 1, 'robot number i (for logs)', low=1),
    Param('initial_pose', 'double[]', [0.0, 0.0, 0.0], 'start pose [x, y, theta] (m, rad)'),
    Param('rate_hz', 'double', DEFAULT_POSE_RATE, 'pose publishing rate (Hz), as an overhead '
          'camera', positive=True),
    Param('disturbance', 'double[]', [0.0, 0.0], 'input disturbance [d_v, d_w] (m/s, rad/s) '
          'added to a non-zero command'),
    Param('disturbance_varies', 'string', '', "how the disturbance changes over the run's "
          "time (s since the first curve, from the curve's clock): the experiment's "
          "disturbance.varies as JSON (sines, steps, ramps); '' = constant"),
) + ROBOT_PARAMETERS


def check_command_jitter(p: SimpleNamespace) -> None:
    """ParameterError unless the command_jitter of ROBOT_PARAMETERS p is at most the
    command_latency (a command never acts before it was sent).
    """
    if p.command_jitter > p.command_latency:
        raise ParameterError(f"parameter 'command_jitter' ({p.command_jitter:g}) must not "
                             f"exceed 'command_latency' ({p.command_latency:g})")


# The e-stop as the fake robots and the fake arena obey it.
ESTOP_TOPICS = estop_uses('true: motors off and every cmd_vel taken as zero until released')

TOPICS = (
    Use('sub', topics.CMD_VEL, 'velocity command; with more than one publishing node, the '
        'robot stands still until one is left'),
    Use('pub', topics.POSE, f'pose at rate_hz (on {topics.TRUE_POSE} instead with pose_topic)'),
    Use('sub', topics.CURVE, "with disturbance_varies: the run's time, from the curve's clock"),
) + ESTOP_TOPICS

class FakeRobot(Node):
    """Unicycle integrated from cmd_vel; pure maths in core.formation.dynamics.DrivenUnicycle."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.params = declare_parameters(self, PARAMETERS)
        for name, size in (('initial_pose', 3), ('disturbance', 2), ('pose_noise', 2)):
            if len(getattr(p, name)) != size:
                raise ParameterError(f'parameter {name!r} must have {size} values, got '
                                     f'{getattr(p, name)}')
        check_command_jitter(p)
        self.robot = DrivenUnicycle(p.initial_pose, p.disturbance, p.command_latency,
                                    p.command_timeout, p.command_jitter, p.seed)
        self.variations = node_variations(p.disturbance_varies)
        self.run_time = RunTime()
        topics.subscription(self, topics.CURVE, self._on_curve)
        self.rng = np.random.default_rng(p.seed)
        self.pose_pub = topics.publisher(self, p.pose_topic)
        reader = topics.subscription(self, topics.CMD_VEL, self._on_cmd)
        self.estop = EstopHolder(self, robot_name(p.index), on_change=self._stop_if_held)
        self.source = CommandSourceWatch(self, topics.CMD_VEL, self._stop_if_held, reader)
        self.create_timer(1.0 / p.rate_hz, self._on_timer)

    def _on_curve(self, msg: Float64MultiArray) -> None:
        known = self.run_time.start is not None
        self.run_time.heard(messages.curve_clock_from_msg(msg), now_seconds(self))
        if not known and self.variations:
            self.get_logger().info('the disturbance varies from the first curve on')

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.robot.pose

    def _on_cmd(self, msg: Twist) -> None:
        v, w = messages.twist_from_msg(msg)
        if not (math.isfinite(v) and math.isfinite(w)):
            self.get_logger().warning('non-finite cmd_vel ignored', throttle_duration_sec=1.0)
            return
        if self.held:
            v, w = 0.0, 0.0
        self.robot.drive(v, w, now_seconds(self))

    @property
    def held(self) -> bool:
        """The robot stands still: e-stop, or more than one node publishing its cmd_vel."""
        return self.estop.engaged or self.source.extra

    def _stop_if_held(self, *_: Any) -> None:
        if self.held:
            self.robot.drive(0.0, 0.0, now_seconds(self))

    def _on_timer(self) -> None:
        now = now_seconds(self)
        if self.robot.advance(now):
            self.get_logger().warning(f'no command for {self.params.command_timeout:g} s: '
                                      'motors off')
        run_time = self.run_time.at(now)
        if self.variations and run_time is not None:   # until the next pose, as it is now
            self.robot.disturbance = varied(self.params.disturbance, self.variations,
                                            self.params.index - 1, run_time)
        if self.rng.random() < self.params.fault_pose_drop:
            return
        noise = self.params.pose_noise
        x, y, th = self.pose
        if noise[0] > 0 or noise[1] > 0:
            x += self.rng.normal(0, noise[0])
            y += self.rng.normal(0, noise[0])
            th += self.rng.normal(0, noise[1])
        self.pose_pub.publish(messages.pose_to_msg(x, y, th, now, self.params.frame_id))


def main(args: list[str] | None = None) -> int:
    return run_node(FakeRobot, args)


if __name__ == '__main__':
    raise SystemExit(main())
