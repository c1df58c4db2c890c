"""One command source per robot: who publishes a robot's cmd_vel, watched from the graph.

A robot's cmd_vel has one publisher, its controller (or a teleop node the lab put there in
its place). A second one (a script on the wrong namespace, a forgotten teleop) would make the
robot obey two masters in turn. The fake robots, the fake arena and the robot bridges hold
their robot stopped while a cmd_vel has more than one publishing node, until it has one again;
the controllers and the runner's monitor report it. A guard against mistakes, not against an
intruder: without DDS security anyone on the domain can still publish as the controller's
own node name.
"""
from collections.abc import Callable

from rclpy.node import Node
from rclpy.subscription import Subscription


WATCH_PERIOD = 0.5   # s between two looks at a robot side's or the monitor's subscription
# s between two looks at the graph by a node that only publishes the topic (a controller,
# which reports a second source but does not stop the robot): a count of the graph's
# publishers walks the graph, whose size grows with the team (a hundred controllers looking
# twice a second took 9 % of their process)
REPORT_PERIOD = 2.0


def publisher_count(node: Node, topic: str, subscription: Subscription | None = None) -> int:
    """How many publish `topic`: as matched with `subscription` (a number DDS keeps, where
    the node reads the topic), else counted in the graph.
    """
    if subscription is not None:
        return subscription.get_publisher_count()
    return node.count_publishers(topic)


def command_publishers(node: Node, topic: str) -> list[str]:
    """Sorted names of the nodes publishing on `topic` (as far as discovery has named them;
    a node restarted under the same name counts once): a cmd_vel's, or the e-stop's senders.
    """
    return sorted({f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                   for i in node.get_publishers_info_by_topic(topic)
                   if not i.node_name.startswith('_NODE_NAME_UNKNOWN')})


class CommandSourceWatch:
    """Watches a robot's cmd_vel for more than one publishing node; `extra` while it has.

    on_change(extra, names) runs when that changes; the change is logged. With `subscription`
    (the node's own to the topic) it looks every WATCH_PERIOD at the publishers matched with
    it, without it every REPORT_PERIOD at the graph.
    """

    def __init__(self, node: Node, topic: str,
                 on_change: Callable[[bool, list[str]], None] | None = None,
                 subscription: Subscription | None = None) -> None:
        self.node = node
        self.subscription = subscription
        self.topic = node.resolve_topic_name(topic)
        self.on_change = on_change
        self.names: list[str] = []
        self.extra = False
        self.episodes = 0     # times a second publisher appeared
        self.count = -1       # publishers DDS counted at the last look
        node.create_timer(REPORT_PERIOD if subscription is None else WATCH_PERIOD, self.look)

    def look(self) -> None:
        # Named again only when the count changes, is more than one or was not all named
        # yet: the names are a walk of the graph in Python, the count a number (a hundred
        # robots' watches looked 400 times a second)
        count = publisher_count(self.node, self.topic, self.subscription)
        if count == self.count and count <= 1 and len(self.names) == count:
            return
        self.count = count
        names = command_publishers(self.node, self.topic)
        extra = len(names) > 1
        self.names = names
        if extra == self.extra:
            return
        self.extra = extra
        if extra:
            self.episodes += 1
            self.node.get_logger().error(
                f'{len(names)} nodes publish {self.topic}: {", ".join(names)}; one command '
                'source per robot')
        else:
            self.node.get_logger().warning(f'{self.topic} has one publisher again')
        if self.on_change is not None:
            self.on_change(extra, names)
