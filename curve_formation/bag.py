"""ROS 2 bags through the pure-Python rosbags library (no rosbag2 install needed).

Storage is sqlite3 (.db3), the rosbag2 format every ROS 2 install reads, chosen because it is
crash-consistent: BagWriter commits its transaction every `commit_period` seconds, so a run
killed hard (SIGKILL, power loss) keeps everything but the last period; metadata.yaml is
written on close and can be rebuilt for a killed bag with `ros2 bag reindex BAG`.
Messages are written as the CDR bytes that crossed DDS, with their receive time.
"""

from pathlib import Path
import time

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores


TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_ZERO = QosTime(0, 0)


class BagError(ValueError):
    """A bag that cannot be written or read; the message names the path."""


def qos(reliable=True, transient_local=False, depth=1):
    """A rosbags Qos record for the offered QoS of a recorded topic."""
    return Qos(QosHistory.KEEP_LAST, depth,
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False)


class BagWriter:
    """Write raw CDR messages to a new bag; use as a context manager (closes on any exit)."""

    def __init__(self, path, commit_period=1.0):
        path = Path(path)
        if path.exists():
            raise BagError(f'{path}: a bag (or file) already exists there; not overwriting')
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.commit_period = commit_period
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
        self._connections = {}
        self._last_commit = time.monotonic()
        self.count = 0

    def __enter__(self):
        self._writer.open()
        return self

    def __exit__(self, *exc):
        self.close()

    def add_topic(self, topic, msgtype, offered_qos):
        """Register a topic with its type name ('geometry_msgs/msg/PoseStamped') and Qos."""
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=[offered_qos])

    def write(self, topic, stamp_ns, data):
        """Append one serialized message received at stamp_ns (ns since the epoch)."""
        self._writer.write(self._connections[topic], int(stamp_ns), bytes(data))
        self.count += 1
        if time.monotonic() - self._last_commit >= self.commit_period:
            self.commit()

    def set_custom(self, key, value):
        """Store a string in the bag's metadata (custom_data), written on close."""
        self._writer.set_custom_data(key, str(value))

    def commit(self):
        """Make everything written so far durable (survives a hard kill)."""
        self._writer.storage.conn.commit()
        self._last_commit = time.monotonic()

    def close(self):
        if self._writer.storage is not None:
            self._writer.close()


def _open_error(path, exc):
    return BagError(f'{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc}); a bag '
                    'from a run killed hard needs `ros2 bag reindex` first')


def read_raw(path, topics=None):
    """Yield (connection, stamp_ns, cdr_bytes) in time order; BagError if unreadable."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    try:
        with Reader(path) as reader:
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            yield from reader.messages(connections=conns)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds for a broken bag
        raise _open_error(path, exc) from None


def read_messages(path, topics=None):
    """Yield (topic, msgtype, stamp_ns, message) from a bag, deserialized with rosbags."""
    for conn, stamp, raw in read_raw(path, topics):
        try:
            msg = TYPESTORE.deserialize_cdr(raw, conn.msgtype)
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'{path}: a {conn.msgtype} message on {conn.topic} at {stamp} ns '
                           f'cannot be decoded ({exc})') from None
        yield conn.topic, conn.msgtype, stamp, msg


def bag_info(path):
    """({topic: (msgtype, count)}, custom metadata dict) of a bag."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    try:
        with Reader(path) as reader:
            topics = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
            return topics, dict(reader.storage.metadata.custom or {})
    except Exception as exc:  # noqa: BLE001
        raise _open_error(path, exc) from None


def bag_summary(path):
    """{topic: (msgtype, count)} from a bag's metadata."""
    return bag_info(path)[0]
