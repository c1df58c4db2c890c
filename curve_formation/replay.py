"""`curve-formation replay`: publish a bag's messages with their original timing and types.

Messages are published as the recorded CDR bytes, with the QoS the recording offered, at the
recorded receive times scaled by 1/rate. With `clock` (default) /clock carries the bag's time,
so nodes started with `use_sim_time:=true` see recorded stamps as fresh and tick on bag time.
"""

import importlib
import time

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import QosDurability, QosReliability
from rosgraph_msgs.msg import Clock

from curve_formation.bag import BagError, read_raw


CLOCK_PERIOD = 0.01   # s of bag time between /clock messages


def message_class(msgtype):
    """The rclpy message class for 'geometry_msgs/msg/Twist'."""
    package, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError):
        raise BagError(f'message type {msgtype} is not available here') from None


def qos_profile(connection):
    """The rclpy QoSProfile a recorded topic was offered with (reliable, depth 10 if unknown)."""
    offered = getattr(connection.ext, 'offered_qos_profiles', None) or []
    if not offered:
        return QoSProfile(depth=10)
    q = offered[0]
    return QoSProfile(
        depth=max(1, q.depth),
        reliability=(ReliabilityPolicy.BEST_EFFORT if q.reliability == QosReliability.BEST_EFFORT
                     else ReliabilityPolicy.RELIABLE),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL
                    if q.durability == QosDurability.TRANSIENT_LOCAL
                    else DurabilityPolicy.VOLATILE))


def load(path, topics=None, start=0.0):
    """[(stamp_ns, topic, cdr)] and {topic: connection} from `start` s into the bag."""
    records, connections = [], {}
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
    publishers = {topic: node.create_publisher(message_class(conn.msgtype), topic,
                                               qos_profile(conn))
                  for topic, conn in connections.items()}
    clock_pub = node.create_publisher(Clock, '/clock', 10) if clock else None
    deadline = time.monotonic() + wait_for_subscribers
    while time.monotonic() < deadline and any(
            p.get_subscription_count() == 0 for p in publishers.values()):
        time.sleep(0.05)
    log(f'replaying {len(records)} messages on {len(publishers)} topics at {rate:g}x')
    sent = 0
    while True:
        sent += _play_once(records, publishers, clock_pub, rate, stop)
        if not loop or (stop is not None and stop.is_set()):
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
