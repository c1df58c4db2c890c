"""report.html: one self-contained page per run (figures and film embedded, no network).

Built from what `sim`, `run`, `analyze` and the demo write into a run's folder: metrics.json
(with its units and provenance), the figures (figures.plots), the animation (figures.animation) and
the experiment's text. It says in plain words whether each curve settled and why not,
whether bodies touched, when the e-stop held the robots and which node died.
"""

import base64
import html
import json
from pathlib import Path

from curve_formation.interface import robot_index


REPORT = 'report.html'
FIGURES = (('paths.png', 'Paths of the offset points over the curves; bodies to scale at '
            'their end poses.'),
           ('error_norm.png', 'Formation error against time (log scale), with the tolerance '
            'and when each curve settled.'),
           ('law_comparison.png', "The paper's law and ours from the same start."),
           ('compare_error_norm.png', 'This run against the compared one.'),
           ('compare_sim_error_norm.png', 'This run against its simulation from the same '
            'start.'),
           ('orientations.png', 'Headings against time, unwrapped.'),
           ('lyapunov.png', "The law's Lyapunov function against time."))
FILMS = ('animation.mp4', 'animation.gif')
SUMMARY_KEYS = ('duration', 'final_error_norm', 'closest_approach', 'peak_v', 'peak_w',
                'peak_wheel_speed', 'lyapunov_initial', 'lyapunov_final',
                'final_estimate_error_max', 'final_orientation_rates_max')
