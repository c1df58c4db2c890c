"""The fleet's status, as a lab watches it during a run: per robot whether its marker is seen,
whether its link answers (and how long ago), its battery where the firmware reports it, the
e-stop, whether it drives or stands, whether its controller is alive and how fast the robot
drives as its controller measured its wheels (top_speed: a weak motor or battery shows).
Published latched on /formation/fleet every STATUS_PERIOD s from the runner's monitor; a
robot whose marker or link is lost, or comes back, is an event with its time (s since t = 0)
for metrics.json and the report.
"""

from dataclasses import dataclass
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from std_msgs.msg import Float64

from curve_formation import diagnostics
from curve_formation.interface import robot_index, robot_name
from curve_formation.nodes import messages, topics
from curve_formation.nodes.runtime import now_seconds


STATUS_PERIOD = 1.0    # s between two fleet messages
UNSEEN_AFTER = 0.5     # s without a pose: the marker is not seen
SILENT_AFTER = 1.0     # s without a command: the controller is not alive


@dataclass
class RobotStatus:
    """One robot now: seen (pose age, s), link (None: no bridge reports it), reply age (s),
    battery (V), e-stopped, driving, controller alive, top speed (m/s, its controller's
    top_speed; NaN: none heard).
    """

    robot: int
    seen: bool
    pose_age: float | None
    link: bool | None
    reply_age: str
    battery: str
    estopped: bool
    driving: bool
    controller: bool
    top_speed: float = math.nan

    def values(self) -> dict[str, str]:
        link = {None: 'no bridge', True: 'up', False: 'down'}[self.link]
        return {'seen': str(self.seen).lower(),
                'pose_age_s': 'never' if self.pose_age is None else f'{self.pose_age:.2f}',
                'link': link, 'reply_age_s': self.reply_age, 'battery': self.battery,
                'estopped': str(self.estopped).lower(),
                'motion': 'driving' if self.driving else 'standing',
                'controller': 'alive' if self.controller else 'silent',
                'top_speed_mps': ('unknown' if math.isnan(self.top_speed)
                                  else f'{self.top_speed:.4f}')}


class FleetStatus:
    """The fleet's status from a Monitor's subscriptions, and the bridges' link reports it
    reads itself (from the start, where the monitor keeps them from t = 0).
    """

    def __init__(self, monitor: Any) -> None:
        self.monitor = monitor
        self.n = monitor.n
        # robot -> (level, reply age text, battery text) of its bridge's newest report
        self.link_reports: dict[int, tuple[int, str, str]] = {}
        # (t s since t = 0, robot, what): 'marker lost', 'marker seen again', 'link lost',
        # 'link back'
        self.events: list[tuple[float, int, str]] = []
        self._last: dict[int, RobotStatus] = {}
        self.publisher = topics.publisher(monitor, topics.FLEET)
        self.top_speeds = np.full(self.n, np.nan)   # m/s, each robot's controller's
        for i in range(1, self.n + 1):
            topics.subscription(monitor, topics.TOP_SPEED,
                                lambda msg, i=i: self._on_top_speed(i, msg), i)
        topics.subscription(monitor, topics.DIAGNOSTICS, self._on_diagnostics)
        monitor.create_timer(STATUS_PERIOD, self.publish)

    def _on_top_speed(self, i: int, msg: Float64) -> None:
        self.top_speeds[i - 1] = float(msg.data)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if not status.name.endswith(diagnostics.LINK_REPORTER):
                continue
            robot = robot_index(status.name)
            if robot is None:
                continue
            values = {kv.key: kv.value for kv in status.values}
            level = status.level[0] if isinstance(status.level, bytes) else status.level
            self.link_reports[robot] = (int(level), values.get('reply_age_s', 'never'),
                                            values.get('battery_v', 'unknown'))

    def statuses(self) -> list[RobotStatus]:
        """Every robot's RobotStatus now."""
        monitor = self.monitor
        now = now_seconds(monitor)
        held = monitor.estop_engaged
        out = []
        for i in range(1, self.n + 1):
            received = monitor.pose_received[i - 1]
            age = None if math.isnan(received) else now - float(received)
            report = self.link_reports.get(i)
            command = monitor.latest.commands[i - 1]
            commanded = monitor.command_times[i - 1]
            out.append(RobotStatus(
                robot=i, seen=age is not None and age <= UNSEEN_AFTER, pose_age=age,
                link=None if report is None else report[0] < 2,
                reply_age='-' if report is None else report[1],
                battery='unknown' if report is None else report[2], estopped=held,
                driving=bool(np.isfinite(command).all() and np.abs(command).max() > 0.0),
                controller=not math.isnan(commanded) and now - commanded <= SILENT_AFTER,
                top_speed=float(self.top_speeds[i - 1])))
        return out

    def publish(self) -> None:
        """The fleet message now, and the events since the last one (none once the run is
        over: its nodes stopping are not the run's).
        """
        if self.monitor.closed:
            return
        now = now_seconds(self.monitor)
        statuses = self.statuses()
        t0 = self.monitor.t0
        for status in statuses:
            before = self._last.get(status.robot)
            if t0 is not None and before is not None:
                t = round(now - t0, 2)
                if before.seen != status.seen:
                    self.events.append((t, status.robot, 'marker seen again' if status.seen
                                        else 'marker lost'))
                if before.link is not None and status.link is not None \
                        and before.link != status.link:
                    self.events.append((t, status.robot, 'link back' if status.link
                                        else 'link lost'))
            self._last[status.robot] = status
        msg = DiagnosticArray(status=[DiagnosticStatus(
            level=DiagnosticStatus.OK if s.seen and s.link is not False
            else DiagnosticStatus.ERROR, name=robot_name(s.robot), hardware_id='',
            message='ok' if s.seen and s.link is not False else
            ', '.join(filter(None, ['' if s.seen else 'not seen',
                                    'link down' if s.link is False else ''])),
            values=[KeyValue(key=k, value=v) for k, v in s.values().items()])
            for s in statuses])
        msg.header.stamp = messages.seconds_to_stamp(now)
        self.publisher.publish(msg)

    def summary(self) -> str:
        """One line for the runner's status: seen, links up, controllers alive."""
        statuses = self._last.values() or self.statuses()
        seen = sum(s.seen for s in statuses)
        links = [s.link for s in statuses if s.link is not None]
        alive = sum(s.controller for s in statuses)
        text = f'fleet: {seen}/{self.n} seen'
        if links:
            text += f', {sum(links)}/{len(links)} links up'
        return text + f', {alive}/{self.n} controllers alive'

    def as_dict(self) -> dict[str, Any]:
        """For metrics.json: the events and every robot's last status."""
        return {'events': [{'t': t, 'robot': robot, 'what': what}
                           for t, robot, what in self.events],
                'final': [{'robot': s.robot, **s.values()} for s in self._last.values()]}
