"""formation_recorder: records the formation's topics, as received, into a ROS 2 bag.

`curve-formation run ... --bag PATH` (and the demo) run it beside the monitor; started on its
own it records a run whose nodes were started by hand. The bag is closed on Ctrl-C, SIGTERM
and at the end of the run; killed hard, it loses at most the last second.
"""

from collections.abc import Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image

from curve_formation.bags import bag
from curve_formation.interface import TopicSpec
from curve_formation.nodes import qos, topics
from curve_formation.nodes.guard import Guarded
from curve_formation.nodes.params import declare_parameters, Param, ParameterError
from curve_formation.nodes.readiness import ReadyReport, REPORTED
from curve_formation.nodes.runtime import (
    RECORDER_NODE,
    run_node,
    spin_until_quiet,
    WithMessageInfo,
    writer_key,
)


# The recorder's own queue: deep, so a busy executor does not overwrite unread messages.
RECORD_DEPTH = 500


class Recorder(Node):
    """Writes every message of the given topics, as received, to an open bag.BagWriter.

    `streams` tallies each writer stream (runtime.writer_key): the DDS sequence number of the
    first message received, the last one, how many arrived and whether they came in order
    (they do from a single writer), from which analysis.bag_accounting tells what was lost.
    """

    def __init__(self, writer: Any, topic_list: Sequence[Any], **kwargs: Any) -> None:
        """topic_list: [topics.Topic] by absolute names (topics.recorded)."""
        super().__init__(RECORDER_NODE, start_parameter_services=False, **kwargs)
        self.writer = writer
        self.received = {}
        self.streams: dict[str, Any] = {}
        for recorded in topic_list:
            topic, msg_class, profile = (recorded.name, recorded.msg_class,
                                         recorded.reader_profile)
            wanted = recorded.reader_qos
            writer.add_topic(topic, recorded.type_name,
                             bag.qos(wanted.reliable, wanted.transient_local, wanted.depth or 0))
            self.received[topic] = 0
            deep = QoSProfile(depth=RECORD_DEPTH, reliability=profile.reliability,
                              durability=profile.durability)
            # the types whose writers runtime.writer_key tells apart by content
            keyed = msg_class if msg_class in (DiagnosticArray, DiagnosticStatus) else None
            subscription = self.create_subscription(
                msg_class, topic,
                Guarded(self, topic, WithMessageInfo(
                    lambda data, info, topic=topic, keyed=keyed:
                    self._on_message(topic, data, info, keyed))),
                deep, raw=True, event_callbacks=qos.observer_events())
            if topic == topics.CURVE:   # the bag's t = 0 is its first curve: not a later one
                ReadyReport(self, subscription, log=False)

    def _on_message(self, topic: str, data: bytes, info: dict[str, Any], keyed: bool) -> None:
        self.received[topic] += 1
        self.writer.write(topic, self.get_clock().now().nanoseconds, data)
        key = topic if keyed is None else writer_key(topic, deserialize_message(data, keyed))
        seq = info['publication_sequence_number']
        stream = self.streams.get(key)
        if stream is None:
            self.streams[key] = {'topic': topic, 'first': seq, 'last': seq, 'received': 1,
                                 'in_order': seq is not None}
            return
        stream['received'] += 1
        stream['in_order'] = stream['in_order'] and seq is not None and seq > stream['last']
        stream['last'] = seq


NODE_NAME = RECORDER_NODE   # also its console script's name
PARAMETERS = (
    Param('bag', 'string', None, 'path of the new bag (refused if it exists)'),
    Param('agent_count', 'int', None, 'number of robots n whose topics are recorded', low=1),
    Param('image_topics', 'string[]', [], 'sensor_msgs/Image topics to record as well'),
    Param('storage', 'string', bag.DEFAULT_STORAGE, "bag storage: mcap (Jazzy's default) or "
          'sqlite3', choices=tuple(bag.STORAGES)),
)

TOPICS = tuple(topics.Use('sub', t.name, robot='<i>' if t.per_robot else None)
               for t in topics.REGISTRY.values() if t.recorded == topics.EVERY_BAG) + (REPORTED,)


class RecorderNode(Recorder):
    """The recorder as a console script: opens the bag itself and closes it on shutdown."""

    def __init__(self, **kwargs: Any) -> None:
        # Parameters must be read before the bag exists, so a bootstrap node reads them.
        probe = Node('formation_recorder_parameters', **kwargs)
        try:
            p = declare_parameters(probe, PARAMETERS)
        finally:
            probe.destroy_node()
        try:
            writer = bag.BagWriter(p.bag, p.storage)
        except bag.BagError as exc:
            raise ParameterError(f"parameter 'bag': {exc}") from None
        writer.__enter__()
        try:   # a signal may come while the node is built: the bag is closed even then
            extra = [topics.Topic(TopicSpec(t, 'sensor_msgs/msg/Image', 'SENSOR',
                                            'a camera image'), Image) for t in p.image_topics]
            super().__init__(writer, topics.recorded(p.agent_count) + extra, **kwargs)
        except BaseException:
            writer.close()
            raise
        self.get_logger().info(f'recording {len(self.received)} topics to {p.bag}')

    def on_shutdown(self) -> None:
        # What arrived before the stop but is still queued goes into the bag too.
        if self.executor is not None:
            spin_until_quiet(self.executor, lambda: self.writer.count)
        self.writer.close()
        self.get_logger().info(f'bag closed: {self.writer.count} messages')

    def destroy_node(self) -> None:
        self.writer.close()   # also when on_shutdown did not run (context already shut down)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(RecorderNode, args, large_data=True)   # camera frames


if __name__ == '__main__':
    raise SystemExit(main())
