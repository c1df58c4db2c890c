"""The e-stop in a node that acts on it: commands from anyone, latched here, announced.

Every node that can move a robot (formation_controller, robot_bridge, fake_robot, fake_arena)
and the curve server holds the e-stop through an EstopHolder:
- it reads /formation/estop (std_msgs/Bool: true stops, false releases) from any publisher,
  with two subscriptions: best effort (which every writer matches, whatever its reliability
  and durability) and reliable (a reliable sender's retransmissions);
- it keeps the state latched (core.controller.estop.EstopLatch) until a release, whoever sent it
and
  whether or not the sender is still there;
- it announces its state on /formation/estop_state (latched, and again every
  announce_period for a late joiner whose history Fast DDS failed to deliver: every second,
  less often in a team of more than TEAM_ANNOUNCEMENTS holders, so that a late joiner still
  hears one within about 1/TEAM_ANNOUNCEMENTS s): the
  confirmation `curve-formation estop` waits for, and how the other nodes learn of a stop
  that reached this one first (a sender that found only some nodes yet still stops them
  all) or that was engaged before they started.
"""

from collections.abc import Callable
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Bool

from curve_formation.core.controller.estop import EstopLatch, EstopReport
from curve_formation.nodes import messages, qos, shared_readers, topics
from curve_formation.nodes.command_source import command_publishers
from curve_formation.nodes.guard import Guarded
from curve_formation.nodes.runtime import now_seconds, WithMessageInfo
from curve_formation.nodes.topics import Use


ANNOUNCE_PERIOD = 1.0   # s between two announcements of an unchanged state, at the least
# Unchanged states a team announces per second, about, at most: a holder that hears more
# holders than this announces less often (announce_period), as every announcement reaches
# every process (a hundred robots' holders announcing every second took 19 % of a core)
TEAM_ANNOUNCEMENTS = 20.0
# announcement periods after its last announcement that a holder is still counted among
# those heard (the `holders` it announces, which `curve-formation estop` waits to have heard
# itself): a node that died is forgotten after a few of its announcements are missed
HOLDER_FORGOTTEN = 3.5
# s a node waits, at its start, to hear another node's e-stop state (or a command) before it
# takes the formation as not stopped: alone on the domain, nobody can hold a stop. A node that
# has discovered another holder by then waits on for that holder's state (latched, and
# announced again every announce_period), however long discovery takes.
HEAR_WAIT = 2.0
UNNAMED = 'a publisher not yet named by discovery'


def estop_uses(on_stop: str) -> tuple[Use, ...]:
    """The TOPICS rows (nodes/docs.py) of a node holding the e-stop; on_stop: what it does."""
    return (Use('sub', topics.ESTOP, on_stop),
            Use('sub', topics.ESTOP_STATE, "other nodes' e-stop state: started while the "
                'formation is stopped, it stays stopped'),
            Use('pub', topics.ESTOP_STATE, 'its e-stop state on every change and every second '
                '(less often past 20 holders: about 20 a second in all; what '
                '`curve-formation estop` waits for)'))


