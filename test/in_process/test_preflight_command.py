"""The pre-flight command against robots nobody answers for: it exits 2 naming every one."""

from pathlib import Path
import subprocess
import sys

import yaml

from cases import lab_dict


def test_the_preflight_command_exits_2_naming_every_robot_nobody_answers_for(ros, tmp_path):
    """No camera, no robot: every robot is named, the command says why and exits 2 (on the
    `ros` fixture's private domain: it runs beside the other node processes' tests).
    """
    data = lab_dict()
    for k, robot in enumerate(data['robots']['fleet']):
        robot['link'] = f'udp:127.0.0.1:{4900 + k}'   # nobody listens there
    path = tmp_path / 'lab.yaml'
    path.write_text(yaml.safe_dump(data))
    done = subprocess.run([str(Path(sys.executable).parent / 'curve-formation'), 'preflight',
                           str(path), '--json', str(tmp_path / 'pre.json')],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith('error: pre-flight refused: robot 1: marker 11 not seen')
    assert 'robot 9: marker 19 not seen, link not answering' in done.stderr
    assert 'pre-flight FAILED for robot(s) 1, 2, 3, 4, 5, 6, 7, 8, 9' in done.stdout
    assert not (tmp_path / 'pre.json').exists()
    assert Path(path).exists()
