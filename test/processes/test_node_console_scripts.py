"""A node console script started without a required parameter says so in one line naming
the fix; a controller takes its realtime priority, or says why not and runs on.
"""

import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from curve_formation import scheduling


# Without CAP_SYS_NICE and with an rtprio limit of 0, as a lab PC's user without the
# `@realtime - rtprio 99` line: SCHED_FIFO is refused even to root.
REFUSED = ['setpriv', '--bounding-set=-sys_nice', 'prlimit', '--rtprio=0', '--']


def test_a_missing_required_parameter_is_one_line_naming_the_fix(ros_domain):
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.nodes.formation_controller'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().count('\n') == 0, proc.stderr
    assert "parameter 'index' is required" in proc.stderr
    assert '`-p index:=VALUE`' in proc.stderr and 'curve-formation params' in proc.stderr


@pytest.mark.parametrize('refused', [False, True], ids=['permitted', 'refused'])
def test_a_controller_started_alone_takes_its_realtime_priority_before_ros(ros_domain,
                                                                         tmp_path, refused):
    """`ros2 run curve_formation formation_controller ... -p realtime_priority:=12`: the
    process and every thread it has (DDS's, the executor's) run SCHED_FIFO at 12 (or, where
    this PC refuses it, the log says so) once it runs (stopped: no curve yet). Refused
    (no CAP_SYS_NICE, no rtprio limit) at its default priority: it says so and why, and runs
    at normal scheduling.
    """
    from test_grouped_controllers import assert_realtime
    if refused and not all(shutil.which(tool) for tool in ('setpriv', 'prlimit')):
        pytest.skip('needs util-linux setpriv and prlimit to refuse realtime scheduling')
    log = tmp_path / 'controller.log'
    asked = ['-p', 'realtime_priority:=12'] if not refused else []   # else the default
    with open(log, 'w') as out:
        proc = subprocess.Popen(
            [*(REFUSED if refused else []), sys.executable, '-m',
             'curve_formation.nodes.formation_controller', '--ros-args',
             '-r', '__ns:=/robot_1', '-p', 'index:=1', '-p', 'agent_count:=1',
             '-p', 'role:=leader', *asked],
            stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 30.0
        while 'no curve received yet' not in log.read_text() and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.2)
        if refused:
            assert os.sched_getscheduler(proc.pid) == os.SCHED_OTHER
            text = log.read_text()
            assert (f'realtime priority {scheduling.CONTROLLERS} not taken (Operation not '
                    'permitted' in text), text
        else:
            assert_realtime(proc.pid, 12, log)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
