"""robot_bridge: one robot's cmd_vel as wheel speeds on its serial line or UDP link, in
namespace /robot_<i>.

Each cmd_vel becomes the rim speeds of the two wheels (wheel base from the parameters), scaled
down together, keeping the curvature, when a wheel would exceed `max_wheel_speed`, and is
written at once as a line of the robot's wire format (wire), at most `rate_hz` lines a
second and two more (see _may_send: a command that comes sooner waits, and a newer command
replaces it), from a thread at real-time priority (`realtime_priority`) when the bridge has
a process of its own.
The stop line is sent while cmd_vel is older than `command_timeout`, while the e-stop is
engaged, and `stop_repeats` times on shutdown (a UDP datagram can be lost). Lines from the
robot (its replies, 'ok' with its battery voltage where the firmware adds it) are counted;
what is not a reply is counted as malformed and dropped.
/diagnostics (1 Hz): sent, failed, malformed, last error, time since the robot last answered
(a link lost for longer than `reply_timeout` is reported), and the bridge's latency
from a cmd_vel received to its bytes written.
"""

import collections
import math
import time
from types import SimpleNamespace
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Twist
import numpy as np
from rclpy.node import Node

from curve_formation import wire
from curve_formation.core.config.schema import MONA_WHEEL_BASE
from curve_formation.core.controller.inputs import is_stale
from curve_formation.core.controller.settings import SETTINGS
from curve_formation.links import LinkError, robot_link
from curve_formation.nodes import messages, topics
from curve_formation.nodes.command_source import CommandSourceWatch
from curve_formation.nodes.estop import estop_uses, EstopHolder
from curve_formation.nodes.params import declare_parameters, Param, ParameterError
from curve_formation.nodes.runtime import now_seconds, run_node
from curve_formation.nodes.topics import Use
from curve_formation.scheduling import BRIDGE, HIGHEST, NORMAL, PARAMETER, realtime_priority


# How the robot's firmware reads its lines (robot_bridge, and fake_arena's emulated robots).
WIRE_PARAMETERS = (
    Param('wire_format', 'string', wire.DEFAULT_PRESET, 'a preset of wire.PRESETS, or empty '
          'for command_template and stop_template', choices=('',) + tuple(wire.PRESETS)),
    Param('command_template', 'string', '', "wire_format '': the command line, with {left} "
          'and {right} (wheel speeds) and optionally {seq}, terminator included'),
    Param('stop_template', 'string', '', "wire_format '': the stop line"),
    Param('unit', 'string', 'rad/s', "wire_format '': wheel speeds in 'rad/s' or 'm/s'",
          choices=('rad/s', 'm/s')),
    Param('wheel_radius', 'double', 0.015, 'wheel radius (m), for rad/s', positive=True),
)


def wire_format_parameter(p: SimpleNamespace) -> wire.WireFormat:
    """The WireFormat of WIRE_PARAMETERS' values; ParameterError naming wire_format."""
    try:
        return wire.wire_format(p.wire_format, p.command_template, p.stop_template, p.unit)
    except wire.WireError as exc:
        raise ParameterError(f"parameter 'wire_format': {exc}") from None


NODE_NAME = 'robot_bridge'   # also its console script's name
PARAMETERS = (
    Param('link', 'string', None, "where the robot is: 'udp:HOST:PORT' or 'serial:DEVICE'"),
    Param('baud', 'int', 115200, 'serial line speed (bits/s)', low=1),
    Param('wheel_base', 'double', MONA_WHEEL_BASE, 'distance between the wheels (m)',
          positive=True),
    Param.of(SETTINGS['limits.max_wheel_speed']),
    Param('rate_hz', 'double', 10.0, 'the most lines a second the robot takes, and two more '
          '(so that a late tick of a controller at this rate is never held back)',
          positive=True),
    Param('command_timeout', 'double', 0.5, 'cmd_vel older than this sends the stop line '
          '(s)', positive=True),
    Param('reply_timeout', 'double', 1.0, 'no line from the robot for this long is reported '
          'as a lost link (s); 0 = the robot does not answer', low=0.0),
    Param('stop_repeats', 'int', 3, 'stop lines sent on shutdown', low=1),
    Param(PARAMETER, 'int', BRIDGE, 'SCHED_FIFO priority (1-99) of the thread that '
          "takes cmd_vel and writes the robot's lines, so that a busy PC does not delay them; "
          '0 = normal scheduling. Needs root, CAP_SYS_NICE or an rtprio limit, else the bridge '
          'warns and runs at normal priority. Not used when the bridge shares a process',
          low=NORMAL, high=HIGHEST),
) + WIRE_PARAMETERS

