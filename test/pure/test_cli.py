import json

from curve_formation.cli import main


def test_sim_writes_metrics_and_figures(tmp_path):
    out = tmp_path / 'open'
    assert main(['sim', 'open_curve', '--out', str(out)]) == 0
    data = json.loads((out / 'metrics.json').read_text())
    assert data['experiment'] == 'open_curve'
    assert data['control'] == 'continuous'
    assert data['phases'][0]['initial_error_norm'] > data['final_error_norm']
    for name in ('paths.png', 'error_norm.png', 'orientations.png', 'lyapunov.png'):
        png = (out / name).read_bytes()
        assert png[:8] == b'\x89PNG\r\n\x1a\n' and len(png) > 10_000


def test_metrics_say_where_they_came_from_and_in_which_units(tmp_path):
    import hashlib

    from curve_formation import version
    from curve_formation.paths import resolve_config
    out = tmp_path / 'open'
    assert main(['sim', 'open_curve', '--out', str(out)]) == 0
    data = json.loads((out / 'metrics.json').read_text())
    made = data['provenance']
    assert made['version'] == version() and made['package'] == 'curve_formation'
    assert made['experiment_sha256'] == hashlib.sha256(
        resolve_config('open_curve').read_bytes()).hexdigest()
    assert made['date'].endswith('+00:00') and 'sim' in made['command']
    assert made['commit'] is None or len(made['commit'].split('-')[0]) == 40
    units = data['units']
    assert units['settle_time'] == 's' and units['final_error_norm'] == 'm'
    assert units['curve_size'] == 'm' and units['duration'] == 's'


def test_an_output_folder_that_holds_something_is_refused_unless_forced(tmp_path, capsys):
    out = tmp_path / 'open'
    assert main(['sim', 'open_curve', '--out', str(out)]) == 0
    before = (out / 'metrics.json').stat().st_mtime_ns
    assert main(['sim', 'open_curve', '--out', str(out)]) == 2
    assert 'output folder is not empty; give a new one, or --force' in capsys.readouterr().err
    assert (out / 'metrics.json').stat().st_mtime_ns == before
    for command in (['run', 'arena_demo'], ['analyze', str(tmp_path / 'bag')],
                    ['params', 'arena_demo']):   # refused before anything starts
        assert main([*command, '--out', str(out)]) == 2, command
        assert 'output folder is not empty' in capsys.readouterr().err
    assert main(['sim', 'open_curve', '--out', str(out), '--force']) == 0
    assert (out / 'metrics.json').stat().st_mtime_ns > before


def test_a_rate_given_on_the_command_line_passes_the_files_checks(tmp_path, capsys):
    """arena_demo's finite-time tail refuses 5 Hz in the file; so it does from --rate."""
    for command in (['sim', 'arena_demo', '--rate', '5'], ['run', 'arena_demo', '--rate', '5'],
                    ['params', 'arena_demo', '--rate', '5']):
        assert main([*command, '--out', str(tmp_path / command[0])]) == 2
        err = capsys.readouterr().err
        assert 'arena_demo.yaml: controller.tail.gain: with --rate 5: ' in err, err
        assert 'must stay below rate_hz 5' in err
    assert main(['sim', 'arena_demo', '--rate', '20', '--out', str(tmp_path / 'ok')]) == 0


def test_sim_rate_option_switches_to_zero_order_hold(tmp_path):
    assert main(['sim', 'open_curve', '--rate', '20', '--out', str(tmp_path)]) == 0
    assert json.loads((tmp_path / 'metrics.json').read_text())['control'] == (
        'zero-order hold at 20 Hz')


def test_unknown_experiment_is_a_clear_error(tmp_path, capsys):
    assert main(['sim', 'no_such_case', '--out', str(tmp_path)]) == 2
    assert 'neither a file nor a shipped experiment' in capsys.readouterr().err


def test_check_reports_certificate_assumptions_and_fit(capsys):
    assert main(['check', 'shape_change', '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['theorem1']['min_eig_P'] > 0 and report['theorem1']['min_eig_Q'] > 0
    assert [c['rank_G_bar'] for c in report['curves']] == [18, 18]
    assert all(c['n_le_H'] and c['fit_rms_residual'] < 1e-9 for c in report['curves'])


def test_a_bridge_without_simulated_robots_is_refused_with_the_way_to_real_ones(tmp_path,
                                                                                capsys):
    for command in ('run', 'params'):
        assert main([command, 'arena_demo', '--no-sim', '--bridge', 'udp',
                     '--out', str(tmp_path / command)]) == 2
        assert "robots' bridges start from the file's robots.fleet" in capsys.readouterr().err


def test_a_split_run_names_its_parts_and_needs_a_shared_domain(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv('ROS_DOMAIN_ID', '7')
    assert main(['run', 'arena_demo', '--only', 'robot', '--out', str(tmp_path / 'a')]) == 2
    assert ("--only: unknown part(s) ['robot']; choose from curve_server, controllers, robots, "
            'camera, observer') in capsys.readouterr().err
    monkeypatch.delenv('ROS_DOMAIN_ID')
    assert main(['run', 'arena_demo', '--only', 'robots', '--out', str(tmp_path / 'b')]) == 2
    assert 'set the same ROS_DOMAIN_ID on every host' in capsys.readouterr().err


def test_agents_of_a_split_run_are_numbers_and_ranges(capsys, monkeypatch, tmp_path):
    from curve_formation.commands import _agents
    assert _agents('1-3,5') == {1, 2, 3, 5} and _agents(None) is None
    monkeypatch.setenv('ROS_DOMAIN_ID', '7')
    assert main(['run', 'arena_demo', '--only', 'controllers', '--agents', '1-x',
                 '--out', str(tmp_path / 'a')]) == 2
    assert "--agents: expected agent numbers and ranges such as 1-5,9, got '1-x'" in (
        capsys.readouterr().err)
    assert main(['run', 'arena_demo', '--only', 'controllers', '--agents', '8-12',
                 '--out', str(tmp_path / 'b')]) == 2
    assert '--agents: agent 12 is not in 1..9 (arena_demo)' in capsys.readouterr().err
