"""Subscription callbacks that are total: any message is taken or rejected, never fatal.

A message that a callback cannot take (a decoder's MessageError, an implausible value, or any
other exception) is rejected: counted per topic and cause, logged once per cause per
LOG_PERIOD, and the node goes on. rclpy would otherwise let the exception out of spin and end
the process: one bad message from a buggy script on the domain would stop every robot whose
controller read it.
"""

from collections.abc import Callable
import inspect
import time
from typing import Any
import weakref

from rclpy.node import Node


LOG_PERIOD = 5.0   # s between two log lines of the same topic and cause


class Rejections:
    """A node's rejected messages: {topic: count}, the last cause, throttled logging."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.counts: dict[str, int] = {}
        self.last = ''
        # (topic, cause kind) -> time.monotonic() of the last log line
        self._logged: dict[tuple[str, str], float] = {}

    def reject(self, topic: str, cause: object) -> None:
        """Count and (throttled) log one rejected message on `topic` because of `cause`."""
        self.counts[topic] = self.counts.get(topic, 0) + 1
        text = ' '.join(str(cause).split())[:300]
        self.last = f'{topic}: {text}'
        kind = (topic, type(cause).__name__ if isinstance(cause, Exception) else text[:40])
        now = time.monotonic()
        if now - self._logged.get(kind, -LOG_PERIOD) >= LOG_PERIOD:
            self._logged[kind] = now
            self.node.get_logger().warning(
                f'message on {topic} rejected ({self.counts[topic]} so far): {text}')

    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> str:
        """'topic: n, ...' for diagnostics ('' when none)."""
        return ', '.join(f'{topic}: {n}' for topic, n in sorted(self.counts.items()))


_REJECTIONS: 'weakref.WeakKeyDictionary[Node, Rejections]' = weakref.WeakKeyDictionary()


def rejections(node: Node) -> 'Rejections':
    """The node's Rejections, created on first use."""
    found = _REJECTIONS.get(node)
    if found is None:
        found = _REJECTIONS[node] = Rejections(node)
    return found


class Guarded:
    """A subscription callback that rejects (rejections(node).reject) what raises in it.

    It keeps the wrapped callback's signature, so rclpy still passes a MessageInfo to a
    two-argument callback (runtime.WithMessageInfo).
    """

    def __init__(self, node: Node, topic: str, fn: Callable[..., Any]) -> None:
        self.fn = fn
        self.topic = topic
        self.book = rejections(node)
        self.__signature__ = inspect.signature(fn)

    def __call__(self, *args: Any) -> Any:
        try:
            return self.fn(*args)
        except Exception as exc:  # noqa: BLE001 - any message, any fault: rejected, not fatal
            self.book.reject(self.topic, exc)
            return None
