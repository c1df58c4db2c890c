"""Why the paper's law stalls on case 1, and what the observer law does instead (figure).

Run: scripts/bench paper_stall [--out docs/figures] [--duration 120]

Simulates paper case 1 (continuous control, d = [1, 1]) with the paper's law and with the
observer law from the same start, and plots: the error norm; the forward push p_i = d_v -
k2 dhat_v,i that the estimate leaves uncancelled, against the instability threshold k1 l
(docs/control-laws-results.md); the turn-channel estimate error; the fastest heading rate.
Prints the numbers quoted in the docs.
"""

import argparse
import dataclasses
from pathlib import Path

import matplotlib
import numpy as np

from curve_formation.core.config.loading import load_experiment
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--out', default='docs/figures')
    parser.add_argument('--duration', type=float, default=120.0)
    args = parser.parse_args()
    case = load_experiment(resolve_config('closed_curve'))
    gains = case.gains
    runs = {'paper': simulate(case, duration=args.duration, gains=gains.paper_law()),
            'observer': simulate(case, duration=args.duration,
                                 gains=dataclasses.replace(gains, law='observer'))}
    threshold = gains.k1 * gains.offset
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for name, result in runs.items():
        t = result.t
        push = result.disturbance[:, 0] - gains.k2 * result.dhat[..., 0]
        turn = result.disturbance[:, 1] - gains.k2 * result.dhat[..., 1]
        rates = np.abs(np.diff(np.unwrap(result.poses[..., 2], axis=0), axis=0)) / np.diff(
            t)[:, None]
        axes[0, 0].semilogy(t, result.error_norm, label=name)
        axes[0, 1].plot(t, push, lw=0.8, color='C0' if name == 'paper' else 'C1')
        axes[1, 0].plot(t, turn, lw=0.8, color='C0' if name == 'paper' else 'C1')
        axes[1, 1].semilogy(t[1:], rates.max(axis=1) + 1e-9, label=name)
        for when in (5.0, 60.0, args.duration - result.t[1]):
            k = np.searchsorted(t, when)
            above = np.mean(push[:k + 1][-500:] > threshold)
            print(f'{name:8s} t = {t[k]:6.1f} s: ||e|| = {result.error_norm[k]:.3g}, '
                  f'max |p| = {np.abs(push[k]).max():.3g}, max |q| = {np.abs(turn[k]).max():.3g}'
                  f', share of the last 5 s with p > k1 l: {above:.2f}')
    axes[0, 0].set(ylabel='||e||', title='error norm, paper case 1, continuous')
    axes[0, 0].legend()
    axes[0, 1].axhline(threshold, color='k', ls='--', lw=0.8)
    axes[0, 1].set_yscale('symlog', linthresh=threshold)
    axes[0, 1].set(ylabel='p = d_v - k2 dhat_v (m/s), symlog',
                   title=f'forward push left uncancelled (dashed: k1 l = {threshold:g})')
    axes[1, 0].set(xlabel='t (s)', ylabel='q = d_w - k2 dhat_w (rad/s)',
                   title='turn channel: adapts at k2^2 l^2 / k1 (paper)')
    axes[1, 1].set(xlabel='t (s)', ylabel="max |theta'| (rad/s)",
                   title='fastest heading rate (circling)')
    axes[1, 1].legend()
    fig.tight_layout()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / 'paper_stall.png', dpi=110)
    print(f'wrote {out / "paper_stall.png"}')


if __name__ == '__main__':
    main()
