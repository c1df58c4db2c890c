"""rosbag2's own bags (test/data/rosbag2) replayed over DDS, topic by topic where the type
exists here.
"""

import os
import subprocess
import sys
import threading

from conftest import DATA_DIR
from curve_formation.bags.bag import (
    describe_bag,
    read_messages,
)


BAGS = DATA_DIR / 'rosbag2'
# Topics of types installed here, and their bags (MCAP and sqlite3 alike)
PLAYABLE = {'talker': ['/rosout', '/topic'],
            'wbag': ['AAA', 'BBB', 'CCC', 'DDD', 'EEE', 'FFF', 'GGG', 'HHH']}


class Reader:
    """Keeps every message of a bag's playable topics, on a domain of its own."""

    def __init__(self, bag, domain):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        self.bag, self.expected = bag, {}
        for topic, _, _, msg in read_messages(bag, PLAYABLE[bag.name]):
            self.expected.setdefault(topic, []).append(text_of(topic, msg))
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.node = rclpy.create_node('bag_reader', context=self.context)
        self.executor.add_node(self.node)
        keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                              reliability=ReliabilityPolicy.RELIABLE)
        self.got = {topic: [] for topic in self.expected}
        for topic in self.expected:
            self.node.create_subscription(
                message_class(topic), topic,
                lambda m, topic=topic: self.got[topic].append(text_of(topic, m)), keep_all)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def complete(self):
        return all(len(self.got[t]) >= len(v) for t, v in self.expected.items())

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.thread.join(5.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def message_class(topic):
    from rcl_interfaces.msg import Log
    from std_msgs.msg import String
    return Log if topic == '/rosout' else String


def text_of(topic, msg):
    return msg.msg if topic == '/rosout' else msg.data


def test_replay_delivers_every_message_whose_type_exists_here(ros_domain):
    """`curve-formation replay` as a user starts it, one process per bag (MCAP and sqlite3,
    at once, each on a domain of its own); an in-process reader per topic keeps all. Topics of
    types not installed here are named and skipped.
    """
    import time
    bags = [BAGS / storage / name for storage in ('mcap', 'sqlite3') for name in PLAYABLE]
    readers, replays = [], []
    try:
        for k, bag in enumerate(bags):
            domain = (ros_domain + 40 * k) % 200 + 1
            readers.append(Reader(bag, domain))
            replays.append(subprocess.Popen(
                [sys.executable, '-m', 'curve_formation.cli', 'replay', str(bag), '--rate', '20',
                 '--wait', '20', '--no-clock'], env=dict(os.environ, ROS_DOMAIN_ID=str(domain)),
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not (
                all(r.poll() is not None for r in replays) and all(r.complete() for r in readers)):
            time.sleep(0.05)
    finally:
        outputs = []
        for proc in replays:
            proc.kill()
            outputs.append(proc.communicate())
        for reader in readers:
            reader.close()
    for bag, reader, proc, (out, err) in zip(bags, readers, replays, outputs, strict=True):
        assert proc.returncode == 0, (bag, err)
        for topic, values in reader.expected.items():
            if topic == '/rosout':   # other nodes may log too: every recorded line arrived
                assert set(values) <= set(reader.got[topic]), bag
            else:
                assert reader.got[topic] == values, (bag, topic, len(reader.got[topic]))
        sent = sum(len(v) for v in reader.expected.values())
        assert f'replayed {sent} messages' in out, (bag, out)
        for topic in describe_bag(bag)['topics']:
            if topic['topic'] not in reader.expected and topic['count']:
                assert f'skipping {topic["topic"]}' in out, (bag, out)