class EstopHolder:
    """A node's e-stop. on_change(engaged) runs at every change, before it is announced, and
    on_change(False) once the node has heard the e-stop state (a command, another node's state,
    or HEAR_WAIT s of silence with no other holder discovered) and it is not engaged: a node
    that must not move before then (a controller) starts stopped and waits for that call.
    """

    def __init__(self, node: Node, robot: str = '', robots: int = 0,
                 on_change: Callable[[bool], None] | None = None) -> None:
        """robot: the robot this node acts for ('robot_3'; '' for none); robots: the
        formation's size as this node knows it (0: unknown).
        """
        self.node = node
        self.robot = robot
        self.robots = robots
        self.on_change = on_change
        self.latch = EstopLatch()
        self.heard = False
        self.name = node.get_fully_qualified_name()
        # other holder -> time.monotonic() until which it is counted as heard
        self.peers: dict[str, float] = {}
        self.announced = -float('inf')   # time.monotonic() of the last announcement
        self.state_pub = topics.publisher(node, topics.ESTOP_STATE)
        on_command = Guarded(node, topics.ESTOP, WithMessageInfo(self._on_command))
        node.create_subscription(Bool, topics.ESTOP, on_command, qos.ANY_PUBLISHER)
        # Without rclpy's incompatible-QoS warning: a best-effort sender, which this one does
        # not match, is read by the one above.
        node.create_subscription(Bool, topics.ESTOP, on_command, qos.ESTOP_RELIABLE,
                                 event_callbacks=qos.observer_events())
        # one subscription for a group's holders (shared_readers), each state converted once
        shared_readers.subscribe(node, topics.ESTOP_STATE, self._on_heard, heard_report)
        node.create_timer(ANNOUNCE_PERIOD, self._announce_if_due)
        self._hear_timer = node.create_timer(HEAR_WAIT, self._silence)
        self.announce()

    @property
    def engaged(self) -> bool:
        return self.latch.engaged

    def _silence(self) -> None:
        """HEAR_WAIT s have passed (and every HEAR_WAIT s after until heard): silence tells
        the state only when no other holder is discovered. One that is has a state on its way
        (a restarted controller under load was seen to find its peers only after 2 s).
        """
        others = self.node.count_publishers(topics.ESTOP_STATE) - 1
        if others > 0:
            self.node.get_logger().info(
                f'waiting for the e-stop state of {others} other holder(s) discovered',
                throttle_duration_sec=10.0)
            return
        self._hear()

    def _hear(self) -> None:
        """The e-stop state is known from now on; on_change if that releases the robot."""
        if self.heard:
            return
        self.heard = True
        self._hear_timer.cancel()
        if not self.latch.engaged and self.on_change is not None:
            self.on_change(False)

    def _announce_if_due(self) -> None:
        if time.monotonic() - self.announced >= announce_period(self.holders()) - 0.05:
            self.announce()

    def announce(self) -> None:
        self.announced = time.monotonic()
        latch = self.latch
        if latch.by == UNNAMED:   # discovery may know the sender's name by now
            latch.by = self._senders()
        self.state_pub.publish(messages.estop_state_to_msg(
            self.name, self.node.get_name(), self.robot, latch.engaged, latch.by, latch.since,
            self.robots, self.holders()))

    def holders(self) -> int:
        """The holders this node hears announce now (HOLDER_FORGOTTEN), itself included."""
        now = time.monotonic()
        return 1 + sum(1 for until in self.peers.values() if until >= now)

    def _senders(self) -> str:
        """Names of the nodes publishing e-stop commands now (who sent, as far as DDS tells:
        a message does not carry its sender's name).
        """
        return ', '.join(command_publishers(self.node, topics.ESTOP)) or UNNAMED

    def _on_command(self, msg: Bool, info: dict[str, Any]) -> None:
        sent_at = info['source_timestamp'] * 1e-9
        engaged = bool(msg.data)
        if self.latch.command(engaged, sent_at, '', now_seconds(self.node)):
            self.latch.by = self._senders()   # asked of the graph only on a change
            self._changed()
        elif not engaged and self.latch.engaged:
            self.node.get_logger().warning('e-stop release older than the stop ignored',
                                           throttle_duration_sec=1.0)
        self._hear()

    def _on_heard(self, heard: tuple[EstopReport, float]) -> None:
        self.on_report(*heard)

    def on_report(self, report: EstopReport, heard: float | None = None) -> None:
        """A holder's announced state (this one's own included, which changes nothing),
        heard at `heard` (time.monotonic(); default now).
        """
        if report.holder == self.name:
            return
        heard = time.monotonic() if heard is None else heard
        self.peers[report.holder] = heard + HOLDER_FORGOTTEN * announce_period(report.holders)
        # (a release is never adopted from a peer: the clock is read only for a stop)
        if report.engaged and self.latch.peer(True, report.since, report.by,
                                              now_seconds(self.node)):
            self._changed(f' (passed on by {report.holder})')
        self._hear()

    def _changed(self, how: str = '') -> None:
        latch = self.latch
        if self.on_change is not None and (self.heard or latch.engaged):
            self.on_change(latch.engaged)
        self.node.get_logger().warning(
            f'e-stop {"engaged" if latch.engaged else "released"} by {latch.by}{how}')
        self.announce()


def announce_period(holders: int) -> float:
    """s between two announcements of an unchanged state by a holder that hears `holders`
    (itself included; 0: not told): ANNOUNCE_PERIOD, longer past TEAM_ANNOUNCEMENTS holders.
    """
    return ANNOUNCE_PERIOD * max(1.0, holders / TEAM_ANNOUNCEMENTS)


def heard_report(node: Node, msg: DiagnosticStatus) -> tuple[EstopReport, float] | None:
    """(the e-stop state a message tells, time.monotonic() now), or None (logged on `node`)
    if it tells none.
    """
    try:
        return messages.estop_state_from_msg(msg), time.monotonic()
    except messages.MessageError as exc:
        node.get_logger().warning(f'{topics.ESTOP_STATE}: {exc}', throttle_duration_sec=5.0)
        return None
