"""Figures of a run as a paper prints them: paths over the curves, error norm, headings, V.

One style for every figure: units on every axis, each robot in the same colour everywhere,
legends outside the data, the curve switches marked, PNG at 300 dpi beside a PDF. The paper's
figures (error norms, trajectories, orientations) are the reference for what is shown.
Headless (Agg backend). Inputs are the same plain arrays as core.record.metrics; lengths in m,
times
in s, angles in rad, in the arena frame.
"""

import functools
from pathlib import Path
from typing import Any

import matplotlib


matplotlib.use('Agg')
from matplotlib.patches import Circle, Rectangle  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from curve_formation.core.formation import dynamics
from curve_formation.core.record import metrics  # noqa: E402


DPI = 300
FORMATS = ('png', 'pdf')
STYLE: Any = {   # rcParams (Any: matplotlib types its keys as literals)
    'font.size': 9, 'axes.titlesize': 10, 'axes.labelsize': 9, 'legend.fontsize': 8,
    'xtick.labelsize': 8, 'ytick.labelsize': 8, 'axes.grid': True, 'grid.alpha': 0.3,
    'pdf.fonttype': 42}   # TrueType in the PDF: text a journal's checker accepts
SWITCH_STYLE = {'color': '0.35', 'lw': 0.8, 'ls': ':'}
TOLERANCE_STYLE = {'color': 'tab:red', 'lw': 0.9, 'ls': '--'}
LEGEND_LIMIT = 12          # robots named one by one in a legend up to this many
DRAWN_SAMPLES = 3000       # a series is drawn through at most this many samples (thin)


def robot_colors(n):
    """(n, 4) RGBA: robot i's colour in every figure and in the animation."""
    cmap = plt.cm.tab10 if n <= 10 else plt.cm.tab20 if n <= 20 else plt.cm.viridis
    return cmap(np.arange(n) % 20 if n <= 20 else np.linspace(0, 1, n))


def _styled(plot):
    """Draw and save a figure in the module's STYLE."""
    @functools.wraps(plot)
    def styled(*args, **kwargs):
        with plt.rc_context(STYLE):
            return plot(*args, **kwargs)
    return styled


