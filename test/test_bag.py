"""ROS 2 bags: round trip, clean close on Ctrl-C/SIGTERM, at most a second lost on SIGKILL."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist
import pytest
import rclpy
from rclpy.serialization import serialize_message

from conftest import DATA_DIR
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


@pytest.mark.parametrize('received, recorded, lost', [
    (7, 7, 0),    # the recorder matched at the 4th of 10: nothing after it is missing
    (6, 6, 1),    # one of the seven from the 4th on never arrived
    (7, 6, 1),    # arrived but not written
])
def test_the_bag_accounting_starts_at_the_first_sample_recorded(tmp_path, received, recorded,
                                                                 lost):
    cmd = '/robot_1/cmd_vel'
    out = accounting(tmp_path, [{cmd: 10}], {cmd: stream(cmd, 4, received)}, {cmd: recorded})
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


def test_a_late_recorder_accounts_exactly_over_dds(ros, tmp_path):
    """Messages published before the recorder was matched are not expected in the bag; the
    ones after are, to the message, and their DDS sequence numbers say which is which.
    """
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from curve_formation.nodes import topics
    from curve_formation.nodes.recorder import Recorder
    context, add, spin_until = ros
    node = add(rclpy.create_node('talker', context=context))
    cmd = '/robot_1/cmd_vel'
    publisher = node.create_publisher(Twist, cmd, QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))
    counter = PublicationCounter(node)
    for _ in range(5):
        publisher.publish(Twist())
    with BagWriter(tmp_path / 'bag') as writer:
        recorder = add(Recorder(writer, [t for t in topics.recorded(1) if t.name == cmd],
                                context=context))
        spin_until(lambda: publisher.get_subscription_count() == 1)
        for _ in range(20):
            publisher.publish(Twist())
        spin_until(lambda: recorder.received[cmd] == 20)
    folder = tmp_path / 'publications'
    folder.mkdir()
    counter.save(folder, 'talker')
    out = bag_accounting(tmp_path / 'bag', folder, recorder.streams)
    assert recorder.streams[cmd]['first'] == 6 and recorder.streams[cmd]['in_order']
    assert out['topics'][cmd] == {'published': 25, 'expected': 20, 'recorded': 20, 'lost': 0,
                                  'best_effort': False}


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


@pytest.mark.ros
def test_recorder_console_script_records_over_dds(ros, ros_env, tmp_path):
    """`ros2 run curve_formation formation_recorder` in its own process (its executor is the
    one every node process spins) records what is published here and closes its bag on SIGINT.
    """
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    context, add, spin_until = ros
    path = tmp_path / 'bag'
    proc = subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.nodes.recorder', '--ros-args',
         '-p', f'bag:={path}', '-p', 'agent_count:=1'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env)
    try:
        node = add(rclpy.create_node('talker', context=context))
        cmd = '/robot_1/cmd_vel'
        publisher = node.create_publisher(Twist, cmd, QoSProfile(
            depth=20, reliability=ReliabilityPolicy.RELIABLE))   # keeps a burst of 20
        spin_until(lambda: publisher.get_subscription_count() == 1 or proc.poll() is not None,
                   timeout=60)
        for k in range(20):
            msg = Twist()
            msg.linear.x = 0.001 * k
            publisher.publish(msg)
        assert publisher.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    got = [m.linear.x for topic, _, _, m in read_messages(path) if topic == cmd]
    assert got == pytest.approx([0.001 * k for k in range(20)]), out


def start_run(tmp_path, ros_env, sigint_ignored=False, storage='mcap'):
    """`curve-formation run` with a bag, returned once its t = 0; with `sigint_ignored` as
    from a background job of a non-interactive shell (SIGINT inherited ignored).
    """
    proc = subprocess.Popen(
        [sys.executable, '-m', 'curve_formation.cli', 'run', str(DATA_DIR / 'fast_closed.yaml'),
         '--out', str(tmp_path / 'run'), '--duration', '120', '--bag', str(tmp_path / 'bag'),
         '--bag-storage', storage],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros_env,
        preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if sigint_ignored
        else None)
    deadline = time.monotonic() + 120
    for line in proc.stdout:
        if 't = 0' in line:
            return proc
        assert time.monotonic() < deadline, 'the run did not start'
    raise AssertionError(f'the run ended early: {proc.wait()}')


def wait_for_status(proc, timeout=60.0):
    """Read the run's output until its first status line (`t ... s  phase ...`)."""
    deadline = time.monotonic() + timeout
    for line in proc.stdout:
        if line.lstrip().startswith('t ') and ' phase ' in line:
            return
        assert time.monotonic() < deadline, 'no status line from the run'
    raise AssertionError(f'the run ended early: {proc.wait()}')


@pytest.fixture
def ros_env(ros_domain):
    return dict(os.environ)


@pytest.mark.ros
@pytest.mark.parametrize('sig', [signal.SIGINT, pytest.param(
    signal.SIGTERM, marks=pytest.mark.slow)])   # 16 s each: the default run stays under 10 min
