"""Where the shipped experiment files are, and the DDS settings every process of a run uses."""

import os
from pathlib import Path
import sys


PACKAGE = 'curve_formation'
# Fast DDS profile (shared memory with large segments, large UDP buffers); see the file.
DDS_PROFILE = Path(__file__).resolve().parent / 'fastdds_large_data.xml'
DDS_PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'


def use_dds_profile(env=None):
    """Point Fast DDS at DDS_PROFILE in `env` (default: this process's, which must happen
    before the process creates its first ROS context), unless a profile is already chosen.
    """
    (os.environ if env is None else env).setdefault(DDS_PROFILE_ENV, str(DDS_PROFILE))


def config_dirs():
    """Folders searched for shipped experiments, most specific first."""
    dirs = [Path(__file__).resolve().parent.parent / 'config',
            Path(sys.prefix) / 'share' / PACKAGE / 'config']
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory(PACKAGE)) / 'config')
    except Exception:  # noqa: BLE001 - not installed through ament: the other folders serve
        pass
    return dirs


def resolve_config(name_or_path):
    """A YAML path as given, or a shipped experiment by name ('closed_curve')."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        if not path.exists():
            raise FileNotFoundError(f'{path}: no such experiment file')
        return path
    for folder in config_dirs():
        candidate = folder / f'{name_or_path}.yaml'
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f'{name_or_path}: neither a file nor a shipped experiment '
                            f'(searched {", ".join(str(d) for d in config_dirs())})')
