"""Start-up handshake: the curve's subscribers say when they can receive from the curve server.

A subscription the curve server counts as matched (`get_subscription_count`, the writer's
side) can still be seconds from receiving: its own side may not have discovered the server's
writer yet, and data from an undiscovered writer is dropped until it has. Measured on the
fault run of the arena demo (9 controllers, recorder, monitor): in 6 of 30 starts one
controller, the leader in two, got curve 0 0.8-1.9 s after the others, each time just after its
subscription first counted a publisher. So every node that should start with the schedule
says so on /formation/ready (std_msgs/String, its node name, latched) once its own subscription
to /formation/curve counts a publisher, and the curve server starts the schedule once enough
have and its own publisher has matched as many subscriptions (the writer's side of the same
links: a curve published before reaches only the readers it has matched, and the others get
a later one).
"""

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.subscription import Subscription
from std_msgs.msg import String

from curve_formation.nodes import topics


POLL = 0.05   # s, how often a node checks whether its curve subscription has a publisher


class ReadyReport:
    """Publishes the node's name on /formation/ready once `subscription` has a publisher and
    `waits` (if given) is False: nothing more is awaited (a controller's motor check, which runs
    before the experiment's first curve: controller.motor_check).

    log: say so in the node's log (the runner's own monitor does not, to keep a terminal quiet).
    """

    def __init__(self, node: Node, subscription: Subscription, log: bool = True,
                 waits: Callable[[], bool] | None = None) -> None:
        self._node = node
        self._log = log
        self._subscription = subscription
        self._waits = waits
        self._pub = topics.publisher(node, topics.READY)
        self._timer = node.create_timer(POLL, self._poll)
        self.reported = False

    def _poll(self) -> None:
        if self._subscription.get_publisher_count() == 0:
            return
        if self._waits is not None and self._waits():
            return
        self.reported = True
        self._pub.publish(String(data=self._node.get_fully_qualified_name()))
        self._timer.cancel()
        if self._log:
            self._node.get_logger().info('ready: /formation/curve has a publisher')


def subscribe_to_curve(node: Node, callback: Callable[..., Any], log: bool = True,
                       waits: Callable[[], bool] | None = None,
                       **kwargs: Any) -> Subscription:
    """node's subscription to /formation/curve, reported ready once it has a publisher and
    `waits` (if given) is False (ReadyReport; kwargs go to create_subscription).
    """
    subscription = topics.subscription(node, topics.CURVE, callback, **kwargs)
    ReadyReport(node, subscription, log, waits)   # kept alive by its timer, which the node holds
    return subscription


class ReadyCount:
    """The names of the nodes that have reported ready (read by the curve server)."""

    def __init__(self, node: Node) -> None:
        self.names: set[str] = set()
        topics.subscription(node, topics.READY, self._on_ready)

    def _on_ready(self, msg: String) -> None:
        self.names.add(msg.data)

    def __len__(self) -> int:
        return len(self.names)


# The line a reporting node adds to its TOPICS (nodes/docs.py).
REPORTED = topics.Use('pub', topics.READY,
                      "this node's name, once it can receive /formation/curve (start-up "
                      'handshake)')
