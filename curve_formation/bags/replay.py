"""`curve-formation replay`: publish a bag's messages with their original timing and types.

Messages are published as the recorded CDR bytes, with the QoS the recording offered, at the
recorded receive times scaled by 1/rate. With `clock` (default) /clock carries the bag's time,
so nodes started with `use_sim_time:=true` see recorded stamps as fresh and tick on bag time.
"""

import importlib
import time
from typing import Any

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import QosDurability, QosReliability
from rosgraph_msgs.msg import Clock

from curve_formation.bags.bag import BagError, read_raw


CLOCK_PERIOD = 0.01   # s of bag time between /clock messages
MATCH_GRACE = 0.5     # s from the subscribers' discovery to the first message
ACK_WAIT = 30.0       # s at most, at the end, for reliable readers to acknowledge it all
# (a loaded machine's readers were seen to take more than 5 s)


def message_class(msgtype):
    """The rclpy message class for 'geometry_msgs/msg/Twist' (or the older
    'geometry_msgs/Twist'); BagError if that type is not installed here.
    """
    parts = msgtype.split('/')
    if len(parts) not in (2, 3) or (len(parts) == 3 and parts[1] != 'msg'):
        raise BagError(f'{msgtype} is not a message type (a service or action event?)')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[-1])
    except (ImportError, AttributeError):
        raise BagError(f'message type {msgtype} is not available here') from None


def playable(connections):
    """({topic: message class}, {topic: why skipped}) of a bag's topics {topic: connection}:
    a topic is replayed when its type is installed here.
    """
    classes, skipped = {}, {}
    for topic, conn in sorted(connections.items()):
        try:
            classes[topic] = message_class(conn.msgtype)
        except BagError as exc:
            skipped[topic] = str(exc)
    return classes, skipped


def qos_profile(connection):
    """The rclpy QoSProfile to replay a recorded topic with: the reliability and durability
    it was offered with (reliable and volatile if unknown). A reliable volatile topic keeps
    all until each reader has it, so that a burst (a bag recorded faster than it can be sent)
    is delivered whole; a latched one keeps its offered depth, which is what a late reader
    gets; a best-effort one, its offered depth (at least 10).
    """
    offered = getattr(connection.ext, 'offered_qos_profiles', None) or []
    q = offered[0] if offered else None
    reliable = q is None or q.reliability != QosReliability.BEST_EFFORT
    latched = q is not None and q.durability == QosDurability.TRANSIENT_LOCAL
    reliability = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
    durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
    if reliable and not latched:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=reliability,
                          durability=durability)
    offered_depth = q.depth if q is not None else 0
    depth = max(1, offered_depth) if latched else max(10, offered_depth)
    return QoSProfile(depth=depth, reliability=reliability, durability=durability)


def load(path, topics=None, start=0.0):
    """[(stamp_ns, topic, cdr)] and {topic: connection} from `start` s into the bag."""
    records: list[tuple[int, str, bytes]] = []
    connections: dict[str, Any] = {}
    for conn, stamp, raw in read_raw(path, topics):
        connections.setdefault(conn.topic, conn)
        records.append((stamp, conn.topic, bytes(raw)))
    if not records:
        raise BagError(f'{path}: no messages on {topics or "any topic"}')
    begin = records[0][0] + int(start * 1e9)
    return [r for r in records if r[0] >= begin], connections


def replay(node, path, rate=1.0, topics=None, loop=False, start=0.0, clock=True,
           wait_for_subscribers=0.0, log=print, stop=None):
    """Publish the bag through `node` (an rclpy Node); returns the number of messages sent.

    wait_for_subscribers: up to this many seconds for every topic to have a subscriber.
    stop: a threading.Event that ends the replay (a loop runs until it is set or Ctrl-C).
    """
    if rate <= 0:
        raise BagError(f'replay rate must be > 0, got {rate}')
    records, connections = load(path, topics, start)
    classes, skipped = playable(connections)
    for topic, why in skipped.items():
        log(f'skipping {topic}: {why}')
    if not classes:
        raise BagError(f'{path}: none of its topics has a message type installed here')
    publishers = {topic: node.create_publisher(cls, topic, qos_profile(connections[topic]))
                  for topic, cls in classes.items()}
    records = [r for r in records if r[1] in publishers]
    clock_pub = node.create_publisher(Clock, '/clock', 10) if clock else None
    deadline = time.monotonic() + wait_for_subscribers
    while time.monotonic() < deadline and any(
            p.get_subscription_count() == 0 for p in publishers.values()):
        time.sleep(0.05)
    if wait_for_subscribers > 0:
        # A publisher sees its reader before the reader sees it; what is sent meanwhile is
        # dropped by the reader (volatile), so the first messages of a bag were seen lost.
        time.sleep(MATCH_GRACE)
    log(f'replaying {len(records)} messages on {len(publishers)} topics at {rate:g}x'
        + (f' ({len(skipped)} skipped)' if skipped else ''))
    sent = 0
    while True:
        sent += _play_once(records, publishers, clock_pub, rate, stop)
        if not loop or (stop is not None and stop.is_set()):
            break
    # What a reliable reader has not yet acknowledged is lost if this process ends now.
    deadline = time.monotonic() + ACK_WAIT
    unacked = [topic for topic, publisher in publishers.items()
               if not publisher.wait_for_all_acked(Duration(
                   seconds=max(deadline - time.monotonic(), 0.0)))]
    if unacked:
        log(f'not acknowledged by every reader within {ACK_WAIT:g} s, so possibly not '
            f'received: the last messages of {", ".join(unacked)}')
    return sent


def _play_once(records, publishers, clock_pub, rate, stop=None):
    bag_start = records[0][0]
    wall_start = time.monotonic()
    next_clock = bag_start
    sent = 0
    for stamp, topic, raw in records:
        if stop is not None and stop.is_set():
            break
        while True:
            due = wall_start + (min(stamp, next_clock) - bag_start) * 1e-9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if clock_pub is None or next_clock > stamp:
                break
            _publish_clock(clock_pub, next_clock)
            next_clock += int(CLOCK_PERIOD * 1e9)
        publishers[topic].publish(raw)
        sent += 1
    return sent


def _publish_clock(publisher, stamp_ns):
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    publisher.publish(msg)
