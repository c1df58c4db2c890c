"""ROS 2 bags as files: written and read back, the accounting of what a run published
against what its bag holds, and a bad path or a corrupt bag refused clearly.
"""

import json

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist
import pytest
from rclpy.serialization import serialize_message

from curve_formation.bags.analysis import bag_accounting
from curve_formation.bags.bag import bag_summary, BagError, BagWriter, qos, read_messages
from curve_formation.nodes.runtime import PublicationCounter


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_write_then_read_round_trip(tmp_path, storage):
    path = tmp_path / 'bag'
    with BagWriter(path, storage) as writer:
        writer.add_topic('/robot_1/cmd_vel', 'geometry_msgs/msg/Twist', qos())
        for k in range(50):
            msg = Twist()
            msg.linear.x, msg.angular.z = 0.01 * k, -0.1 * k
            writer.write('/robot_1/cmd_vel', 1_000_000_000 + k * 100_000_000,
                         serialize_message(msg))
    assert bag_summary(path) == {'/robot_1/cmd_vel': ('geometry_msgs/msg/Twist', 50)}
    got = list(read_messages(path))
    assert [m.linear.x for _, _, _, m in got] == pytest.approx([0.01 * k for k in range(50)])
    assert [stamp for _, _, stamp, _ in got] == sorted(stamp for _, _, stamp, _ in got)
    assert (path / 'metadata.yaml').read_text().count('offered_qos_profiles') == 1
    assert len(list(path.glob('*.mcap' if storage == 'mcap' else '*.db3'))) == 1


class _NodeStub:
    """A node with a cmd_vel and a /diagnostics publisher that only count what they send."""

    def __init__(self):
        self.sent = 0
        stub = self

        class Publisher:
            def __init__(self, topic_name):
                self.topic_name = topic_name

            def publish(self, msg):
                stub.sent += 1

        self.publishers = [Publisher('/robot_1/cmd_vel'), Publisher('/diagnostics')]


def test_publications_are_counted_per_writer_stream():
    node = _NodeStub()
    counter = PublicationCounter(node)
    cmd, diagnostics = node.publishers
    for _ in range(3):
        cmd.publish(Twist())
    for name in ('/robot_1/formation_controller', '/robot_1/formation_controller', 'other'):
        diagnostics.publish(DiagnosticArray(status=[DiagnosticStatus(name=name)]))
    assert node.sent == 6
    assert counter.counts == {'/robot_1/cmd_vel': 3,
                              '/diagnostics /robot_1/formation_controller': 2,
                              '/diagnostics other': 1}


def accounting(tmp_path, publications, streams, recorded):
    """bag_accounting over node files `publications` ([{key: count}]) and a bag holding
    `recorded` ({topic: count}) cmd_vel-typed messages.
    """
    folder = tmp_path / 'publications'
    folder.mkdir(parents=True)
    for k, counts in enumerate(publications):
        (folder / f'node{k}.json').write_text(json.dumps(counts))
    with BagWriter(tmp_path / 'bag') as writer:
        for topic, count in recorded.items():
            writer.add_topic(topic, 'geometry_msgs/msg/Twist', qos())
            for k in range(count):
                writer.write(topic, k + 1, serialize_message(Twist()))
    return bag_accounting(tmp_path / 'bag', folder, streams)


def stream(topic, first, received, in_order=True):
    return {'topic': topic, 'first': first, 'last': first + received - 1,
            'received': received, 'in_order': in_order}


@pytest.mark.parametrize('received, written, lost', [
    (7, 7, 0),    # the recorder matched at the 4th of 10: nothing after it is missing
    (6, 6, 1),    # one of the seven from the 4th on never arrived
    (7, 6, 1),    # arrived but not written
])
def test_the_bag_accounting_starts_at_the_first_sample_recorded(tmp_path, received, written,
                                                                 lost):
    cmd = '/robot_1/cmd_vel'
    out = accounting(tmp_path, [{cmd: 10}], {cmd: stream(cmd, 4, received)}, {cmd: written})
    assert out['lost'] == lost and out['published'] == 10
    assert out['topics'][cmd]['expected'] == 7


def test_the_bag_accounting_counts_whole_what_it_cannot_place(tmp_path):
    cmd, diag = '/robot_1/cmd_vel', '/diagnostics'
    out = accounting(
        tmp_path,
        [{cmd: 10, f'{diag} a': 5}, {cmd: 8}],     # two nodes wrote cmd_vel
        {cmd: stream(cmd, 1, 17, in_order=False), f'{diag} a': stream(diag, 1, 5)},
        {cmd: 17, diag: 5, '/robot_2/cmd_vel': 0})
    assert out['topics'][cmd]['expected'] == 18 and out['topics'][cmd]['lost'] == 1
    assert out['topics'][diag]['lost'] == 0
    out = accounting(tmp_path / 'x', [{cmd: 4}], {}, {cmd: 0})    # never received
    assert out['lost'] == 4


def test_existing_path_is_refused(tmp_path):
    (tmp_path / 'bag').mkdir()
    with pytest.raises(BagError, match='already exists'):
        BagWriter(tmp_path / 'bag')


def test_corrupt_bag_is_a_clear_error(tmp_path):
    bad = tmp_path / 'bad'
    bad.mkdir()
    (bad / 'metadata.yaml').write_text('rosbag2_bagfile_information: [1, 2\n')
    with pytest.raises(BagError, match='not a readable ROS 2 bag'):
        list(read_messages(bad))
