"""Bags written by rosbag2 itself (its own test resources, test/data/rosbag2): described as
`ros2 bag info` describes them, read whole, replayed over DDS topic by topic where the type
exists here, analysed without tripping on topics the analysis does not read.
"""

import os
import subprocess
import sys
import threading

import pytest
import yaml

from conftest import DATA_DIR
from curve_formation.bags.bag import (
    BagError,
    describe_bag,
    format_bag_info,
    read_messages,
    read_raw,
)


BAGS = DATA_DIR / 'rosbag2'
ALL = sorted(p.relative_to(BAGS) for p in BAGS.glob('*/*') if p.is_dir())
UNREADABLE = {'wrong_rmw_test'}   # serialization format 'wrong_format': no reader decodes it
# Topics of types installed here, and their bags (MCAP and sqlite3 alike)
PLAYABLE = {'talker': ['/rosout', '/topic'],
            'wbag': ['AAA', 'BBB', 'CCC', 'DDD', 'EEE', 'FFF', 'GGG', 'HHH']}


def metadata(bag):
    return yaml.safe_load((BAGS / bag / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']


def test_the_bags_cover_every_metadata_version_rosbag2_wrote_before_ours():
    assert {metadata(bag)['version'] for bag in ALL} == {4, 5, 6, 7, 8}
    assert {metadata(bag)['storage_identifier'] for bag in ALL} == {'mcap', 'sqlite3'}


@pytest.mark.parametrize('bag', ALL, ids=str)
def test_bag_info_tells_what_the_metadata_holds(bag):
    meta = metadata(bag)
    info = describe_bag(BAGS / bag)
    assert info['version'] == meta['version']
    assert info['storage'] == meta['storage_identifier'] == bag.parts[0]
    assert info['files'] == [os.path.basename(f) for f in meta['relative_file_paths']]
    assert info['messages'] == meta['message_count']
    assert {t['topic']: t['count'] for t in info['topics']} == {
        e['topic_metadata']['name']: e['message_count']
        for e in meta['topics_with_message_count']}
    text = format_bag_info(info)
    assert f'Storage id:        {bag.parts[0]}' in text
    assert f'Files:             {", ".join(info["files"])}' in text


def test_bag_info_of_a_version_4_mcap_bag_from_the_command_line():
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'bag', 'info',
                           str(BAGS / 'mcap' / 'talker')], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert 'Files:             talker.mcap\nBag size:' in proc.stdout
    assert 'Storage id:        mcap' in proc.stdout
    assert ('Topic: /topic | Type: std_msgs/msg/String | Count: 10 | Serialization Format: cdr'
            ' | QoS: reliable, volatile, keep last 0') in proc.stdout


@pytest.mark.parametrize('bag', ALL, ids=str)
def test_every_message_is_read_whatever_the_metadata_qos(bag):
    """rosbags alone read nothing of 5 of these bags: their metadata offers other QoS than
    their storage files record.
    """
    if bag.name in UNREADABLE:
        with pytest.raises(BagError, match='wrong_format'):
            list(read_raw(BAGS / bag))
        return
    counts = {}
    for conn, _, _ in read_raw(BAGS / bag):
        counts[conn.topic] = counts.get(conn.topic, 0) + 1
    assert counts == {e['topic_metadata']['name']: e['message_count']
                      for e in metadata(bag)['topics_with_message_count']
                      if e['message_count']}


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


@pytest.mark.ros
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


def test_replay_of_a_bag_without_any_known_type_says_so():
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'replay',
                           str(BAGS / 'sqlite3' / 'cdr_test'), '--wait', '0'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'skipping /test_topic: message type test_msgs/msg/BasicTypes is not available' \
        in proc.stdout
    assert 'none of its topics has a message type installed here' in proc.stderr
