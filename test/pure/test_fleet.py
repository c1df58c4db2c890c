"""A lab's robots from one file: robots.fleet (each robot's marker, link, wire format and own
wheels), the bridges and controllers it gives, the pre-flight's judgement of each robot and
its start scripts, and the team without the robots it leaves out.
"""

import time
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cases import lab_dict
from conftest import CONFIG_DIR, quiet
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.loading import build_experiment
from curve_formation.core.config.team import without_robots
from curve_formation.fleet import fleet_robots
from curve_formation.run.launches import node_launches
from curve_formation.run.preflight import judge, PreflightResult, STILL
from curve_formation.run.run_options import RunOptions
from curve_formation.run.start_scripts import graph_launches, start_scripts
from curve_formation.run.team_file import write_team_file


def test_the_fleet_gives_each_bridge_its_link_and_each_controller_its_robot():
    experiment = build_experiment(lab_dict(), 'lab.yaml')
    assert experiment.spec.camera.robot_ids == list(range(11, 20))   # from the fleet
    launches = {launch.key: launch.parameters for launch in node_launches(
        experiment, 'lab.yaml', RunOptions(with_robots=False))}
    bridge = launches['robot_3.robot_bridge']
    assert (bridge['link'], bridge['baud'], bridge['wire_format'], bridge['wheel_base']) == (
        'serial:/dev/ttyUSB2', 57600, 'wheel-m-s', 0.079)
    assert launches['robot_7.robot_bridge']['link'] == 'udp:10.0.0.6:4210'
    assert launches['robot_7.robot_bridge']['wire_format'] == 'mona-serial'
    three, four = launches['robot_3.formation_controller'], launches[
        'robot_4.formation_controller']
    assert (three['wheel_base'], three['motor_time_constant']) == (0.079, 0.04)
    assert (four['wheel_base'], four['motor_time_constant']) == (0.08, 0.0)   # the file's
    # with simulated robots the fleet's links are not driven
    assert not any(key.endswith('robot_bridge') for key in {launch.key for launch in
                   node_launches(experiment, 'lab.yaml', RunOptions())})


@pytest.mark.parametrize('change, key, expected', [
    (lambda f: f.pop(), 'robots.fleet', 'expected 9 robots'),
    (lambda f: f[4].update(link='serial:/dev/ttyUSB0'), 'robots.fleet[4].link',
     "already robot 1's link"),
    (lambda f: f[8].update(marker=11), 'robots.fleet[8].marker', "already robot 1's"),
    (lambda f: f[1].update(link='usb0'), 'robots.fleet[1].link', 'expected udp:HOST:PORT'),
    (lambda f: f[1].update(link='udp:10.0.0.1:99999'), 'robots.fleet[1].link',
     'expected udp:HOST:PORT'),
    (lambda f: f[1].update(link='serial:/dev/ttyUSB1@fast'), 'robots.fleet[1].link',
     'BAUD in bits/s'),
    (lambda f: f[1].update(link='pty:/tmp/robot'), 'robots.fleet[1].link', 'emulated'),
    (lambda f: f[1].pop('marker'), 'robots.fleet', 'robots [2] have no marker'),
    (lambda f: f[0].update(speed=1), 'robots.fleet[0].speed', 'Extra inputs'),
], ids=['count', 'link twice', 'marker twice', 'link form', 'port', 'baud', 'pty',
        'one marker missing', 'unknown key'])
def test_a_fleet_that_cannot_be_driven_is_refused_naming_its_key(change, key, expected):
    data = lab_dict()
    change(data['robots']['fleet'])
    with pytest.raises(ConfigError) as caught:
        build_experiment(data, 'lab.yaml')
    assert f'lab.yaml: {key}: ' in str(caught.value) and expected in str(caught.value)


def test_a_wire_format_no_bridge_knows_and_markers_the_camera_disagrees_with_are_refused():
    data = lab_dict()
    data['robots']['fleet'][5]['format'] = 'mona-seriall'
    experiment = build_experiment(data, 'lab.yaml')   # the loader does not know the formats
    with pytest.raises(ConfigError, match=r"lab.yaml: robots.fleet\[5\].format: unknown wire "
                       r"format 'mona-seriall'; one of mona-serial"):
        fleet_robots(experiment)
    data = lab_dict()
    data['camera']['robot_ids'] = list(range(1, 10))
    with pytest.raises(ConfigError, match=r'robots.fleet: markers \[11, .* differ from '
                       r'camera.robot_ids \[1, '):
        build_experiment(data, 'lab.yaml')


