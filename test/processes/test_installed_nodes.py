"""The colcon-installed nodes as `ros2 run` finds them: a node publishes over DDS, and the
graph its ros2 run lines start settles as `run` does (-m slow).
"""

import json
import os
from pathlib import Path
import subprocess
import sys

import pytest

from installed_package import find_executable, installed_env


def test_installed_node_publishes_over_dds(colcon_install, ros_domain):
    """`ros2 run curve_formation fake_robot` equivalent: the colcon-installed executable."""
    import signal
    import time

    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from curve_formation.nodes import messages, qos

    exe = find_executable(colcon_install, 'fake_robot')
    proc = subprocess.Popen([str(exe), '--ros-args', '-r', '__ns:=/robot_7',
                             '-p', 'initial_pose:=[1.0, 2.0, 0.5]'],
                            env=installed_env(colcon_install), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    poses = []
    node.create_subscription(PoseStamped, '/robot_7/pose',
                             lambda m: poses.append(messages.pose_from_msg(m)), qos.SENSOR)
    try:
        deadline = time.monotonic() + 60
        while not poses and time.monotonic() < deadline and proc.poll() is None:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.send_signal(signal.SIGINT)
        out = proc.communicate(timeout=20)[0]
    assert poses, out
    assert poses[0][:3] == pytest.approx((1.0, 2.0, 0.5))
    assert proc.returncode == 0, out


ROS2_RUN = """#!/usr/bin/env bash
# Stands in for `ros2 run PKG EXE ARGS...` (ros2cli is not installed here) as ros2run finds
# an executable: the package's prefix from the ament index, then PREFIX/lib/PKG/EXE.
set -e
[ "${1:-}" = run ] || { echo "this stand-in knows only 'ros2 run'" >&2; exit 2; }
prefix=$(python3 -c "from ament_index_python.packages import get_package_prefix as p
print(p('$2'))")
exec "$prefix/lib/$2/$3" "${@:4}"
"""


@pytest.mark.slow
def test_the_graph_started_by_its_ros2_run_lines_settles_as_run_does(colcon_install, tmp_path,
                                                                      ros_domain):
    """The arena demo's whole graph from `curve-formation params --observer`'s start_all.sh,
    each node started by its `ros2 run` line from the colcon install (no runner), settles
    within two control periods of `curve-formation run` (about 3 minutes for both).
    """
    bin_dir = tmp_path / 'bin'
    bin_dir.mkdir()
    (bin_dir / 'ros2').write_text(ROS2_RUN)
    (bin_dir / 'ros2').chmod(0o755)
    env = installed_env(colcon_install)
    env['PATH'] = f'{bin_dir}{os.pathsep}{Path(sys.executable).parent}{os.pathsep}{env["PATH"]}'
    command = str(find_executable(colcon_install, 'curve-formation'))
    # a `ros2 run` line per node (a process each, on any PC), and `run` alike
    proc = subprocess.run([command, 'params', 'arena_demo', '--out', str(tmp_path / 'byhand'),
                           '--observer', '--controllers-per-process', '1'], env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    started = subprocess.run(['bash', str(tmp_path / 'byhand' / 'start_all.sh')], env=env,
                             capture_output=True, text=True, timeout=400)
    assert started.returncode == 0, started.stdout[-3000:] + started.stderr[-3000:]
    assert 'ros2 run curve_formation formation_controller' in (
        tmp_path / 'byhand' / 'start_all.sh').read_text()
    by_hand = json.loads((tmp_path / 'byhand' / 'run' / 'metrics.json').read_text())
    proc = subprocess.run([command, 'run', 'arena_demo', '--out', str(tmp_path / 'run'),
                           '--controllers-per-process', '1'],
                          env=env, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    reference = json.loads((tmp_path / 'run' / 'metrics.json').read_text())
    settled = [p['settle_time'] for p in by_hand['phases']]
    expected = [p['settle_time'] for p in reference['phases']]
    print(f'settled by hand {settled} s, by run {expected} s')
    assert None not in settled and None not in expected
    period = 1.0 / 10.0
    assert all(abs(a - b) <= 2 * period for a, b in zip(settled, expected, strict=True))
