"""Fast DDS's shared-memory files (/dev/shm/fastrtps_*) that processes killed hard leave behind.

Fast DDS's own `fastdds shm clean` removes segments and ports whose lock file nobody holds;
it goes by the lock files, so a port segment whose lock file is already gone (with the
semaphore beside it) stays for good: after a day of test runs here, 1134 port segments of
52 KB (59 MB of RAM in tmpfs) and 1130 semaphores. Those are removed here when no process
has them mapped or open (read from /proc): a live port is always mapped by its listener.
"""

import os
from pathlib import Path
import re
import subprocess


SHM_DIR = Path('/dev/shm')
PORT_FILE = re.compile(r'^(sem\.)?fastrtps_port\d+(_mutex)?$')   # segment, or its semaphore


def files_in_use(folder=SHM_DIR):
    """Names of the files in `folder` that some process has mapped or open."""
    prefix = str(folder) + os.sep
    used = set()
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        try:
            for line in (proc / 'maps').read_text().splitlines():
                path = line.split(maxsplit=5)[-1]
                if path.startswith(prefix):
                    used.add(path[len(prefix):].split(' ')[0])
            for fd in (proc / 'fd').iterdir():
                target = os.readlink(fd)
                if target.startswith(prefix):
                    used.add(target[len(prefix):])
        except OSError:   # the process ended, or is not ours to read
            continue
    return used


def orphan_ports(folder=SHM_DIR):
    """Names of the Fast DDS port segments and port semaphores in `folder` that have no lock
    file and that no process has mapped or open: what a process killed hard left.
    """
    try:
        names = set(os.listdir(folder))
    except FileNotFoundError:
        return []
    locked = {n for n in names if n.endswith(('_el', '_sl'))}
    in_use = files_in_use(folder)
    return sorted(name for name in names if PORT_FILE.match(name)
                  and not {name.removeprefix('sem.').removesuffix('_mutex') + lock
                           for lock in ('_el', '_sl')} & locked
                  and name not in in_use)


def remove_orphan_ports(folder=SHM_DIR):
    """Remove the orphan port files in `folder` (orphan_ports); returns the names removed."""
    removed = []
    for name in orphan_ports(folder):
        try:
            (Path(folder) / name).unlink()
        except OSError:
            continue
        removed.append(name)
    return removed


def clean(quiet=False):
    """Fast DDS's `fastdds shm clean` (segments and ports whose lock nobody holds), then the
    port files it leaves (remove_orphan_ports). Returns (the tool's exit status, the names
    removed here); FileNotFoundError without the tool. quiet: the tool prints nothing.
    """
    from curve_formation.paths import fastdds_tool_command
    status = subprocess.run(fastdds_tool_command('shm', 'clean'), check=False,
                            capture_output=quiet, timeout=60).returncode
    return status, remove_orphan_ports()


def remove_dead_shared_memory():
    """Remove the Fast DDS shared-memory files that no live process holds (clean):
    what node processes that died or were killed left in /dev/shm. Under
    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps gives every participant a
    shared-memory transport, whatever the profile says (docs/arena-setup.md).
    """
    try:
        clean(quiet=True)
    except (OSError, subprocess.SubprocessError):
        pass   # no fastdds tool here: `curve-formation clean-shm` says so when asked
