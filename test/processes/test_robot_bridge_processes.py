"""robot_bridge and emulated robots in processes of their own: their ports, the experiment's
wheel radius, and the bridge's realtime writer thread.
"""

import contextlib
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from conftest import DATA_DIR
from curve_formation import links
from curve_formation.core.config.loading import load_experiment
from curve_formation.run import launches
from curve_formation.run.run_options import RunOptions
from curve_formation.scheduling import realtime_priority
from link_robot import Robot


def test_emulated_robots_listen_outside_the_ephemeral_ports(tmp_path):
    """A bridge's own socket takes an ephemeral port; a robot's port probed from that range
    could be taken before fake_arena binds it (it was, once, in a full test run).
    """
    low = int(Path('/proc/sys/net/ipv4/ip_local_port_range').read_text().split()[0])
    found = launches.robot_links(9, 'udp', tmp_path)
    ports = [int(link.rsplit(':', 1)[1]) for link in found]
    assert len(set(ports)) == 9 and max(ports) < min(low, 7400)
    assert launches.robot_links(2, 'pty', tmp_path) == [f'pty:{tmp_path.resolve()}/robot_{i}'
                                                      for i in (1, 2)]


def udp_ports_of(pid):
    """Local UDP ports of the sockets process `pid` holds (from /proc)."""
    inodes = set()
    for fd in Path(f'/proc/{pid}/fd').iterdir():
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith('socket:['):
                inodes.add(target[8:-1])
    ports = set()
    for table in ('udp', 'udp6'):
        for line in Path(f'/proc/{pid}/net/{table}').read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                ports.add(int(fields[1].rsplit(':', 1)[1], 16))
    return ports


def test_dds_participants_leave_the_emulated_robots_ports_alone(ros_domain):
    """Every Fast DDS participant binds a UDP port from 7000 up (one per process on the
    machine) besides its domain's ports: a robot's port probed free from there was taken by
    a participant starting before fake_arena bound it (twice). The robots' range is below.
    """
    code = ('import rclpy, time; rclpy.init(); n = rclpy.create_node("port_probe"); '
            'print("ready", flush=True); time.sleep(30)')
    proc = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == 'ready'
        ports = udp_ports_of(proc.pid)
    finally:
        proc.kill()
        proc.wait(10)
    assert any(7000 <= port < 7400 for port in ports), ports
    assert not set(launches.LINK_PORTS) & ports, ports


def test_bridges_and_emulated_robots_share_the_experiments_wheel_radius(tmp_path):
    """In rad/s formats the radius turns rim speeds into wheel speeds and back: the emulated
    robots must read with the radius the bridges write with (it used to be their default).
    """
    experiment_path = tmp_path / 'radius.yaml'
    text = (DATA_DIR / 'arena_bodies.yaml').read_text()
    experiment_path.write_text(text.replace('limits: {wheel_base: 0.08, max_wheel_speed: 0.08}',
                                            'limits: {wheel_base: 0.08, max_wheel_speed: 0.08, '
                                            'wheel_radius: 0.02}'))
    experiment = load_experiment(experiment_path)
    graph = launches.node_launches(experiment, experiment_path, RunOptions(bridge='pty'),
                                   links_dir=tmp_path)
    radii = {launch.key: launch.parameters['wheel_radius'] for launch in graph
             if 'wheel_radius' in launch.parameters}
    assert len(radii) == experiment.n + 1 and set(radii.values()) == {0.02}, radii


def test_a_bridge_in_its_own_process_writes_from_a_realtime_thread(ros_domain, tmp_path):
    """Started as `ros2 run` starts it, the bridge's spinning thread takes SCHED_FIFO at its
    realtime_priority, so that a busy PC does not delay its lines (over pseudo-terminals
    the latency p99 fell from 0.9-4.2 ms to 0.2-0.8 ms: benchmarks/robot_bridge.py); where
    that is not permitted it says so and runs on. Its stop lines (no cmd_vel yet) arrive.
    """
    endpoint = links.UdpEndpoint(('127.0.0.1', 0))
    robot = Robot(endpoint, answer=False)
    log = tmp_path / 'bridge.log'
    link = f'udp:127.0.0.1:{endpoint.socket.getsockname()[1]}'
    with open(log, 'w') as out:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'curve_formation.nodes.robot_bridge', '--ros-args', '-p',
             f'link:={link}', '-p', 'realtime_priority:=15'], stdout=out,
            stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 30.0
        while len(robot.lines) < 3 and time.monotonic() < deadline and proc.poll() is None:
            robot.poll()
            time.sleep(0.02)
        policy, priority = os.sched_getscheduler(proc.pid), os.sched_getparam(proc.pid)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(20)
        endpoint.close()
    assert len(robot.lines) >= 3 and all(said[0] == 'stop' for said in robot.said()), (
        robot.lines, log.read_text())
    if policy == os.SCHED_FIFO:
        assert priority.sched_priority == 15
    else:
        assert 'realtime_priority 15 not taken' in log.read_text()


def test_a_realtime_priority_that_cannot_be_taken_says_why():
    assert realtime_priority(0) is None   # normal scheduling asked for: nothing done
    assert realtime_priority(100)         # beyond SCHED_FIFO's 1-99: refused, with the reason
