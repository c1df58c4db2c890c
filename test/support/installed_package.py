"""The package as colcon installs it, and its commands found as `ros2 run` finds them."""

import os
from pathlib import Path
import subprocess
import sys


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
