"""The package builds with colcon as ament_python and runs as `ros2 run` would find it."""

import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest


ROOT = Path(__file__).resolve().parent.parent
NODES = ('curve_server', 'formation_controller', 'fake_robot', 'formation_recorder')


def test_package_xml_is_format_3_with_the_message_dependencies():
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'curve_formation'
    assert root.find('export/build_type').text == 'ament_python'
    deps = {e.text for e in root.findall('exec_depend')}
    assert {'rclpy', 'geometry_msgs', 'std_msgs', 'nav_msgs', 'sensor_msgs',
            'visualization_msgs', 'diagnostic_msgs'} <= deps


# Every third-party module the package imports at run time: (pip name, rosdep key or None
# where rosdep has none). ROS packages are exec_depends by their own name.
RUNTIME = {'numpy': ('numpy', 'python3-numpy'), 'scipy': ('scipy', 'python3-scipy'),
           'numba': ('numba', 'python3-numba'),
           'matplotlib': ('matplotlib', 'python3-matplotlib'),
           'yaml': ('PyYAML', 'python3-yaml'), 'pydantic': ('pydantic', 'python3-pydantic'),
           'cv2': ('opencv-python-headless', 'python3-opencv'),
           'rosbags': ('rosbags', 'python3-rosbags-pip'), 'mcap': ('mcap', None),
           'serial': ('pyserial', 'python3-serial'), 'mujoco': ('mujoco', None),
           'imageio_ffmpeg': ('imageio-ffmpeg', None), 'PIL': ('pillow', 'python3-pil')}
ROS = {'rclpy', 'geometry_msgs', 'std_msgs', 'nav_msgs', 'sensor_msgs', 'visualization_msgs',
       'diagnostic_msgs', 'builtin_interfaces', 'ament_index_python', 'rcl_interfaces',
       'rosgraph_msgs'}


def imported_modules():
    """Top-level names of every module imported anywhere in curve_formation/."""
    import ast
    names = set()
    for path in (ROOT / 'curve_formation').rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names.add(node.module.split('.')[0])
    return names - set(sys.stdlib_module_names) - {'curve_formation'}


def install_requires():
    """The distribution names setup.py's install_requires lists (read, not run)."""
    import ast
    import re
    for node in ast.walk(ast.parse((ROOT / 'setup.py').read_text())):
        if isinstance(node, ast.keyword) and node.arg == 'install_requires':
            return {re.split(r'[<>=!~ ]', ast.literal_eval(item))[0] for item in node.value.elts}
    raise AssertionError('setup.py has no install_requires')


def test_package_xml_states_the_versions_the_code_needs_and_every_test_dependency():
    root = ET.parse(ROOT / 'package.xml').getroot()
    versions = {e.text: e.get('version_gte') for e in root.findall('exec_depend')}
    assert versions['python3-pydantic'] == '2.0' and versions['python3-opencv'] == '4.7'
    assert all(versions[key] for _, key in RUNTIME.values() if key is not None)
    tests = {e.text for e in root.findall('test_depend')}
    assert tests == {'python3-pytest', 'python3-pytest-timeout', 'python3-hypothesis'}
    config = (ROOT / 'pyproject.toml').read_text()
    assert '--timeout=' in config   # what pytest-timeout is there for


