"""Topics shared by the nodes of one process (node_group), as a ROS component container
shares them.

A group's controllers each read the same broadcast topics (every robot's pose for the safety
filter, every holder's e-stop state): with one subscription per node, every message arrives
once per node, and each arrival costs the executor as much as the callback. Inside
`readers_shared()` the nodes that `subscribe` to such a topic share one subscription, whose
message is converted once (`convert`) and handed to each of them in the order they joined.

A controller's state goes to its out-neighbours at the pose rate, and most of them are in
the same group: `subscribe_robot` and `publish_robot` hand such a message over in the process
(what rclcpp's intra-process communication does), and publish it on DDS only where something
else reads it (a neighbour in another process, the recorder). The handover skips DDS's copy,
take and conversion: 3000 states a second with a hundred robots. A node that reads a hosted
robot's topic this way does not hear another publisher on it (a test's or a lab's).

Outside `readers_shared()` (a node alone in its process) each node has its own
subscriptions and every message goes through DDS.
"""

from collections.abc import Callable, Iterable, Iterator
import contextlib
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher

from curve_formation.interface import robot_namespace, robot_topic
from curve_formation.nodes import topics
from curve_formation.nodes.guard import Guarded


Convert = Callable[[Node, Any], Any]   # (the first reader's node, message) -> what readers get


class SharedReader:
    """One topic's subscription, made on the first reader's node, for every reader of the
    process; a converted value of None is handed to nobody.
    """

    def __init__(self, name: str, convert: Convert) -> None:
        self.name = name
        self.convert = convert
        self.node: Node | None = None
        self.readers: list[Callable[[Any], None]] = []

    def join(self, node: Node, callback: Callable[[Any], None]) -> None:
        if self.node is None:   # the first reader's node reads for all
            self.node = node
            topics.subscription(node, self.name, self._on_message)
        self.readers.append(callback)

    def _on_message(self, msg: Any) -> None:
        assert self.node is not None
        value = self.convert(self.node, msg)
        if value is not None:
            for reader in self.readers:
                reader(value)


_shared: dict[str, SharedReader] | None = None   # the process's, while its nodes live
_hosted: frozenset[str] = frozenset()   # namespaces of the process's nodes ('/robot_3')
# absolute topic name -> the process's readers of a hosted robot's topic (publish_robot)
_local: dict[str, list[Callable[[Any], None]]] = {}


@contextlib.contextmanager
def readers_shared(hosted: Iterable[str] = ()) -> Iterator[None]:
    """The nodes made inside share one subscription per topic they `subscribe` to, and
    read the per-robot topics of the namespaces `hosted` here (subscribe_robot); they must
    not outlive the block.
    """
    global _shared, _hosted, _local
    _shared, _hosted, _local = {}, frozenset(hosted), {}
    try:
        yield
    finally:
        _shared, _hosted, _local = None, frozenset(), {}


def subscribe(node: Node, name: str, callback: Callable[[Any], None], convert: Convert
              ) -> None:
    """callback(convert(node, message)) for every message of topic `name` (a global one, the
    same for every node), through the process's shared subscription inside
    `readers_shared()`, else through the node's own. Every reader of a topic passes the same
    convert.
    """
    if _shared is None:
        SharedReader(name, convert).join(node, callback)
        return
    reader = _shared.setdefault(name, SharedReader(name, convert))
    if reader.convert is not convert:
        raise ValueError(f'{name}: every reader of a shared topic must convert it alike')
    reader.join(node, callback)


def subscribe_robot(node: Node, name: str, robot: int, callback: Callable[[Any], None]
                    ) -> None:
    """callback(message) for every message of robot `robot`'s topic `name`: handed over by
    its publisher's publish_robot where that robot's node is in this process (inside
    `readers_shared`), else through the node's own DDS subscription. Guarded either way.
    """
    placed = robot_topic(robot, name)
    if robot_namespace(robot) in _hosted:
        _local.setdefault(placed, []).append(Guarded(node, placed, callback))
        return
    topics.subscription(node, name, callback, robot=robot)


def publish_robot(publisher: Publisher, msg: Any) -> None:
    """Hand `msg` to this process's readers of the publisher's topic (subscribe_robot), then
    publish it on DDS if anything else reads it. The readers run now, before this returns.
    """
    for reader in _local.get(publisher.topic_name, ()):
        reader(msg)
    if publisher.get_subscription_count():
        publisher.publish(msg)
