"""`curve-formation clean-shm`: Fast DDS's shared-memory files left by a process killed hard
are removed; those of a live process are kept.
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest

from curve_formation.cli import main
from curve_formation.dds_shm import SHM_DIR


PARTICIPANT = """
from curve_formation.paths import use_dds_profile
use_dds_profile(large_data=True)   # shared memory, as the camera nodes use it
import rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node('shm_user')
pub = node.create_publisher(String, 'shm_probe', 10)
node.create_subscription(String, 'shm_probe', lambda m: None, 10)
print('ready', flush=True)
while True:
    pub.publish(String(data='x'))
    rclpy.spin_once(node, timeout_sec=0.05)
"""


def start_participant():
    proc = subprocess.Popen([sys.executable, '-c', PARTICIPANT], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == 'ready'
    # its ports and segments made: its shared-memory files, unchanged over 0.3 s
    deadline, seen, since = time.monotonic() + 10.0, set(), time.monotonic()
    while time.monotonic() < deadline:
        now = shm_files_of(proc.pid)
        if now != seen:
            seen, since = now, time.monotonic()
        elif seen and time.monotonic() - since >= 0.3:
            return proc
        time.sleep(0.05)
    raise AssertionError(f'the participant mapped no stable set of files: {seen}')


def shm_files_of(pid):
    """Names of the /dev/shm files process `pid` has mapped."""
    prefix = f'{SHM_DIR}{os.sep}'
    maps = Path(f'/proc/{pid}/maps').read_text().splitlines()
    return {line.split(maxsplit=5)[-1][len(prefix):] for line in maps
            if line.split(maxsplit=5)[-1].startswith(prefix)}


@pytest.mark.skipif(not SHM_DIR.is_dir(), reason='no /dev/shm')
def test_clean_shm_removes_what_a_killed_process_left_and_keeps_a_live_ones(ros_domain,
                                                                          capfd):
    live = start_participant()
    killed = None
    try:
        # The live one's own files (taken before the other starts: it maps the other's data
        # segment too, to read from it, and that one dies with its owner).
        kept = shm_files_of(live.pid)
        killed = start_participant()
        left = shm_files_of(killed.pid) - kept
        assert left and kept, (left, kept)
        killed.send_signal(signal.SIGKILL)
        killed.wait(10)
        assert all((SHM_DIR / name).exists() for name in left)   # nobody removed them
        assert main(['clean-shm']) == 0
        assert 'zombie segments cleaned' in capfd.readouterr().out
        assert not any((SHM_DIR / name).exists() for name in left), left
        assert all((SHM_DIR / name).exists() for name in kept), kept
        assert live.poll() is None
    finally:
        for proc in (live, killed):
            if proc is None:
                continue
            if proc.poll() is None:
                proc.kill()
            proc.wait(10)


def test_port_files_without_a_lock_or_a_user_are_removed_and_no_others(tmp_path):
    """What `fastdds shm clean` leaves: a port segment and its semaphore whose lock file is
    gone. Kept: a port with its lock file, a port file some process holds open, anything
    that is not a Fast DDS port.
    """
    from curve_formation.dds_shm import remove_orphan_ports
    names = ['fastrtps_port7001', 'sem.fastrtps_port7001_mutex', 'fastrtps_port7003',
             'fastrtps_port7003_el', 'fastrtps_port7005', 'fastrtps_0123456789abcdef',
             'other']
    for name in names:
        (tmp_path / name).write_bytes(b'x')
    with open(tmp_path / 'fastrtps_port7005', 'rb'):   # a user holds it open
        removed = remove_orphan_ports(tmp_path)
    assert removed == ['fastrtps_port7001', 'sem.fastrtps_port7001_mutex']
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names[2:])