TOPICS = (
    Use('sub', topics.CMD_VEL, 'velocity command; with more than one publishing node, the stop '
        'line until one is left'),
    Use('pub', topics.DIAGNOSTICS, 'link: sent, failed, malformed, last error, reply age, '
        'latency (1 Hz)'),
) + estop_uses('true sends the stop line at once and holds it until released (latched here, '
               'whoever sent it)')

LATENCY_WINDOW = 1000   # latencies kept for the diagnostics' percentiles
SPARE_LINES = 2         # lines beyond rate_hz allowed in any second (see _may_send)
WAIT_POLL = 0.001       # s between checks while a command waits for the robot's rate


class RobotBridge(Node):
    """cmd_vel -> wheel speeds -> the robot's wire format over its link."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.params = declare_parameters(self, PARAMETERS)
        try:
            self.link = robot_link(p.link, p.baud)
        except ValueError as exc:
            raise ParameterError(f"parameter 'link': {exc}") from None
        self.format = wire_format_parameter(p)
        # (left, right, perf counter at arrival) not yet sent
        self.command: tuple[float, float, float] | None = None
        self.command_time: float | None = None
        # write times of the last lines (s, perf counter), as many as one window allows
        self.window = max(1, round(p.rate_hz))
        self.written: collections.deque[float] = collections.deque(
            maxlen=self.window + SPARE_LINES)
        self.seq = 0
        self.counts = {'sent': 0, 'failed': 0, 'stops': 0, 'replies': 0, 'malformed': 0}
        self.last_error = ''          # the latest send error, kept for the diagnostics
        self.failing = False          # the latest send failed
        self.last_reply: float | None = None
        self.battery: float | None = None   # V, where the firmware's answers say it
        self.latencies: collections.deque[float] = collections.deque(maxlen=LATENCY_WINDOW)
        self.diag_pub = topics.publisher(self, topics.DIAGNOSTICS)
        reader = topics.subscription(self, topics.CMD_VEL, self._on_cmd)
        self.estop = EstopHolder(self, self._robot_name(), on_change=self._stop_if_held)
        self.source = CommandSourceWatch(self, topics.CMD_VEL, self._stop_if_held, reader)
        self.create_timer(1.0 / p.rate_hz, self._on_timer)
        # A command that came too soon after the last line is written as soon as it may be
        # (this timer runs only while one waits), not at the next tick of the timer above:
        # that would delay every command by the phase between the controller's timer and ours.
        self.waiting = self.create_timer(WAIT_POLL, self._on_waiting)
        self.waiting.cancel()
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f'bridge to {p.link} ({p.wire_format or "custom format"})')

    def _on_cmd(self, msg: Twist) -> None:
        v, w = messages.twist_from_msg(msg)
        if not (math.isfinite(v) and math.isfinite(w)):
            self.get_logger().warning('non-finite cmd_vel ignored', throttle_duration_sec=1.0)
            return
        received = time.perf_counter()
        left, right = wire.saturated_wheel_speeds(v, w, self.params.wheel_base,
                                        self.params.max_wheel_speed)
        self.command = (left, right, received)
        self.command_time = now_seconds(self)
        if self.held:
            return
        if self._may_send():
            self._send_command()
        elif self.waiting.is_canceled():
            self.waiting.reset()

    def _on_waiting(self) -> None:
        if self.command is None or self.held:
            self.waiting.cancel()
        elif self._may_send():
            self.waiting.cancel()
            self._send_command()

    def _robot_name(self) -> str:
        """'robot_3' in namespace /robot_3 (or /mona_3, ...: the namespace's last part)."""
        return self.get_namespace().rstrip('/').split('/')[-1]

    @property
    def held(self) -> bool:
        """The robot is held stopped: e-stop, or more than one node publishing its cmd_vel."""
        return self.estop.engaged or self.source.extra

    def _stop_if_held(self, *_: Any) -> None:
        if self.held:
            self.command = None
            self._send_stop()

    def _may_send(self) -> bool:
        """A line may go now: at most N + SPARE_LINES lines in any N periods (N = rate_hz
        rounded, about a second), i.e. two more than rate_hz lines a second.

        A controller at the robot's own rate is then never held back: its ticks come late
        now and then (a busy PC), and with one spare line (N + 1 in N periods) a tick 20 to
        90 ms late held the tick a second later back by as much (measured: 2 to 7 commands
        in 600 per robot, enough to put the p99 latency at 37 ms); with two, only a tick
        more than a whole period late could. Any gap between lines (one period, half a
        period, measured from the last line or from the last command's arrival, or a token
        bucket at the same rate) held commands of a 10 Hz controller back by 2 to 90 ms,
        and a strict one locked later commands into waits of their own. A runaway publisher
        gets (N + 2) / N x rate_hz lines a second, at most three back to back.
        """
        if len(self.written) < self.window + SPARE_LINES:
            return True
        return time.perf_counter() - self.written[0] >= self.window / self.params.rate_hz

    def _on_timer(self) -> None:
        self._read_replies()
        now = now_seconds(self)
        if self.held or is_stale(self.command_time, now, self.params.command_timeout):
            if self._may_send():
                self._send_stop()
        elif self.command is not None and self._may_send():
            self._send_command()

    def _send_command(self) -> None:
        assert self.command is not None   # _on_timer sends only a command it holds
        left, right, received = self.command
        self.command = None
        data = wire.encode(self.format, left, right, self._next_seq(), self.params.wheel_radius)
        if self._send(data):
            self.latencies.append(time.perf_counter() - received)

    def _send_stop(self) -> None:
        self._send(wire.encode_stop(self.format, self._next_seq()), stop=True)

    def _next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def _send(self, data: bytes, stop: bool = False) -> bool:
        try:
            self.link.send(data)
        except LinkError as exc:
            self.counts['failed'] += 1
            if str(exc) != self.last_error or not self.failing:
                self.get_logger().error(f'link: {exc}')
            self.last_error = str(exc)
            self.failing = True
            return False
        if self.failing:
            self.get_logger().info('link: sending again')
            self.failing = False
        self.written.append(time.perf_counter())
        self.counts['sent'] += 1
        self.counts['stops'] += stop
        return True

    def _read_replies(self) -> None:
        for line in self.link.lines():
            if wire.is_reply(line):
                self.counts['replies'] += 1
                self.last_reply = now_seconds(self)
                self.battery = wire.battery(line) or self.battery
            else:
                self.counts['malformed'] += 1

    def link_lost(self, now: float) -> bool:
        """True when the robot has not answered for reply_timeout (s)."""
        timeout = self.params.reply_timeout
        return timeout > 0 and self.counts['sent'] > 0 and is_stale(self.last_reply, now,
                                                                      timeout)

    def _publish_diagnostics(self) -> None:
        now = now_seconds(self)
        self._read_replies()
        lost = self.link_lost(now)
        age = 'never' if self.last_reply is None else f'{now - self.last_reply:.2f}'
        latency = (np.percentile(self.latencies, [50, 99]) * 1e3 if self.latencies
                   else [math.nan, math.nan])
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR if lost
            else DiagnosticStatus.WARN if self.failing else DiagnosticStatus.OK,
            name=self.get_fully_qualified_name(), hardware_id=self.params.link,
            message=('no reply from the robot' if lost else self.last_error if self.failing
                     else 'ok'),
            values=[KeyValue(key=k, value=str(v)) for k, v in self.counts.items()]
            + [KeyValue(key='dropped_lines', value=str(self.link.dropped)),
               KeyValue(key='command_publishers', value=', '.join(self.source.names)),
               KeyValue(key='last_error', value=self.last_error),
               KeyValue(key='reply_age_s', value=age),
               KeyValue(key='battery_v', value='unknown' if self.battery is None
                        else f'{self.battery:.2f}'),
               KeyValue(key='latency_ms_p50', value=f'{latency[0]:.3f}'),
               KeyValue(key='latency_ms_p99', value=f'{latency[1]:.3f}')])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = messages.seconds_to_stamp(now)
        self.diag_pub.publish(msg)
        if lost:
            self.get_logger().warning('no reply from the robot yet' if self.last_reply is None
                                      else f'no reply from the robot for {age} s',
                                      throttle_duration_sec=5.0)

    def on_shutdown(self) -> None:
        """Leave the robot stopped: the stop line stop_repeats times, 20 ms apart."""
        for _ in range(self.params.stop_repeats):
            self._send_stop()
            time.sleep(0.02)
        self.link.close()


def _bridge_in_its_own_process() -> 'RobotBridge':
    """A RobotBridge whose spinning thread (this process' main thread) runs at its
    realtime_priority: measured over pseudo-terminals with 9 bridges and a whole simulated
    run on 2 cores, cmd_vel-to-bytes latency p99 0.23-0.71 ms against 0.9-4.2 ms at normal
    priority, where the write was often preempted by the processes it woke.
    """
    node = RobotBridge()
    why_not = realtime_priority(node.params.realtime_priority)
    if why_not:
        node.get_logger().warning(f'realtime_priority {node.params.realtime_priority} not '
                                  f'taken ({why_not}): running at normal priority')
    return node


def main(args: list[str] | None = None) -> int:
    return run_node(_bridge_in_its_own_process, args)


if __name__ == '__main__':
    raise SystemExit(main())