def test_interrupted_run_leaves_a_closed_valid_bag(tmp_path, ros_env, sig):
    """SIGTERM comes as to a background job of a non-interactive shell (SIGINT inherited
    ignored): the run must still stop every node promptly, each sending its zero command.
    """
    proc = start_run(tmp_path, ros_env, sigint_ignored=sig == signal.SIGTERM)
    wait_for_status(proc)   # the run records: its first 5 s status line
    proc.send_signal(sig)
    signalled = time.time()
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    # Every node (curve server, 6 controllers, 6 fake robots) took the runner's SIGINT and
    # ended through its own shutdown, which writes its publication counts, within its group's
    # 10 s timeout (after which it would have been killed, writing nothing).
    counts = list((tmp_path / 'run' / 'publications').glob('*.json'))
    assert len(counts) == 13, counts
    assert max(path.stat().st_mtime for path in counts) - signalled < 10.0
    logs = (tmp_path / 'run' / 'logs' / 'robot_1.formation_controller.log').read_text()
    assert 'Traceback' not in logs
    summary = bag_summary(tmp_path / 'bag')
    for i in range(1, 7):
        msgtype, count = summary[f'/robot_{i}/cmd_vel']
        assert msgtype == 'geometry_msgs/msg/Twist' and count >= 40   # >= 4 s at 10 Hz
        assert summary[f'/robot_{i}/pose'][1] >= 100                  # >= 4 s at 30 Hz
    last = {}
    for topic, _, _, msg in read_messages(tmp_path / 'bag', [f'/robot_{i}/cmd_vel'
                                                            for i in range(1, 7)]):
        last[topic] = (msg.linear.x, msg.angular.z)
    # A complete, indexed MCAP file, as Jazzy's reader needs it.
    assert _complete_mcap_messages(tmp_path / 'bag' / 'bag.mcap', summary=True)[0] == sum(
        count for _, count in summary.values())
    # Each controller's final command, sent as it was stopped, is zero and was recorded.
    assert all(v == (0.0, 0.0) for v in last.values()), last
    # Every message the nodes published on a reliable topic (while subscribed) is in the bag;
    # of the best-effort poses DDS may drop a few under load.
    accounting = json.loads((tmp_path / 'run' / 'metrics.json').read_text())['bag']
    assert accounting['published'] > 1000 and accounting['lost'] == 0, accounting
    assert accounting['lost_best_effort'] < 0.005 * accounting['published'], accounting


@pytest.mark.ros
@pytest.mark.parametrize('storage', ['mcap', pytest.param('sqlite3', marks=pytest.mark.slow)])
def test_hard_killed_run_loses_at_most_the_last_second(tmp_path, ros_env, storage):
    """Killed hard, the bag holds all but the last second, and `bag repair` makes a complete
    bag of it that our reader (and, for MCAP, the independent mcap reader) reads whole.
    """
    proc = start_run(tmp_path, ros_env, storage=storage)
    bag = tmp_path / 'bag'
    deadline = time.monotonic() + 60
    while _stored_messages(bag, storage)[0] <= 1000:   # a few seconds of the run on disk
        assert time.monotonic() < deadline and proc.poll() is None, 'the bag did not fill'
        time.sleep(0.2)
    killed_at = time.time()
    proc.kill()
    proc.wait(10)
    assert not (bag / 'metadata.yaml').exists()   # never closed
    count, newest = _stored_messages(bag, storage)
    assert count > 1000
    assert killed_at - newest * 1e-9 < 1.5   # commit period 1 s, plus scheduling slack
    with pytest.raises(BagError, match='bag repair'):
        list(read_messages(bag))
    repaired = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'bag', 'repair',
                               str(bag)], capture_output=True, text=True)
    assert repaired.returncode == 0, repaired.stderr
    assert f'{count} messages' in repaired.stdout
    stamps = [stamp for _, _, stamp, _ in read_messages(tmp_path / 'bag-repaired')]
    assert len(stamps) == count and max(stamps) == newest
    if storage == 'mcap':
        assert _complete_mcap_messages(tmp_path / 'bag-repaired' / 'bag-repaired.mcap',
                                       summary=True) == (count, newest)
    # The node processes do not outlive a killed runner.
    deadline = time.monotonic() + 20
    while subprocess.run(['pgrep', '-f', str(tmp_path / 'run' / 'params')],
                         capture_output=True).returncode == 0:
        assert time.monotonic() < deadline, 'node processes outlived the killed runner'
        time.sleep(0.2)


def _stored_messages(bag, storage):
    """(count, newest timestamp in ns) of the messages a bag being written holds on disk."""
    if storage == 'mcap':
        path = bag / 'bag.mcap'
        return _complete_mcap_messages(path) if path.exists() else (0, 0)
    try:
        with sqlite3.connect(f'file:{bag / "bag.db3"}?mode=ro', uri=True) as conn:
            count, newest = conn.execute(
                'SELECT COUNT(*), MAX(timestamp) FROM messages').fetchone()
    except sqlite3.OperationalError:   # not created yet, or locked by the writer
        return 0, 0
    return count, newest or 0


def _complete_mcap_messages(path, summary=False):
    """(count, newest log time in ns) of an MCAP file's messages, read with the independent
    `mcap` library: record by record up to a killed writer's unfinished tail, or (summary)
    through the file's summary and indexes, as Jazzy's reader does.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader
    count, newest = 0, 0
    with open(path, 'rb') as stream:
        if summary:
            for _, _, message in make_reader(stream).iter_messages():
                count, newest = count + 1, max(newest, message.log_time)
            return count, newest
        try:
            for record in StreamReader(stream).records:
                if type(record).__name__ == 'Message':
                    count, newest = count + 1, max(newest, record.log_time)
        except (McapError, EOFError, ValueError):
            pass   # the chunk being written when the process was killed
    return count, newest
