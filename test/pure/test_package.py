"""The package as ament_python: package.xml and setup.py agree with the code, colcon installs
every node, the installed command runs, bootstrap.sh sources cleanly.
"""

import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

from conftest import ROOT
from installed_package import find_executable, installed_env


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
