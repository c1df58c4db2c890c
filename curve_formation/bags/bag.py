"""ROS 2 bags through the pure-Python rosbags library (no rosbag2 install needed).

Storage is MCAP by default, as Jazzy's `ros2 bag record` writes it (chunks with message
indexes, a summary, `ros2msg` schemas and rosbag2's metadata record), or sqlite3 (.db3).
Both keep what a run killed hard (SIGKILL, power loss) had written up to the last second:
BagWriter closes an MCAP chunk (sqlite3: commits its transaction) every `commit_period` s and
flushes it to disk. A killed bag has no metadata.yaml (and an MCAP file no summary): `repair`
rewrites what it holds as a complete bag. Messages are written as the CDR bytes that crossed
DDS, with their receive time.
"""

from datetime import datetime, timezone
import os
from pathlib import Path, PurePath
import sqlite3
import time
from typing import Any

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import get_typestore, Stores
import yaml


STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
DEFAULT_STORAGE = 'mcap'
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
    """Write raw CDR messages to a new bag; use as a context manager (closes on any exit).

    storage: 'mcap' (Jazzy's default) or 'sqlite3'. Every `commit_period` s what was written
    is made durable: a run killed hard loses at most that much.
    """

    def __init__(self, path, storage=DEFAULT_STORAGE, commit_period=1.0):
        path = Path(path)
        if storage not in STORAGES:
            raise BagError(f'{path}: unknown bag storage {storage!r}; one of '
                           f'{", ".join(STORAGES)}')
        if path.exists():
            raise BagError(f'{path}: a bag (or file) already exists there; not overwriting')
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.storage = storage
        self.commit_period = commit_period
        self._writer = Writer(path, version=9, storage_plugin=STORAGES[storage])
        self._connections = {}
        self._last_commit = time.monotonic()
        self.count = 0

    def __enter__(self):
        self._writer.open()
        return self

    def __exit__(self, *exc):
        self.close()

    def add_topic(self, topic, msgtype, offered_qos):
        """Register a topic with its type name ('geometry_msgs/msg/PoseStamped') and its
        offered Qos (one, or a list: one per publisher).
        """
        profiles = list(offered_qos) if isinstance(offered_qos, (list, tuple)) and not \
            isinstance(offered_qos, Qos) else [offered_qos]
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=profiles)

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
        # the storage plugin's own state (sqlite3's connection, MCAP's open chunk), which
        # rosbags' StorageWriter protocol does not declare
        storage: Any = self._writer.storage
        if self.storage == 'sqlite3':
            storage.conn.commit()
        else:
            # rosbags keeps an MCAP chunk in memory until it holds 1 MiB: close it now (a
            # complete chunk record with its message indexes) and put it on disk.
            if storage.chunk.msgs:
                storage.close_chunk()
            storage.bio.flush()
            os.fsync(storage.bio.fileno())
        self._last_commit = time.monotonic()

    def close(self):
        if self._writer.storage is not None:
            self._writer.close()


def _open_error(path, exc):
    if (Path(path) / 'metadata.yaml').exists():
        return BagError(f'{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})')
    return BagError(f'{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc}); a bag '
                    'from a run killed hard needs `curve-formation bag repair` first')


def read_raw(path, topics=None):
    """Yield (connection, stamp_ns, cdr_bytes) in time order (file after file of a split
    bag); BagError if unreadable.

    Each storage file's own connections are read, each given as the metadata's connection of
    the same topic and type: rosbags matches them by their QoS as well, and in bags written by
    rosbag2 the metadata's QoS may differ from the file's, which read nothing.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    try:
        with Reader(path) as reader:
            described = {(c.topic, c.msgtype): c for c in reader.connections}
            files = getattr(reader.storage, 'storages', None)
            stored = ([c for storage in files for c in storage.connections] if files
                      else list(reader.connections))
            wanted = [c for c in stored if topics is None or c.topic in topics]
            if not wanted:
                return
            for conn, stamp, raw in reader.messages(connections=wanted):
                yield described.get((conn.topic, conn.msgtype), conn), stamp, raw
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


METADATA_VERSIONS = range(1, 10)   # rosbag2's metadata.yaml versions read here (Jazzy: 9)


def describe_bag(path):
    """What `ros2 bag info` tells of a bag, from its metadata.yaml alone (as rosbag2 does;
    versions 4 to 9, i.e. Foxy's to Jazzy's), as a dict: metadata version, storage, files,
    size (bytes), start, end and duration (ns since the epoch, ns), message count, custom
    metadata keys, and per topic its type, count, serialization format and offered QoS.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    meta_path = path / 'metadata.yaml'
    if not meta_path.exists():
        raise _open_error(path, FileNotFoundError(f'no {meta_path.name}'))
    try:
        meta = yaml.safe_load(meta_path.read_text())['rosbag2_bagfile_information']
        version = int(meta['version'])
        if version not in METADATA_VERSIONS:
            raise ValueError(f'metadata version {version}; this reader knows 1 to 9')
        topics = []
        for entry in meta['topics_with_message_count']:
            topic = entry['topic_metadata']
            profiles = parse_qos(topic.get('offered_qos_profiles') or [])
            topics.append({'topic': topic['name'], 'type': topic['type'],
                           'count': int(entry['message_count']),
                           'serialization_format': topic['serialization_format'],
                           'qos': [qos_text(q) for q in profiles]})
        files = [PurePath(f).name for f in meta['relative_file_paths']]
        start = int(meta['starting_time']['nanoseconds_since_epoch'])
        duration = int(meta['duration']['nanoseconds'])
        return {'path': str(path), 'version': version, 'storage': meta['storage_identifier'],
                'files': files,
                'size': sum(f.stat().st_size for f in path.iterdir() if f.is_file()),
                'start': start, 'end': start + duration, 'duration': duration,
                'messages': int(meta['message_count']),
                'custom': sorted(meta.get('custom_data') or {}),
                'topics': sorted(topics, key=lambda t: t['topic'])}
    except (KeyError, TypeError, ValueError, AttributeError, yaml.YAMLError) as exc:
        raise BagError(f'{meta_path}: not rosbag2 metadata ({type(exc).__name__}: {exc})') \
            from None