def test_check_lists_the_fleet(tmp_path, capsys):
    from curve_formation.cli import main
    path = tmp_path / 'lab.yaml'
    path.write_text(yaml.safe_dump(lab_dict()))
    assert main(['check', str(path)]) == 0
    out = capsys.readouterr().out
    assert 'robot 3: serial:/dev/ttyUSB2 at 57600 baud, wheel-m-s, marker 13' in out
    assert 'robot 9: udp:10.0.0.8:4210, mona-serial, marker 19' in out
    assert "leader's news: robot 4 is 3 hops from the leader, relayed with each pose: it " \
        'stops after 1 s + 0.13 s without news' in out


def test_the_team_without_robots_keeps_their_order_and_every_per_agent_key():
    data = lab_dict()
    data['agents']['initial'] = {'poses': [[0.1 * k, 0.2, 0.0] for k in range(1, 10)]}
    team = without_robots(data, {4, 7}, 'lab.yaml')
    assert team['agents']['count'] == 7
    assert [pose[0] for pose in team['agents']['initial']['poses']] == pytest.approx(
        [0.1, 0.2, 0.3, 0.5, 0.6, 0.8, 0.9])
    assert [robot['marker'] for robot in team['robots']['fleet']] == [11, 12, 13, 15, 16,
                                                                       18, 19]
    # the file's 1-2, 2-3, 5-6, 8-9, 1-5, 3-6, 5-8 (robots 5, 6, 8, 9 now 4, 5, 6, 7); its
    # 3-4, 4-5, 6-7, 7-8, 9-4 and 7-2 touch a robot left out
    edges = {(e['from'], e['to']) for e in team['graph']['edges']}
    assert edges == {(1, 2), (2, 3), (4, 5), (6, 7), (1, 4), (3, 5), (4, 6)}
    experiment = build_experiment(team, 'team.yaml')   # still rooted: the leader's edges
    assert experiment.n == 7
    with pytest.raises(ConfigError, match='robot 1 is the leader'):
        without_robots(data, {1}, 'lab.yaml')


def test_a_team_whose_graph_would_lose_its_root_is_refused_saying_which_robots(tmp_path):
    data = yaml.safe_load((CONFIG_DIR / 'arena_demo.yaml').read_text())
    data['graph']['edges'] = [{'from': k, 'to': k + 1} for k in range(1, 9)]   # a chain
    path = tmp_path / 'chain.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as caught:
        write_team_file(path, {5}, tmp_path / 'team.yaml')
    message = str(caught.value)
    assert 'chain.yaml: graph: without robots [5] the graph left is not rooted at the leader, ' \
        'so the formation cannot run: agents [1, 5] receive from nobody' in message
    assert "(the team's agents 1..8 are the file's robots 1, 2, 3, 4, 6, 7, 8, 9)" in message


def probe(replies=10, age=0.05, first=0.1, error=''):
    now = 3.0
    return SimpleNamespace(replies=replies, last_reply=None if replies == 0 else now - age,
                           first_reply=None if replies == 0 else first, error=error)


def poses_still(x, y, moving=0.0):
    """Poses at 30 Hz over 3 s, moving `moving` m/s along x."""
    return [(t, x + moving * t, y, 0.0) for t in np.arange(0.0, 3.0, 1 / 30)]


def test_judge_names_each_way_a_robot_fails():
    experiment = build_experiment(lab_dict(), 'lab.yaml')
    fleet = fleet_robots(experiment)[:6]
    poses = {1: poses_still(0.3, 0.3), 2: poses_still(0.6, 0.3, moving=0.01),
             4: poses_still(2.5, 0.3), 5: poses_still(0.9, 0.5), 6: poses_still(0.93, 0.5)}
    probes = [probe(), probe(), probe(), probe(replies=0, error='udp 10.0.0.4: refused'),
              probe(), probe()]
    checks = {c.agent: c for c in judge(experiment, fleet, poses, probes, 0.0, 3.0)}
    assert checks[1].passed and checks[1].stop_confirmed and checks[1].moved <= STILL
    assert checks[2].problems == ['moved 26 mm while stopped'] and not checks[2].stop_confirmed
    assert checks[3].problems == ['marker 13 not seen']
    assert checks[4].problems == ['outside the arena at (2.500, 0.300) m',
                                  'link udp 10.0.0.4: refused']
    assert checks[5].problems == ['on top of robot 6 (30 mm apart)']
    assert checks[6].problems == ['on top of robot 5 (30 mm apart)']
    result = PreflightResult(list(checks.values()))
    assert result.failing == [2, 3, 4, 5, 6] and not result.passed
    table = result.table()
    assert 'robot_4  14      yes   down  -          no' in table
    assert table.splitlines()[-1].startswith('pre-flight FAILED for robot(s) 2, 3, 4, 5, 6')