STYLE = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:960px;
color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;margin-top:1.6em;
border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f3f3f3}.ok{color:#1a7f37;font-weight:600}.bad{color:#c62828;font-weight:600}
figure{margin:1em 0}figure img,video,.film{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.85em;color:#555}pre{background:#f6f6f6;padding:.6em;overflow:auto;
font-size:.8em}ul.verdicts li{margin:.2em 0}
"""


def write_report(folder, title=None):
    """Write report.html into `folder` (a run's output folder); returns its path."""
    folder = Path(folder)
    result = json.loads((folder / 'metrics.json').read_text())
    units = result.get('units', {})
    name = result.get('experiment', folder.name)
    parts = [f'<h1>{_e(title or name)}</h1>',
             f'<p>{_e(result.get("control", ""))} · {result.get("agents", "?")} robots · '
             f'{_number(result.get("duration"))} s</p>',
             '<h2>Verdict</h2>', _verdicts(result),
             '<h2>Curves</h2>', _phase_table(result),
             '<h2>Metrics</h2>', _metrics_table(result, units)]
    if result.get('fleet') or result.get('preflight'):
        parts += ['<h2>Fleet</h2>', _fleet_table(result)]
    estimates = _estimates_table(result)
    if estimates:
        parts += ['<h2>The robots as their controllers found them</h2>', estimates]
    film = next((folder / f for f in FILMS if (folder / f).exists()), None)
    if film is not None:
        parts += ['<h2>Animation</h2>', _film(film)]
    figures = [(folder / f, caption) for f, caption in FIGURES if (folder / f).exists()]
    if figures:
        parts.append('<h2>Figures</h2>')
        parts += [_figure(path, caption) for path, caption in figures]
    parts += ['<h2>Provenance</h2>', _provenance(result.get('provenance', {}))]
    experiment = folder / 'experiment.yaml'
    if experiment.exists():
        parts += ['<h2>Experiment</h2>',
                  f'<details><summary>experiment.yaml</summary><pre>'
                  f'{_e(experiment.read_text())}</pre></details>']
    page = ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<title>{_e(name)}: curve_formation report</title>'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<style>{STYLE}</style></head><body>\n' + '\n'.join(parts)
            + '\n</body></html>\n')
    out = folder / REPORT
    out.write_text(page)
    return out


def verdicts(result):
    """[(good, sentence)] of a run in plain words: each curve, contacts, e-stops, deaths."""
    out = []
    for p in result.get('phases', ()):
        if p.get('settled'):
            out.append((True, f"Curve {p['index']} settled {_number(p['settle_time'])} s after "
                              f"it began: every robot within the tolerance "
                              f"({_mm(p['tolerance'])}) from then on."))
        else:
            out.append((False, f"Curve {p['index']} did not settle: "
                               f"{p.get('not_settled_because') or 'no reason recorded'} "
                               f"(final error {_mm(p.get('final_error_norm'))}, tolerance "
                               f"{_mm(p.get('tolerance'))})."))
    contacts = (result.get('bodies') or {}).get('contacts')
    if contacts is not None:
        count = int(contacts.get('count') or 0)
        out.append((count == 0, 'No contact between bodies.' if count == 0 else
                    f"{count} contacts between bodies, {_number(contacts.get('time'))} s in "
                    'all.'))
    intervals = (result.get('estop') or {}).get('intervals') or []
    for start, stop in intervals:
        out.append((True, f'The e-stop held the robots from t = {_number(start)} s '
                          + ('to the end.' if stop is None else f'to {_number(stop)} s.')))
    ticks = result.get('ticks')
    if ticks and ticks.get('slowest'):
        slowest = ticks['slowest']
        below = ticks.get('below_rate') or []
        out.append((not below, (f"The controllers of robots {', '.join(map(str, below))} fell "
                                f"below 95 % of {_number(ticks['rate_hz'])} Hz; "
                                if below else 'Every controller kept its rate: ')
                    + f"slowest robot {slowest['robot']} at {_number(slowest['rate_hz'])} Hz, "
                    f"period jitter p99 up to {_number(ticks.get('jitter_ms_p99_worst'))} ms."))
    preflight = result.get('preflight')
    if preflight is not None:
        left = preflight.get('left_out') or []
        out.append((not left, f"Pre-flight passed for {len(preflight.get('robots', []))} "
                    'robots' + (': robots left out for failing it: ' + '; '.join(
                        f"{r['robot']} ({', '.join(r.get('problems', []))})" for r in left)
                        + '.' if left else '.')))
    for event in (result.get('fleet') or {}).get('events', ()):
        lost = event['what'].endswith('lost')
        out.append((not lost, f"Robot {event['robot']}: {event['what']} at t = "
                              f"{_number(event['t'])} s."))
    for death in result.get('node_deaths') or ():
        when = 'before t = 0' if death.get('t') is None else f"at t = {_number(death['t'])} s"
        out.append((False, f"Node {death['node']} died {when} ({death.get('how', '')})."))
    return out


def _verdicts(result):
    items = ''.join(f'<li><span class="{"ok" if good else "bad"}">'
                    f'{"✔" if good else "✘"}</span> {_e(text)}</li>'
                    for good, text in verdicts(result))
    return f'<ul class="verdicts">{items}</ul>'


def _phase_table(result):
    head = ('<tr><th>curve</th><th>from (s)</th><th>size (m)</th><th>tolerance (m)</th>'
            '<th>settled</th><th>settle time (s)</th><th>initial error (m)</th>'
            '<th>final error (m)</th><th>worst robot at the end (m)</th></tr>')
    rows = ''.join(
        f"<tr><td>{p['index']}</td><td>{_number(p['start'])}</td>"
        f"<td>{_number(p.get('curve_size'))}</td><td>{_number(p.get('tolerance'))}</td>"
        f"<td class=\"{'ok' if p.get('settled') else 'bad'}\">"
        f"{'yes' if p.get('settled') else 'no'}</td><td>{_number(p.get('settle_time'))}</td>"
        f"<td>{_number(p.get('initial_error_norm'))}</td>"
        f"<td>{_number(p.get('final_error_norm'))}</td>"
        f"<td>{_number(p.get('final_max_agent_error'))}</td></tr>"
        for p in result.get('phases', ()))
    return f'<table>{head}{rows}</table>'


def _fleet_table(result):
    """The pre-flight per robot, then the fleet's timeline (markers and links lost, back)."""
    rows = ''.join(
        f"<tr><td>robot {r['robot']}</td><td>{_e(r.get('link', ''))}</td>"
        f"<td>{'yes' if r.get('seen') else 'no'}</td>"
        f"<td>{'yes' if r.get('stop_confirmed') else 'no'}</td>"
        f"<td>{_e(', '.join(r.get('problems', [])) or 'ok')}</td></tr>"
        for r in (result.get('preflight') or {}).get('robots', ()))
    table = ('<table><tr><th>pre-flight</th><th>link</th><th>marker seen</th>'
             f'<th>stop confirmed</th><th>problems</th></tr>{rows}</table>' if rows else '')
    events = ''.join(f"<tr><td>{_number(e['t'])}</td><td>robot {e['robot']}</td>"
                     f"<td>{_e(e['what'])}</td></tr>"
                     for e in (result.get('fleet') or {}).get('events', ()))
    timeline = (f'<table><tr><th>t (s)</th><th>robot</th><th>event</th></tr>{events}</table>'
                if events else '<p>No marker or link was lost during the run.</p>')
    return table + timeline


def robot_estimates(result):
    """{robot (1-based): {'command_latency' s, 'motor_time_constant' s, 'wheel_gains'
    [left, right] or None, 'dead_band' m/s or None, and where known each '<name>_bound' and
    '<name>_from'}} from a run's metrics: its `robot_estimates` (a ROS run's controllers'
    last reports, a pipeline simulation's controllers at the end) or else a simulation's
    estimated_* lists; {} if neither.
    """
    if result.get('robot_estimates'):
        return {robot_index(name): values for name, values in result['robot_estimates'].items()}
    lists = {'command_latency': result.get('estimated_latency'),
             'motor_time_constant': result.get('estimated_motor_time_constant'),
             'wheel_gains': result.get('estimated_wheel_gains'),
             'dead_band': result.get('estimated_dead_band')}
    count = max((len(v) for v in lists.values() if v), default=0)
    return {i + 1: {key: values[i] for key, values in lists.items() if values}
            for i in range(count)}


def _estimate_cell(values, name, shown):
    """One robot's `name` as the report shows it: the value (shown(value) -> text, '-' for
    none), +- its bound where it has one, and where it came from (told, online, check).
    """
    value, bound, source = (values.get(name), values.get(f'{name}_bound'),
                            values.get(f'{name}_from'))
    text = shown(value)
    if value is not None and bound is not None:
        text += f' &plusmn; {shown(bound)}'
    return text + (f' ({_e(source)})' if source and value is not None else '')


def _estimates_table(result):
    """Each robot's latency, motors' lag, wheel gains and dead band as its controller held
    them at the end (told or estimated online), each with its bound and source where known;
    '' if the run has none.
    """
    found = robot_estimates(result)
    if not found:
        return ''

    def ms(value):
        return '-' if value is None else f'{1000 * value:.0f}'

    def mm(value):
        return '-' if value is None else f'{1000 * value:.2f}'

    def gains(value):
        return '-' if not value else ' / '.join(f'{g:.3f}' for g in value)

    rows = ''.join(
        f'<tr><td>robot {i}</td>' + ''.join(
            f'<td>{_estimate_cell(v, name, shown)}</td>' for name, shown in (
                ('command_latency', ms), ('motor_time_constant', ms), ('wheel_gains', gains),
                ('dead_band', mm))) + '</tr>' for i, v in sorted(found.items()))
    return ("<table><tr><th>robot</th><th>command latency (ms)</th><th>motors' lag (ms)</th>"
            f'<th>wheel gains (left / right)</th><th>dead band (mm/s)</th></tr>{rows}</table>'
            '<p>As told, or as each controller estimated it online (controller.estimate_latency, '
            'estimate_motors) or in its motor check (controller.motor_check), &plusmn; its '
            "bound: for the latency and the motors' lag how far the last 30 fits of 6 s alone "
            "scatter (robustly), for a wheel gain 3 standard errors, for the dead band its "
            "fit's; a "
            'wheel gain is its speed per unit of command, the dead band the smallest wheel '
            'command that turns a wheel; - where none was told or found.</p>')


def _metrics_table(result, units):
    rows = ''.join(f'<tr><td>{_e(key)}</td><td>{_number(result[key])}</td>'
                   f'<td>{_e(units.get(key, ""))}</td></tr>'
                   for key in SUMMARY_KEYS if key in result and result[key] is not None)
    bodies = result.get('bodies') or {}
    for key in ('radius', 'smallest_gap', 'marker_hidden_time'):
        if bodies.get(key) is not None:
            rows += (f'<tr><td>bodies: {_e(key)}</td><td>{_number(bodies[key])}</td>'
                     f'<td>{_e(units.get(key, ""))}</td></tr>')
    return f'<table><tr><th>metric</th><th>value</th><th>unit</th></tr>{rows}</table>'


def _provenance(provenance):
    rows = ''.join(f'<tr><td>{_e(key)}</td><td>{_e(value)}</td></tr>'
                   for key, value in provenance.items())
    return f'<table>{rows}</table>'


def _data_url(path, mime):
    """The file as a data: URL (the page fetches nothing)."""
    return f'data:{mime};base64,' + base64.b64encode(path.read_bytes()).decode('ascii')


def _figure(path, caption):
    pdf = path.with_suffix('.pdf')
    also = f' (vector: {pdf.name} beside this page)' if pdf.exists() else ''
    return (f'<figure><img src="{_data_url(path, "image/png")}" alt="{_e(path.stem)}">'
            f'<figcaption>{_e(path.name)}: {_e(caption)}{_e(also)}</figcaption></figure>')


def _film(path):
    if path.suffix == '.gif':
        return f'<img class="film" src="{_data_url(path, "image/gif")}" alt="animation">'
    return (f'<video controls muted loop playsinline preload="auto" '
            f'src="{_data_url(path, "video/mp4")}"></video>')


def _number(value):
    if value is None:
        return '–'
    if isinstance(value, bool):
        return 'yes' if value else 'no'
    if isinstance(value, (int, float)):
        return f'{value:.4g}'
    return _e(value)


def _mm(value):
    return '–' if value is None else f'{1000 * value:.3g} mm'


def _e(text):
    return html.escape(str(text))