def qos_text(profile):
    """A Qos record in words: 'reliable, transient local, keep last 1'."""
    history = ('keep all' if profile.history == QosHistory.KEEP_ALL
               else f'keep last {profile.depth}')
    return ', '.join((profile.reliability.name.lower().replace('_', ' '),
                      profile.durability.name.lower().replace('_', ' '), history))


def format_bag_info(info):
    """The text of `curve-formation bag info`, laid out as `ros2 bag info` prints it."""
    def when(ns):
        moment = datetime.fromtimestamp(ns * 1e-9, tz=timezone.utc)
        return f'{moment:%b %d %Y %H:%M:%S}.{ns // 1_000_000 % 1000:03d} ({ns * 1e-9:.3f})'
    count = info['messages']
    lines = [f'Files:             {", ".join(info["files"])}',
             f'Bag size:          {_size_text(info["size"])}',
             f'Storage id:        {info["storage"]}',
             f'Duration:          {info["duration"] * 1e-9:.3f}s',
             f'Start:             {when(info["start"]) if count else "-"}',
             f'End:               {when(info["end"]) if count else "-"}',
             f'Messages:          {count}']
    for k, topic in enumerate(info['topics']):
        lines.append(('Topic information: ' if k == 0 else ' ' * 19)
                     + f'Topic: {topic["topic"]} | Type: {topic["type"]} | Count: '
                     f'{topic["count"]} | Serialization Format: '
                     f'{topic["serialization_format"]} | QoS: {"; ".join(topic["qos"])}')
    if info['custom']:
        lines.append(f'Custom data:       {", ".join(info["custom"])}')
    return '\n'.join(lines)


def _size_text(size):
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if size < 1024 or unit == 'GiB':
            return f'{size:.1f} {unit}' if unit != 'B' else f'{size} B'
        size /= 1024


def repair(path, out=None):
    """Rewrite a bag whose writer was killed (no metadata.yaml; for MCAP no summary) as a
    complete bag at `out` (default: PATH-repaired) in the same storage; the original is left
    as it is. Returns (out, messages copied). What a killed writer left half-written at the
    end of an MCAP file is dropped.
    """
    path = Path(path)
    out = Path(out) if out is not None else path.with_name(path.name + '-repaired')
    files = {'mcap': sorted(path.glob('*.mcap')), 'sqlite3': sorted(path.glob('*.db3'))}
    storage = next((name for name, found in files.items() if found), None)
    if storage is None:
        raise BagError(f'{path}: no .mcap or .db3 file to repair')
    topics, records = (_mcap_records(files['mcap']) if storage == 'mcap'
                       else _sqlite3_records(files['sqlite3']))
    with BagWriter(out, storage) as writer:
        for topic, (msgtype, profiles) in topics.items():
            writer.add_topic(topic, msgtype, profiles or [qos()])
        for topic, stamp, data in sorted(records, key=lambda r: r[1]):
            writer.write(topic, stamp, data)
    return out, len(records)


def _sqlite3_records(db_files):
    """({topic: (msgtype, [Qos])}, [(topic, stamp_ns, cdr)]) committed to .db3 files."""
    topics, records = {}, []
    for db in db_files:
        try:
            with sqlite3.connect(f'file:{db}?mode=ro', uri=True) as conn:
                names = {}
                for tid, name, msgtype, profiles in conn.execute(
                        'SELECT id, name, type, offered_qos_profiles FROM topics'):
                    names[tid] = name
                    topics[name] = (msgtype, parse_qos(profiles) if profiles else [])
                records += [(names[tid], stamp, bytes(data)) for tid, stamp, data in
                            conn.execute('SELECT topic_id, timestamp, data FROM messages')]
        except sqlite3.Error as exc:
            raise BagError(f'{db}: not a readable sqlite3 bag file ({exc})') from None
    return topics, records


def _mcap_records(mcap_files):
    """({topic: (msgtype, [Qos])}, [(topic, stamp_ns, cdr)]) of the complete records of
    .mcap files, read in order with the `mcap` library up to the first incomplete one.
    """
    try:
        from mcap.records import Channel, Message, Schema
        from mcap.stream_reader import StreamReader
    except ImportError:
        raise BagError('repairing an MCAP bag needs the `mcap` package (pip install mcap; '
                       'rosdep has no key for it)') from None
    topics, records = {}, []
    for path in mcap_files:
        schemas, channels = {}, {}
        with open(path, 'rb') as stream:
            reader = StreamReader(stream, validate_crcs=True)
            try:
                for record in reader.records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        profiles = record.metadata.get('offered_qos_profiles', '')
                        channels[record.id] = record.topic
                        topics[record.topic] = (schemas[record.schema_id],
                                                parse_qos(profiles) if profiles else [])
                    elif isinstance(record, Message) and record.channel_id in channels:
                        records.append((channels[record.channel_id], record.log_time,
                                        bytes(record.data)))
            except Exception:  # noqa: BLE001, S110 - the killed writer's unfinished tail
                pass
    return topics, records