def test_a_firmware_that_does_not_answer_is_judged_by_its_stillness_alone():
    data = lab_dict()
    data['robots']['fleet'][0]['replies'] = False
    experiment = build_experiment(data, 'lab.yaml')
    fleet = fleet_robots(experiment)[:1]
    check, = judge(experiment, fleet, {1: poses_still(0.3, 0.3)}, [probe(replies=0)], 0.0,
                   3.0)
    assert check.passed and check.link_up is None and check.stop_confirmed


def test_start_scripts_run_the_preflight_before_any_bridge(tmp_path):
    path = tmp_path / 'lab.yaml'
    path.write_text(yaml.safe_dump(lab_dict()))
    _, launches = graph_launches(path, tmp_path, with_robots=False, camera=True)
    scripts = start_scripts(launches, 'lab')
    for name in ('start_robots.sh', 'start_all.sh'):
        lines = scripts[name].splitlines()
        gate = next(k for k, line in enumerate(lines) if 'curve-formation preflight' in line)
        assert str(path) in lines[gate] and 'stop 2' in lines[gate]
        bridges = [k for k, line in enumerate(lines) if 'robot_bridge' in line]
        assert len(bridges) == 9 and min(bridges) > gate, name
    lines = scripts['start_all.sh'].splitlines()
    gate = next(k for k, line in enumerate(lines) if 'curve-formation preflight' in line)
    assert all(k < gate for k, line in enumerate(lines) if 'camera_tracker' in line)
    assert all(k > gate for k, line in enumerate(lines)
               if 'formation_controller' in line or 'curve_server' in line)


# -- against fake_arena's emulated robots, through real links and DDS ------------------------


def test_run_preflight_over_real_links_refuses_a_camera_without_its_calibration():
    """Nine emulated firmwares on UDP answer every stop line; the poses come from a stand-in
    for the camera tracker, which says on /diagnostics that it has no arena calibration: every
    robot passes and the pre-flight refuses for the camera, saying why.
    """
    from curve_formation import links, wire
    from curve_formation.run.preflight import run_preflight
    endpoints = [links.UdpEndpoint(('127.0.0.1', 0)) for _ in range(9)]
    data = lab_dict()
    for robot, endpoint in zip(data['robots']['fleet'], endpoints, strict=True):
        robot['link'] = f'udp:127.0.0.1:{endpoint.socket.getsockname()[1]}'
    experiment = build_experiment(data, 'lab.yaml')
    fleet = fleet_robots(experiment)
    start = experiment.initial_poses

    class Watch:   # PoseWatch's interface, fed by hand
        poses = {i: [] for i in range(1, 10)}
        calibration = 'none'

        def now(self):
            return time.monotonic()

        def another_formation(self):
            return False

    watch = Watch()
    heard = []

    def spin(seconds):
        time.sleep(seconds)
        for i, endpoint in enumerate(endpoints, 1):
            for line in endpoint.lines():
                said = wire.decode(wire.PRESETS[fleet[i - 1].format], line, 0.015)
                heard.append(said[0] if said else (i, line))
                endpoint.send(b'ok\n')
            watch.poses[i].append((watch.now(), *start[i - 1]))
    try:
        result = run_preflight(experiment, fleet, watch, spin, quiet)
    finally:
        for endpoint in endpoints:
            endpoint.close()
    assert result.failing == [] and all(r.stop_confirmed for r in result.robots)
    # stop lines only, in each robot's format (once, in a fresh clone's run beside the node
    # tests, a line that was not one came: the message says which robot heard what)
    assert heard and set(heard) == {'stop'}, [h for h in heard if h != 'stop']
    assert result.problems == ['the camera tracker has no arena calibration (corner markers '
                               'not seen, or no calibration_file)']
    assert not result.passed and 'camera: arena calibration residual none px' in result.table()
