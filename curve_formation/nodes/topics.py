"""The formation's topics (interface.TOPICS, where each is described once) with their rclpy
message classes.

Nodes create their publishers and subscriptions through `publisher` and `subscription`, the
recorder records the topics marked `recorded`, and the node tables of docs/nodes.md
(nodes/docs.py) are generated from the same records. Per-robot topics have relative names, so
a robot is placed by its namespace; `robot_topic` gives their absolute names.
"""

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from typing import Any, NamedTuple

from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

from curve_formation.interface import (  # noqa: F401 (the names, for the nodes)
    CAMERA_DEBUG,
    CAMERA_IMAGE,
    CAMERA_POSES,
    CMD_VEL,
    CURVE,
    CURVE_MARKERS,
    CURVE_PATH,
    DIAGNOSTICS,
    ESTIMATE,
    ESTOP,
    ESTOP_STATE,
    EVERY_BAG,
    FLEET,
    OBSERVED_CURVE,
    POSE,
    PREFLIGHT,
    QOS,
    QosSpec,
    READY,
    robot_namespace,
    ROBOT_POSES,
    robot_topic,
    STATE,
    TICK,
    TOP_SPEED,
    TOPICS,
    TopicSpec,
    TRUE_POSE,
    WITH_IMAGES,
)
from curve_formation.nodes import qos
from curve_formation.nodes.guard import Guarded


def message_class(type_name: str) -> type:
    """The rclpy message class of a type name such as 'geometry_msgs/msg/PoseStamped'."""
    package, kind, name = type_name.split('/')
    return getattr(import_module(f'{package}.{kind}'), name)


@dataclass(frozen=True)
class Topic:
    """A topic of interface.TOPICS (its name, type, QoS, meaning and recording) with its rclpy
    message class, under the name it is placed at (a per-robot topic's absolute name in
    `recorded`; default the spec's).
    """

    spec: TopicSpec
    msg_class: type
    placed: str | None = None

    @classmethod
    def of(cls, spec: TopicSpec, placed: str | None = None) -> 'Topic':
        return cls(spec, message_class(spec.type_name), placed)

    @property
    def name(self) -> str:
        return self.placed or self.spec.name

    @property
    def meaning(self) -> str:
        return self.spec.meaning

    @property
    def recorded(self) -> str | None:
        return self.spec.recorded

    @property
    def profile(self) -> QoSProfile:
        return getattr(qos, self.spec.qos_name)

    @property
    def reader_profile(self) -> QoSProfile:
        return getattr(qos, self.spec.reader_qos_key)

    @property
    def reader_qos(self) -> QosSpec:
        """The QoS our subscriptions ask, as data (interface.QOS)."""
        return QOS[self.spec.reader_qos_key]

    @property
    def per_robot(self) -> bool:
        return not self.name.startswith('/')

    @property
    def type_name(self) -> str:
        """'geometry_msgs/msg/PoseStamped', as bags and `ros2 topic` name it."""
        return f'{self.msg_class.__module__.split(".")[0]}/msg/{self.msg_class.__name__}'


REGISTRY = {name: Topic.of(spec) for name, spec in TOPICS.items()}


def _placed(name: str, robot: int | str | None) -> str:
    return name if robot is None else robot_topic(robot, name)  # type: ignore[arg-type]


def publisher(node: Node, name: str, robot: int | str | None = None) -> Publisher:
    """node's publisher of the registered topic `name` (of robot `robot`, if given)."""
    topic = REGISTRY[name]
    return node.create_publisher(topic.msg_class, _placed(name, robot), topic.profile)


def subscription(node: Node, name: str, callback: Callable[..., Any],
                 robot: int | str | None = None, **kwargs: Any) -> Subscription:
    """node's subscription to the registered topic `name` (of robot `robot`, if given), its
    callback guarded (nodes/guard.py: a message it cannot take is rejected, never fatal);
    kwargs go to create_subscription (raw, event_callbacks).
    """
    topic = REGISTRY[name]
    placed = _placed(name, robot)
    return node.create_subscription(topic.msg_class, placed, Guarded(node, placed, callback),
                                    topic.reader_profile, **kwargs)


def recorded(n: int, images: bool = False) -> list['Topic']:
    """[Topic] a run of n robots records, per-robot topics by their absolute names."""
    kinds = (EVERY_BAG, WITH_IMAGES) if images else (EVERY_BAG,)
    chosen = [t for t in REGISTRY.values() if t.recorded in kinds]
    out = [t for t in chosen if not t.per_robot]
    for i in range(1, n + 1):
        out += [Topic(t.spec, t.msg_class, robot_topic(i, t.name)) for t in chosen
                if t.per_robot]
    return out


class Use(NamedTuple):
    """A line of a node's TOPICS table: 'pub' or 'sub', a registered name, what the node
    does with it (default: the registry's meaning), and for a per-robot topic the robot's
    placeholder shown in its name ('<i>': every robot; None: the node's own namespace).
    """

    direction: str
    name: str
    meaning: str | None = None
    robot: str | None = None

    @property
    def shown_name(self) -> str:
        return _placed(self.name, self.robot)