def thin(count, limit=DRAWN_SAMPLES):
    """The samples drawn of a series of `count`: every k-th, the last included, at most about
    `limit` (as many points as a printed column has pixels; metrics use every sample).
    """
    step = max(1, -(-count // limit))
    rows = np.arange(0, count, step)
    return rows if count == 0 or rows[-1] == count - 1 else np.append(rows, count - 1)


def _figure(width=6.5, height=3.2):
    fig, ax = plt.subplots(figsize=(width, height), layout='constrained')
    ax.grid(True, which='both', alpha=STYLE['grid.alpha'])
    return fig, ax


def _legend_outside(ax):
    """The legend right of the axes, never over the data."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, labels, loc='upper left', bbox_to_anchor=(1.02, 1.0),
                  borderaxespad=0.0, fontsize=STYLE['legend.fontsize'])


def _mark_switches(ax, experiment):
    """A dotted line at each curve switch."""
    for k, p in enumerate(experiment.phases[1:]):
        ax.axvline(p.start, **SWITCH_STYLE, label='curve switch' if k == 0 else None)


def draw_arena(ax, arena):
    """The arena's walls (ArenaSpec, or None for none), to scale in the arena frame (m)."""
    if arena is not None:
        ax.add_patch(Rectangle((0.0, 0.0), *arena.size, fill=False, lw=1.5, color='0.2',
                               label='arena walls'))


def _semilogy(ax, t, values, **style):
    """values against t on a log axis, through thin(len(t)) samples; values <= 0 (an exact
    formation) left out rather than clamped.
    """
    rows = thin(len(t))
    shown = np.asarray(values)[rows]
    ax.semilogy(np.asarray(t)[rows], np.where(shown > 0, shown, np.nan), lw=1.0, **style)


def _time_axes(fig, ax, experiment, ylabel, title, path):
    """Finish a figure against time: curve switches, labels, the legend; save it."""
    _mark_switches(ax, experiment)
    ax.set_xlabel('time t (s)')
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    _legend_outside(ax)
    return _save(fig, path)


def _robot_entries(ax, colors, n):
    """Legend entries naming each robot in its colour (one entry for them all past
    LEGEND_LIMIT).
    """
    if n > LEGEND_LIMIT:
        ax.plot([], [], color=colors[n // 2], lw=1.2, label=f'robots 1-{n}')
        return
    for i in range(n):
        ax.plot([], [], color=colors[i], lw=1.2, label=f'robot {i + 1}')


@_styled
def plot_paths(path, experiment, poses, phase, title=None, overlay=None):
    """Each robot's offset point over the curve(s), with the arena's walls and each body drawn
    to scale at its end pose (a line gives its heading). poses (R, n, 3).
    overlay: optional (label, poses) of a second run drawn dashed for comparison.
    """
    n = experiment.n
    colors = robot_colors(n)
    arena = experiment.spec.arena
    xb = dynamics.offset_points(poses, experiment.gains.offset)[thin(len(poses))]
    shown = [xb.reshape(-1, 2), *(p.curve.sample(200)[1] for p in experiment.phases)]
    if arena is not None:
        shown.append(np.array([[0.0, 0.0], arena.size]))
    points = np.vstack(shown)
    span = np.nanmax(points, axis=0) - np.nanmin(points, axis=0)
    aspect = float(np.clip(span[1] / max(span[0], 1e-9), 0.25, 1.6))
    entries = (len(experiment.phases) + (n if n <= LEGEND_LIMIT else 1) + 3
               + (arena is not None) + (overlay is not None))
    # axes about 4.3 in wide; tall enough for the legend beside them
    fig, ax = _figure(6.5, max(4.3 * aspect + 1.0, 0.19 * entries + 0.7))
    draw_arena(ax, arena)
    for k, p in enumerate(experiment.phases):
        line = p.curve.outline(600)
        ax.plot(line[:, 0], line[:, 1], color='0.15', lw=1.1,
                ls=('--', '-.', ':')[k % 3], label=f'curve {p.index} (from {p.start:g} s)')
        ax.plot(p.targets[:, 0], p.targets[:, 1], '*', color='0.15', ms=7, ls='none',
                label='targets' if k == len(experiment.phases) - 1 else None)
    for i in range(n):
        ax.plot(xb[:, i, 0], xb[:, i, 1], color=colors[i], lw=0.9)
        ax.plot(xb[0, i, 0], xb[0, i, 1], 'o', color=colors[i], ms=3.5)
        _body(ax, poses[-1, i], experiment.radius, colors[i])
    _robot_entries(ax, colors, n)
    ax.plot([], [], 'o', color='0.4', ms=3.5, label='start')
    ax.plot([], [], marker=r'$\ominus$' if experiment.radius > 0 else 'x', color='0.4',
            ls='none', ms=7, label='end (body to scale)' if experiment.radius > 0 else 'end')
    if overlay is not None:
        label, other = overlay
        oxb = dynamics.offset_points(other, experiment.gains.offset)[thin(len(other))]
        for i in range(n):
            ax.plot(oxb[:, i, 0], oxb[:, i, 1], color=colors[i], lw=0.8, ls=(0, (4, 3)),
                    alpha=0.7)
        ax.plot([], [], color='0.3', ls=(0, (4, 3)), label=label)
    ax.set_aspect('equal', adjustable='box')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_title(title or f'{experiment.name}: paths of the offset points')
    _legend_outside(ax)
    return _save(fig, path)


def _body(ax, pose, radius, color):
    """A robot at pose (x, y, theta): its body to scale (radius m) and heading, or a cross."""
    x, y, theta = pose
    if radius > 0:
        ax.add_patch(Circle((x, y), radius, fill=False, color=color, lw=1.0))
        ax.plot([x, x + radius * np.cos(theta)], [y, y + radius * np.sin(theta)],
                color=color, lw=1.0)
    else:
        ax.plot(x, y, 'x', color=color, ms=6)


@_styled
def plot_error_norm(path, experiment, series, tolerance=None, title=None, settled=()):
    """Error norm ||xb_e|| (m) against time (s), log scale; series: [(label, t, norm)].
    tolerance: the experiment's (m), drawn as a line; settled: [(label, time s)] marked where
    the error entered the tolerance for good. Zeros (an exact formation) are left out of a log
    axis rather than clamped.
    """
    fig, ax = _figure()
    for label, t, norm in series:
        _semilogy(ax, t, norm, label=label)
    if tolerance is not None:
        ax.axhline(tolerance, **TOLERANCE_STYLE, label=f'tolerance ({tolerance:.2g} m)')
    for k, (label, when) in enumerate(settled):
        ax.axvline(when, color='tab:green', lw=0.9, ls=('-.', (0, (5, 2)), '-')[k % 3],
                   label=f'{label} settled ({when:.1f} s)')
    return _time_axes(fig, ax, experiment, r'error norm $\|\bar{x}_e\|$ (m)',
                      title or f'{experiment.name}: formation error', path)


@_styled
def plot_orientations(path, experiment, t, poses, title=None):
    """Each robot's heading (rad) against time (s), unwrapped (no jumps at 2 pi)."""
    fig, ax = _figure()
    colors = robot_colors(experiment.n)
    rows = thin(len(t))
    headings = np.unwrap(poses[..., 2], axis=0)[rows]
    for i in range(experiment.n):
        ax.plot(np.asarray(t)[rows], headings[:, i], color=colors[i], lw=0.9)
    _robot_entries(ax, colors, experiment.n)
    return _time_axes(fig, ax, experiment, r'heading $\theta$ (rad)',
                      title or f'{experiment.name}: orientations', path)


@_styled
def plot_lyapunov(path, experiment, t, value, title=None):
    """The law's Lyapunov function V (m^2) against time (s), log scale."""
    fig, ax = _figure()
    _semilogy(ax, t, value, color='0.15', label='V')
    return _time_axes(fig, ax, experiment, r'Lyapunov function $V$ (m$^2$)',
                      title or f'{experiment.name}: Lyapunov function', path)


def settle_marks(result):
    """[(label, time s)] of each settled phase of a metrics dict (metrics.run_metrics)."""
    if not result:
        return []
    return [(f"curve {p['index']}", p['start'] + p['settle_time'])
            for p in result.get('phases', ()) if p.get('settled')]


def run_figures(out_dir, experiment, t, poses, phase, dhat=None, label='run', result=None):
    """paths, error_norm, orientations (and lyapunov with dhat), each as PNG and PDF; result
    (metrics.run_metrics) marks when each phase settled. Returns the PNG paths.
    """
    out = Path(out_dir)
    errors = metrics.target_errors(poses, phase, experiment, t=t)
    norm = metrics.error_norm(errors)
    written = [plot_paths(out / 'paths.png', experiment, poses, phase),
               plot_error_norm(out / 'error_norm.png', experiment, [(label, t, norm)],
                               experiment.tolerance(),
                               settled=settle_marks(result)),
               plot_orientations(out / 'orientations.png', experiment, t, poses)]
    if dhat is not None:
        written.append(plot_lyapunov(out / 'lyapunov.png', experiment, t,
                                     metrics.lyapunov(errors, dhat, experiment)))
    return written


def _save(fig, path):
    """Write the figure as PNG (300 dpi) and beside it as PDF; returns the PNG path."""
    path = Path(path).with_suffix('.png')
    path.parent.mkdir(parents=True, exist_ok=True)
    for fmt in FORMATS:
        fig.savefig(path.with_suffix(f'.{fmt}'), dpi=DPI)
    plt.close(fig)
    return path
