"""Figures like the paper's: paths over the desired curves, error norm, orientations.

Headless (Agg backend). Inputs are the same plain arrays as core.metrics.
"""

from pathlib import Path

import matplotlib


matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from curve_formation.core import metrics  # noqa: E402


def _switch_lines(ax, experiment):
    for p in experiment.phases[1:]:
        ax.axvline(p.start, color='0.5', lw=0.8, ls=':')


def plot_paths(path, experiment, poses, phase, title=None, overlay=None):
    """Agents' offset-point paths over the desired curve(s); start o, end x, targets *.

    overlay: optional (label, poses) of a second run drawn dashed for comparison.
    """
    fig, ax = plt.subplots(figsize=(7, 6))
    colors = plt.cm.tab10(np.arange(experiment.n) % 10)
    for p in experiment.phases:
        s, pts = p.curve.sample(600)
        closed = np.vstack([pts, pts[:1]]) if p.curve.basis.closed else pts
        ax.plot(closed[:, 0], closed[:, 1], color='k', lw=1.2, ls='--',
                label=f'curve {p.index} (t >= {p.start:g} s)')
        ax.plot(p.targets[:, 0], p.targets[:, 1], '*', color='k', ms=7)
    xb = metrics.offset_points(poses, experiment.gains.offset)
    for i in range(experiment.n):
        ax.plot(xb[:, i, 0], xb[:, i, 1], color=colors[i], lw=0.9, label=f'agent {i + 1}'
                if experiment.n <= 12 else None)
        ax.plot(xb[0, i, 0], xb[0, i, 1], 'o', color=colors[i], ms=4)
        ax.plot(xb[-1, i, 0], xb[-1, i, 1], 'x', color=colors[i], ms=7)
    if overlay is not None:
        label, other = overlay
        oxb = metrics.offset_points(other, experiment.gains.offset)
        for i in range(experiment.n):
            ax.plot(oxb[:, i, 0], oxb[:, i, 1], color=colors[i], lw=0.8, ls=(0, (4, 3)),
                    alpha=0.7)
        ax.plot([], [], color='0.3', ls=(0, (4, 3)), label=label)
    ax.set_aspect('equal')
    ax.set_xlabel('x')
    ax.set_ylabel('y')
    ax.set_title(title or f'{experiment.name}: paths')
    ax.legend(fontsize=7, loc='best')
    _save(fig, path)


def plot_error_norm(path, experiment, series, tolerance=None, title=None):
    """Error norm ||xb_e|| vs time on a log scale; series: [(label, t, norm)]."""
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for label, t, norm in series:
        ax.semilogy(t, np.maximum(norm, 1e-12), lw=1.0, label=label)
    if tolerance is not None:
        ax.axhline(tolerance, color='r', lw=0.8, ls='--', label='tolerance')
    _switch_lines(ax, experiment)
    ax.set_xlabel('time (s)')
    ax.set_ylabel('||xb_e||')
    ax.set_title(title or f'{experiment.name}: error norm')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)


def plot_orientations(path, experiment, t, poses, title=None):
    """Headings wrapped to [0, 2 pi) vs time, as in the paper."""
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(t, np.mod(poses[..., 2], 2 * np.pi), lw=0.6, marker='.', ms=0.5, ls='none')
    _switch_lines(ax, experiment)
    ax.set_xlabel('time (s)')
    ax.set_ylabel('theta (rad)')
    ax.set_ylim(0, 2 * np.pi)
    ax.set_title(title or f'{experiment.name}: orientations')
    _save(fig, path)


def plot_lyapunov(path, experiment, t, value, title=None):
    """Lyapunov function V vs time on a log scale."""
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.semilogy(t, np.maximum(value, 1e-12), lw=1.0)
    _switch_lines(ax, experiment)
    ax.set_xlabel('time (s)')
    ax.set_ylabel('V')
    ax.set_title(title or f'{experiment.name}: Lyapunov function')
    ax.grid(True, which='both', alpha=0.3)
    _save(fig, path)


def run_figures(out_dir, experiment, t, poses, phase, dhat=None, label='run'):
    """Write paths.png, error_norm.png, orientations.png (and lyapunov.png with dhat)."""
    out = Path(out_dir)
    errors = metrics.target_errors(poses, phase, experiment, t=t)
    norm = metrics.error_norm(errors)
    tol = experiment.spec.metrics.tolerance * experiment.phases[0].curve.size()
    written = [out / 'paths.png', out / 'error_norm.png', out / 'orientations.png']
    plot_paths(written[0], experiment, poses, phase)
    plot_error_norm(written[1], experiment, [(label, t, norm)], tol)
    plot_orientations(written[2], experiment, t, poses)
    if dhat is not None:
        written.append(out / 'lyapunov.png')
        plot_lyapunov(written[3], experiment, t, metrics.lyapunov(errors, dhat, experiment))
    return written


def _save(fig, path):
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
