"""ROS 2 bags: round trip, clean close on Ctrl-C/SIGTERM, at most a second lost on SIGKILL."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

from geometry_msgs.msg import Twist
import pytest
from rclpy.serialization import serialize_message

from conftest import DATA_DIR
from curve_formation.bag import bag_summary, BagError, BagWriter, qos, read_messages
from curve_formation.nodes.runtime import PublicationCounter, RECORDER_NODE


def test_write_then_read_round_trip(tmp_path):
    path = tmp_path / 'bag'
    with BagWriter(path) as writer:
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


class _GraphStub:
    """A node and one publisher whose graph and matched readers a test sets by hand."""

    def __init__(self):
        self.graph = []     # node names of the subscriptions the graph lists
        self.matched = 0    # subscriptions the publisher's writer has matched
        self.sent = 0
        stub = self

        class Publisher:
            topic_name = '/robot_1/cmd_vel'

            def publish(self, msg):
                stub.sent += 1

            def get_subscription_count(self):
                return stub.matched

        self.publishers = [Publisher()]

    def get_subscriptions_info_by_topic(self, topic):
        return [type('Info', (), {'node_name': name}) for name in self.graph]


def test_publications_count_once_the_recorders_reader_is_matched():
    node = _GraphStub()
    counter = PublicationCounter(node)
    publish = node.publishers[0].publish
    node.graph, node.matched = ['monitor'], 1
    publish(None)                                   # the recorder is not subscribed yet
    node.graph = ['monitor', RECORDER_NODE]
    publish(None)                                   # in the graph, not matched: not delivered
    node.matched = 2
    publish(None)
    publish(None)
    assert node.sent == 4 and counter.counts == {'/robot_1/cmd_vel': 2}


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


def start_run(tmp_path, ros_env):
    proc = subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.cli', 'run', str(DATA_DIR / 'fast_closed.yaml'),
         '--out', str(tmp_path / 'run'), '--duration', '120', '--bag', str(tmp_path / 'bag')],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env)
    deadline = time.monotonic() + 120
    for line in proc.stdout:
        if 't = 0' in line:
            return proc
        assert time.monotonic() < deadline, 'the run did not start'
    raise AssertionError(f'the run ended early: {proc.wait()}')


@pytest.fixture
def ros_env(ros_domain):
    return dict(os.environ)


@pytest.mark.ros
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_interrupted_run_leaves_a_closed_valid_bag(tmp_path, ros_env, sig):
    proc = start_run(tmp_path, ros_env)
    time.sleep(4.0)
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    summary = bag_summary(tmp_path / 'bag')
    for i in range(1, 7):
        msgtype, count = summary[f'/robot_{i}/cmd_vel']
        assert msgtype == 'geometry_msgs/msg/Twist' and count >= 40   # >= 4 s at 10 Hz
        assert summary[f'/robot_{i}/pose'][1] >= 100                  # >= 4 s at 30 Hz
    last = {}
    for topic, _, _, msg in read_messages(tmp_path / 'bag', [f'/robot_{i}/cmd_vel'
                                                            for i in range(1, 7)]):
        last[topic] = (msg.linear.x, msg.angular.z)
    # Each controller's final command, sent as it was stopped, is zero and was recorded.
    assert all(v == (0.0, 0.0) for v in last.values()), last
    # Every message the nodes published on a reliable topic (while subscribed) is in the bag;
    # of the best-effort poses DDS may drop a few under load.
    accounting = json.loads((tmp_path / 'run' / 'metrics.json').read_text())['bag']
    assert accounting['published'] > 1000 and accounting['lost'] == 0, accounting
    assert accounting['lost_best_effort'] < 0.005 * accounting['published'], accounting


@pytest.mark.ros
def test_hard_killed_run_loses_at_most_the_last_second(tmp_path, ros_env):
    proc = start_run(tmp_path, ros_env)
    time.sleep(4.0)
    killed_at = time.time()
    proc.kill()
    proc.wait(10)
    db = tmp_path / 'bag' / 'bag.db3'
    assert not (tmp_path / 'bag' / 'metadata.yaml').exists()   # never closed
    with sqlite3.connect(db) as conn:
        count, newest = conn.execute('SELECT COUNT(*), MAX(timestamp) FROM messages').fetchone()
    assert count > 1000
    assert killed_at - newest * 1e-9 < 1.5   # commit period 1 s, plus scheduling slack
    # The node processes do not outlive a killed runner.
    deadline = time.monotonic() + 20
    while subprocess.run(['pgrep', '-f', str(tmp_path / 'run' / 'params')],
                         capture_output=True).returncode == 0:
        assert time.monotonic() < deadline, 'node processes outlived the killed runner'
        time.sleep(0.2)


@pytest.mark.ros
def test_run_started_with_sigint_ignored_still_stops_promptly(tmp_path, ros_env):
    """As from a background job of a non-interactive shell: SIGINT is inherited ignored."""
    proc = subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.cli', 'run', str(DATA_DIR / 'fast_closed.yaml'),
         '--out', str(tmp_path / 'run'), '--duration', '3'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    start = time.monotonic()
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, out
    # Start-up takes ~10 s; the stop must not wait out a timeout per node (19 x 10 s before).
    assert time.monotonic() - start < 60
    logs = (tmp_path / 'run' / 'logs' / 'robot_1.formation_controller.log').read_text()
    assert 'Traceback' not in logs
    assert (tmp_path / 'run' / 'metrics.json').exists()
