"""report.html opened as a reader would, in headless Chromium (Debian's chromium package, which
scripts/test installs): the page renders, every image and the film load, nothing is fetched
from the network, no console error; a screenshot is saved in the test's folder.
"""

import json
import shutil

import pytest

from curve_formation.results.report import verdicts


CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
                 '--disable-background-networking', '--disable-component-update',
                 '--disable-sync']


def chromium():
    path = shutil.which('chromium')
    if path is None:
        pytest.fail('chromium not found: scripts/test installs it (apt-get install chromium, '
                    'as root)')
    return path


@pytest.fixture(scope='module')
def simulated(tmp_path_factory):
    """`sim shape_change --animate`: two curves, a switch, the film."""
    from curve_formation.cli import main
    out = tmp_path_factory.mktemp('shape_change')
    assert main(['sim', 'shape_change', '--out', str(out), '--animate', '--force']) in (0, None)
    return out


def test_the_report_renders_every_image_and_the_film_in_chromium(simulated):
    from playwright.sync_api import sync_playwright
    report = simulated / 'report.html'
    errors, fetched = [], []
    with sync_playwright() as driver:
        browser = driver.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={'width': 1100, 'height': 900})
            page.on('console', lambda m: errors.append(m.text) if m.type == 'error' else None)
            page.on('pageerror', lambda exc: errors.append(str(exc)))
            page.on('request', lambda r: fetched.append(r.url))
            page.goto(report.as_uri(), wait_until='load')
            images = page.eval_on_selector_all(
                'img', 'els => els.map(e => [e.alt, e.complete, e.naturalWidth])')
            page.wait_for_function("document.querySelector('video').readyState >= 2",
                                   timeout=10_000)
            film = page.evaluate("(() => { const v = document.querySelector('video'); "
                                 "return [v.videoWidth, v.duration, v.error]; })()")
            title = page.title()
            headings = page.eval_on_selector_all('h2', 'els => els.map(e => e.textContent)')
            page.screenshot(path=str(simulated / 'report_screenshot.png'), full_page=True)
        finally:
            browser.close()
    assert len(images) >= 4 and all(done and width > 0 for _, done, width in images), images
    assert film[0] > 0 and film[1] > 1.0 and film[2] is None, film
    assert not errors, errors
    assert all(url.startswith(('file:', 'data:')) for url in fetched), fetched
    assert title.startswith('shape_change')
    assert {'Verdict', 'Curves', 'Metrics', 'Animation', 'Figures', 'Provenance'} <= set(headings)
    assert (simulated / 'report_screenshot.png').stat().st_size > 50_000


def test_verdicts_say_in_words_what_settled_and_why_not():
    result = {'phases': [
        {'index': 0, 'settled': True, 'settle_time': 12.5, 'tolerance': 0.00077},
        {'index': 1, 'settled': False, 'settle_time': None, 'tolerance': 0.00077,
         'final_error_norm': 0.0031,
         'not_settled_because': 'the error does not stay below the tolerance'}],
        'bodies': {'contacts': {'count': 2.0, 'time': 0.4}},
        'estop': {'intervals': [[5.0, 9.5]]},
        'node_deaths': [{'node': 'robot_3.formation_controller', 't': 20.0, 'how': 'killed'}]}
    said = verdicts(result)
    assert said[0] == (True, 'Curve 0 settled 12.5 s after it began: every robot within the '
                             'tolerance (0.77 mm) from then on.')
    assert said[1][0] is False and 'does not stay below the tolerance' in said[1][1]
    assert '3.1 mm' in said[1][1]
    assert said[2] == (False, '2 contacts between bodies, 0.4 s in all.')
    assert said[3] == (True, 'The e-stop held the robots from t = 5 s to 9.5 s.')
    assert said[4] == (False, 'Node robot_3.formation_controller died at t = 20 s (killed).')


def test_the_report_of_a_run_holds_its_metrics_with_units(simulated):
    page = (simulated / 'report.html').read_text()
    result = json.loads((simulated / 'metrics.json').read_text())
    for phase in result['phases']:
        assert f"Curve {phase['index']} " in page
    assert '<td>final_error_norm</td>' in page and '<td>m</td>' in page
    assert result['provenance']['experiment_sha256'] in page


def test_the_report_lists_each_robot_as_its_controller_found_it(tmp_path):
    """A ROS run's robot_estimates (its controllers' last /diagnostics) and a simulation's
    estimated_* lists both become one row per robot: latency and motors' lag in ms, wheel
    gains, dead band in mm/s, '-' where none was told.
    """
    from curve_formation.results.report import write_report
    ros = {'robot_estimates': {'robot_2': {'command_latency': 0.104, 'motor_time_constant':
                                           0.038, 'wheel_gains': None, 'dead_band': 0.00112},
                               'robot_1': {'command_latency': 0.1, 'motor_time_constant': 0.0,
                                           'wheel_gains': [0.95, 1.05], 'dead_band': None}}}
    sim = {'estimated_latency': [0.1, 0.104], 'estimated_motor_time_constant': [0.0, 0.038],
           'estimated_wheel_gains': [[0.95, 1.05], None], 'estimated_dead_band': [None, 0.00112]}
    pages = []
    for k, result in enumerate((ros, sim)):
        folder = tmp_path / str(k)
        folder.mkdir()
        (folder / 'metrics.json').write_text(json.dumps({'phases': [], **result}))
        pages.append(write_report(folder).read_text())
    for page in pages:
        assert ('<tr><td>robot 1</td><td>100</td><td>0</td><td>0.950 / 1.050</td><td>-</td></tr>'
                '<tr><td>robot 2</td><td>104</td><td>38</td><td>-</td><td>1.12</td></tr>') in page
    (tmp_path / '0' / 'metrics.json').write_text(json.dumps({'phases': []}))
    assert 'as their controllers found them' not in write_report(tmp_path / '0').read_text()
    # with bounds and sources (RobotModel.estimates, as /diagnostics and a pipeline carry them)
    (tmp_path / '0' / 'metrics.json').write_text(json.dumps({'phases': [], 'robot_estimates': {
        'robot_1': {'command_latency': 0.1, 'command_latency_bound': 0.004,
                    'command_latency_from': 'online', 'motor_time_constant': 0.04,
                    'motor_time_constant_bound': None, 'motor_time_constant_from': 'told',
                    'wheel_gains': [0.95, 1.05], 'wheel_gains_bound': [0.003, 0.006],
                    'wheel_gains_from': 'check', 'dead_band': 0.0011,
                    'dead_band_bound': 0.0002, 'dead_band_from': 'online'}}}))
    page = write_report(tmp_path / '0').read_text()
    assert ('<tr><td>robot 1</td><td>100 &plusmn; 4 (online)</td><td>40 (told)</td>'
            '<td>0.950 / 1.050 &plusmn; 0.003 / 0.006 (check)</td>'
            '<td>1.10 &plusmn; 0.20 (online)</td></tr>') in page
