"""Batch simulator speed: wall time per paper case and scaling in the number of agents.

Run: scripts/bench simulation_speed   (or python benchmarks/simulation_speed.py [--quick])

Prints a table per part. Compilation is done (and cached) before anything is timed; each
figure is the best of `--repeat` runs. Goals: the 150 s shape-change case at dt = 1 ms well
under a second; mona_arena (9 robots, bodies and the safety filter) at 10 Hz at least 1000x
real time; cost linear in n. A file whose controllers estimate their latency has no
continuous row (its commands must be timed at a rate).
"""

import argparse
import time

from scenarios import scaled_experiment
import yaml

from curve_formation.core.config.loading import build_experiment, load_experiment
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


CASES = ('closed_curve', 'open_curve', 'shape_change', 'mona_arena')


def best_time(func, repeat):
    best = float('inf')
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        best = min(best, time.perf_counter() - start)
    return best


def paper_cases(repeat):
    print('Paper cases (dt = 1 ms; continuous = substepped RK4, 10 Hz = zero-order hold)')
    print(f'{"case":14s} {"sim s":>6s} {"mode":>11s} {"wall s":>8s} {"steps/s":>11s} '
          f'{"x real time":>11s}')
    for name in CASES:
        experiment = load_experiment(resolve_config(name))
        spec = experiment.spec.simulation
        steps = int(round(spec.duration / spec.dt))
        for label, rate in (('continuous', None), ('10 Hz', 10.0)):
            if rate is None and experiment.spec.controller.estimate_latency:
                print(f'{name:14s} {spec.duration:6.0f} {label:>11s} {"-":>8s} {"-":>11s} '
                      f'{"-":>11s}  (estimates its latency: needs a rate)')
                continue
            simulate(experiment, rate_hz=rate, duration=0.01)   # compile outside the timing
            wall = best_time(lambda e=experiment, r=rate: simulate(e, rate_hz=r), repeat)
            print(f'{name:14s} {spec.duration:6.0f} {label:>11s} {wall:8.3f} '
                  f'{steps / wall:11.3e} {spec.duration / wall:11.0f}')


def arena_with_avoidance(repeat):
    """mona_arena's 9 robots with bodies and the safety filter at 10 Hz, its controllers told
    their latency: none (the online estimate's replay over the record is timed in the table
    above), and 150 ms (each command acting that late, the controllers predicting over it).
    """
    print()
    for latency in (0.0, 0.15):
        data = yaml.safe_load(resolve_config('mona_arena').read_text())
        data['controller'].update(estimate_latency=False, command_latency=latency)
        experiment = build_experiment(data, 'mona_arena.yaml')
        simulate(experiment, duration=0.01)
        wall = best_time(lambda e=experiment: simulate(e), repeat)
        duration = experiment.spec.simulation.duration
        print(f'mona_arena, 9 robots, bodies and avoidance, 10 Hz, latency {1000 * latency:.0f} '
              f'ms told: {wall:.3f} s for {duration:g} s, {duration / wall:.0f}x real time '
              '(goal 1000x)')


def scaling(sizes, repeat):
    print('\nScaling in n (10 s simulated at dt = 1 ms, 10 Hz zero-order hold, ~1.3 n edges)')
    print(f'{"n":>6s} {"H":>6s} {"wall s":>8s} {"steps/s":>10s} {"agent-steps/s":>14s} '
          f'{"us per agent-step":>18s}')
    base = None
    for n in sizes:
        experiment = scaled_experiment(n)
        simulate(experiment, duration=0.01)
        wall = best_time(lambda e=experiment: simulate(e), repeat)
        steps = 10_000
        per_agent = wall / (steps * n) * 1e6
        base = base or per_agent
        print(f'{n:6d} {experiment.phases[0].curve.basis.H:6d} {wall:8.3f} '
              f'{steps / wall:10.3e} {steps * n / wall:14.3e} {per_agent:18.3f}')
    print(f'cost per agent-step at the largest n is {per_agent / base:.2f}x that at n = '
          f'{sizes[0]} (1.00 = linear)')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--quick', action='store_true', help='fewer sizes, one repeat')
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()
    repeat = 1 if args.quick else args.repeat
    paper_cases(repeat)
    arena_with_avoidance(repeat)
    scaling([9, 50, 100] if args.quick else [9, 25, 50, 100, 250, 500, 1000], repeat)


if __name__ == '__main__':
    main()
