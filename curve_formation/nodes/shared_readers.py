"""One subscription to a topic for all the nodes of a process that read it (node_group).

A group's controllers each read the same broadcast topics (every robot's pose for the safety
filter, every holder's e-stop state): with one subscription per node, every message arrives
once per node, and each arrival costs the executor as much as the callback. Inside
`readers_shared()` the nodes that `subscribe` to such a topic share one subscription, whose
message is converted once (`convert`) and handed to each of them in the order they joined.
Outside it (a node alone in its process), `subscribe` makes the node's own subscription.
"""

from collections.abc import Callable, Iterator
import contextlib
from typing import Any

from rclpy.node import Node

from curve_formation.nodes import topics


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


@contextlib.contextmanager
def readers_shared() -> Iterator[None]:
    """The nodes made inside share one subscription per topic they `subscribe` to; they must
    not outlive the block.
    """
    global _shared
    _shared = {}
    try:
        yield
    finally:
        _shared = None


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
