"""Node processes: a console script refusing a bad parameter or executor, a node hung in its
shutdown still ending after a stop signal, a monitor on a stalled machine.
"""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import rclpy

from cases import circle_curve
from curve_formation.nodes import messages, topics


def test_console_script_exits_2_with_one_line(ros_domain):
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.nodes.formation_controller',
                           '--ros-args', '-p', 'index:=1', '-p', 'agent_count:=3',
                           '-p', 'role:=leader', '-p', 'k1:=-2.0'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("error: parameter 'k1'")
    assert 'Traceback' not in proc.stderr


def test_unknown_executor_choice_exits_2_naming_the_variable(ros_domain):
    env = dict(os.environ, CURVE_FORMATION_EXECUTOR='multi')
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.nodes.fake_robot'], env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert 'CURVE_FORMATION_EXECUTOR' in proc.stderr and 'events, single' in proc.stderr


HUNG_IN_SHUTDOWN = """
import sys, time
from rclpy.node import Node
from curve_formation.nodes import runtime
runtime.EXIT_DEADLINE = 2.0

class Hung(Node):
    def __init__(self):
        super().__init__('hung')
        print('built', flush=True)

    def on_shutdown(self):
        time.sleep(3600)   # stands for a DDS teardown that never returns

sys.exit(runtime.run_node(Hung))
"""


def test_a_node_hung_in_its_shutdown_still_ends_after_a_stop_signal(ros_domain):
    """No node process outlives its run (orphans of a killed runner once hung for hours)."""
    import signal
    proc = subprocess.Popen([sys.executable, '-c', HUNG_IN_SHUTDOWN], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == 'built'
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode != 0
    assert 'Timeout' in err and 'on_shutdown' in err   # where it hung, from faulthandler


def test_monitor_skips_the_sample_a_stalled_machine_would_take_with_old_poses(ros_domain):
    """A robot's pose comes at 30 Hz from another process, x = its stamp (s since it began).
    The whole machine stalls for 0.35 s (that process stopped, the monitor's asleep): on
    waking the monitor's timer is called before the fresh poses arrive, and a sample taken
    then would hold a 0.35 s old pose (a 3.5 mm error at 1 cm/s; seen in CI on the moving
    loop). It is skipped: every recorded row holds a pose under 0.15 s old.
    """
    from rclpy.context import Context

    from curve_formation.nodes.monitor import Monitor
    from curve_formation.nodes.runtime import make_executor
    publisher = subprocess.Popen([sys.executable, '-c', POSE_PUBLISHER], env=os.environ)
    context = Context()
    rclpy.init(context=context)
    executor = make_executor(context)
    monitor = Monitor(1, record_hz=20.0, context=context)
    executor.add_node(monitor)
    probe = rclpy.create_node('probe', context=context)
    curve_pub = topics.publisher(probe, topics.CURVE)
    try:
        def spin_for(seconds):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.02)
        deadline = time.monotonic() + 20.0
        while np.isnan(monitor.latest.pose_stamps[0]):
            assert time.monotonic() < deadline and publisher.poll() is None, 'no pose'
            executor.spin_once(timeout_sec=0.02)
        curve_pub.publish(messages.curve_to_msg(circle_curve(), 0, [0.0]))
        spin_for(1.0)
        publisher.send_signal(signal.SIGSTOP)   # the whole machine stalls
        time.sleep(0.35)
        publisher.send_signal(signal.SIGCONT)
        spin_for(1.0)
        data = monitor.recording.arrays()
    finally:
        publisher.kill()
        publisher.wait()
        executor.shutdown()
        monitor.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
    latest = monitor.latest
    start = latest.pose_stamps[0] - latest.poses[0, 0]   # the publisher's time origin
    ages = data['t'] + monitor.t0 - start - data['poses'][:, 0, 0]
    print(f'{len(ages)} rows, pose age at most {1e3 * ages.max():.0f} ms; '
          f'{monitor.late_samples} skipped')
    assert len(ages) >= 30 and ages.max() < 0.15
    assert monitor.late_samples >= 1


POSE_PUBLISHER = """
import time, rclpy
from curve_formation.nodes import messages, topics
rclpy.init()
node = rclpy.create_node('pose_source', namespace='/robot_1')
pub = topics.publisher(node, topics.POSE)
start = time.time()
while True:
    now = time.time()
    pub.publish(messages.pose_to_msg(now - start, 0.0, 0.0, now))
    time.sleep(1 / 30)
"""