def test_every_runtime_dependency_is_declared_for_pip_and_rosdep():
    imported = imported_modules()
    assert imported <= set(RUNTIME) | ROS, imported - set(RUNTIME) - ROS
    deps = {e.text for e in ET.parse(ROOT / 'package.xml').getroot().findall('exec_depend')}
    for module in imported:
        pip, rosdep = RUNTIME.get(module, (None, module))
        if rosdep is not None:
            assert rosdep in deps, f'package.xml lacks {rosdep} (imports {module})'
        if pip is not None:
            assert pip in install_requires(), f'setup.py lacks {pip} (imports {module})'


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory):
    """colcon build of a copy of the tracked sources; returns the install prefix."""
    if shutil.which('colcon') is None:
        pytest.fail('colcon is not installed: run the tests through scripts/test')
    ws = tmp_path_factory.mktemp('ws')
    files = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard'],
                           cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        if (ROOT / name).is_file():
            (ws / 'src' / 'curve_formation' / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, ws / 'src' / 'curve_formation' / name)
    proc = subprocess.run(['colcon', 'build', '--base-paths', 'src'], cwd=ws,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return ws / 'install' / 'curve_formation'


def installed_env(prefix):
    env = dict(os.environ)
    site = next(prefix.glob('lib/python3*/site-packages'))
    env['PYTHONPATH'] = f'{site}{os.pathsep}{env.get("PYTHONPATH", "")}'
    env['AMENT_PREFIX_PATH'] = f'{prefix}{os.pathsep}{env.get("AMENT_PREFIX_PATH", "")}'
    return env


def find_executable(prefix, name):
    """What `ros2 run curve_formation NAME` does: ament index -> prefix/lib/<pkg>/NAME."""
    code = ('from ament_index_python.packages import get_package_prefix; '
            'print(get_package_prefix("curve_formation"))')
    found = subprocess.run([sys.executable, '-c', code], env=installed_env(prefix),
                           capture_output=True, text=True, check=True).stdout.strip()
    assert Path(found) == prefix
    return Path(found) / 'lib' / 'curve_formation' / name


def test_colcon_installs_every_node_and_the_index_entry(colcon_install):
    assert (colcon_install / 'share/ament_index/resource_index/packages/curve_formation').exists()
    assert (colcon_install / 'share/curve_formation/package.xml').exists()
    assert sorted(p.name for p in (colcon_install / 'share/curve_formation/config').glob(
        '*.yaml')) == sorted(p.name for p in (ROOT / 'config').glob('*.yaml'))
    for node in NODES + ('curve-formation',):
        assert os.access(find_executable(colcon_install, node), os.X_OK), node


def test_installed_command_checks_a_shipped_experiment(colcon_install, tmp_path):
    """The installed command finds a shipped experiment (share/curve_formation/config) and
    builds it: fit, graph, Theorem 1 (a `sim` would add only the compiled simulator's first
    compilation in the new install, ~20 s; `sim` of the sources is tested in test_cli.py).
    """
    exe = find_executable(colcon_install, 'curve-formation')
    proc = subprocess.run([str(exe), 'check', 'open_curve', '--json'],
                          env=installed_env(colcon_install), capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report['experiment'] == 'open_curve', report
    assert str(colcon_install) in report['source'], report   # the installed copy


@pytest.mark.ros
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
@pytest.mark.ros
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
    proc = subprocess.run([command, 'params', 'arena_demo', '--out', str(tmp_path / 'byhand'),
                           '--observer'], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    started = subprocess.run(['bash', str(tmp_path / 'byhand' / 'start_all.sh')], env=env,
                             capture_output=True, text=True, timeout=400)
    assert started.returncode == 0, started.stdout[-3000:] + started.stderr[-3000:]
    assert 'ros2 run curve_formation formation_controller' in (
        tmp_path / 'byhand' / 'start_all.sh').read_text()
    by_hand = json.loads((tmp_path / 'byhand' / 'run' / 'metrics.json').read_text())
    proc = subprocess.run([command, 'run', 'arena_demo', '--out', str(tmp_path / 'run')],
                          env=env, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    reference = json.loads((tmp_path / 'run' / 'metrics.json').read_text())
    settled = [p['settle_time'] for p in by_hand['phases']]
    expected = [p['settle_time'] for p in reference['phases']]
    print(f'settled by hand {settled} s, by run {expected} s')
    assert None not in settled and None not in expected
    period = 1.0 / 10.0
    assert all(abs(a - b) <= 2 * period for a, b in zip(settled, expected, strict=True))


def test_version_and_license_are_the_packages():
    root = ET.parse(ROOT / 'package.xml').getroot()
    done = subprocess.run([sys.executable, '-m', 'curve_formation.cli', '--version'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.split() == ['curve-formation',
                                                            root.findtext('version')]
    assert f"version='{root.findtext('version')}'" in (ROOT / 'setup.py').read_text()
    assert root.findtext('license') == 'Apache-2.0'
    assert 'Apache License' in (ROOT / 'LICENSE').read_text().splitlines()[0]


def test_sourcing_bootstrap_leaves_the_callers_shell_options_as_they_were(tmp_path):
    """`source scripts/bootstrap.sh` in an interactive shell must not leave `set -e` behind
    (the first failing command would close the terminal), nor end the shell on failure.
    """
    script = (f'set +e +u; before=$(set +o); source {ROOT}/scripts/bootstrap.sh; '
              'after=$(set +o); [ "$before" = "$after" ] && echo same; '
              'command -v curve-formation; false; echo "still here"')
    done = subprocess.run(['bash', '-c', script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.split('\n')
    assert 'same' in lines and any(line.endswith('.venv/bin/curve-formation') for line in lines)
    assert 'still here' in done.stdout
    # A checkout it cannot set up (no requirements.txt): status 1, the caller's shell goes on.
    (tmp_path / 'scripts').mkdir()
    shutil.copy(ROOT / 'scripts' / 'bootstrap.sh', tmp_path / 'scripts')
    failing = subprocess.run(['bash', '-c', f'source {tmp_path}/scripts/bootstrap.sh; '
                              'echo "status $?"'], capture_output=True, text=True, timeout=60)
    assert failing.returncode == 0 and 'status 1' in failing.stdout, failing
    assert 'could not set up' in failing.stderr
