"""Collision avoidance on the arena: settling, contacts and gaps from random starts; the dense
and crossing cases; the filter's cost per robot per tick; the simulator's speed with it on.

Run: scripts/bench collision_avoidance   (--seeds N; --quick: 5 seeds; --first K: seeds from
K, e.g. the held-out starts: --first 20 --seeds 60)

For each arena experiment (the shipped mona_arena and arena_demo: 8 cm bodies, the safety
filter, re-assignment) and each start (the file's random box, reseeded), per curve phase:
settling time with avoidance; the same start with the law alone (point robots passing
through each other: today's behaviour, `avoidance: off`), and their ratio where that settles;
the physical lower bound, the longest straight trip of any robot from where the phase begins
to its assigned target at the wheel limit, and the ratio to it; a tighter bound that still
no robot can beat, each robot's turn in place to face its target, forwards or backwards
(whichever turn is smaller), with both wheels at the limit and then its straight trip (for a
differential drive with bounded wheel speeds that is the fastest way to a point: Balkcom and
Mason, "Time optimal trajectories for bounded velocity differential drive vehicles", IJRR
2002), and the ratio to it; contacts between bodies and the smallest gap between two
surfaces over the run.
"""

import argparse
import math
from pathlib import Path
import time

import numpy as np

from curve_formation.core.config.agents import agent_configs
from curve_formation.core.config.experiment import point_robots
from curve_formation.core.config.loading import load_experiment, with_start
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.controller.law import agent_command
from curve_formation.core.controller.safety import AVOIDANCE_OFF
from curve_formation.core.formation import dynamics
from curve_formation.core.record import body_metrics, metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


DATA = Path(__file__).resolve().parent.parent / 'test' / 'data'
ARENA_CASES = ('mona_arena', 'arena_demo')
# 25 robots on a larger curve in the same arena, and a switch whose paths all cross.
HARD_CASES = (DATA / 'dense_arena.yaml', DATA / 'crossing_switch.yaml')


def lower_bounds(result, turning=False, drift=False):
    """Per phase: the longest straight trip (m) of any robot's control point, from where it
    is when the phase begins to its target then, over the wheel limit (s); with turning, each
    robot first turns in place to face its target forwards or backwards, whichever is the
    smaller turn (both wheels at the limit, w = 2 u / B); with drift, that turn and trip as
    the disturbance acting on the robot (not one added on the PC, which the law cancels
    before the limits) lets them go: turning at 2 u / B plus or minus its turn drift d_w,
    either way round, then straight at u - B |d_w| / 2 (cancelling d_w) plus or minus its
    forward drift d_v, backwards only with controller.reverse. An estimate, not a bound: the
    drift also carries the robot while it turns.
    """
    experiment = result.experiment
    points = dynamics.offset_points(result.poses, experiment.gains.offset)
    # turning alone: no drift, and the smaller turn whichever way the robot then drives
    on_robot = drift and experiment.spec.disturbance.injected != 'on_pc'
    reverse = experiment.gains.reverse if drift else True
    out = []
    for p in experiment.phases:
        k = int(np.searchsorted(result.t, p.start))
        if k >= len(result.t):
            break
        trips = p.targets - points[k]
        if turning or drift:
            times = [fastest_with_drift(trips[i], result.poses[k, i, 2],
                                        result.disturbance[i] if on_robot else (0.0, 0.0),
                                        experiment.limits, reverse)
                     for i in range(experiment.n)]
        else:
            times = np.linalg.norm(trips, axis=1) / experiment.limits.max_wheel_speed
        out.append(float(np.max(times)))
    return out


def fastest_with_drift(trip, heading, disturbance, limits, reverse):
    """Seconds to turn in place and drive straight along trip (m, arena frame) from heading
    (rad) under the drift (d_v m/s, d_w rad/s) acting on the robot (lower_bounds); with no
    drift and reverse, the turn-and-straight bound: the smaller of the turns to face the
    target forwards or backwards, at 2 u / B, then the trip at u.
    """
    u, base = limits.max_wheel_speed, limits.wheel_base
    d_v, d_w = disturbance
    distance = math.hypot(*trip)
    best = math.inf
    for way in (1.0, -1.0) if reverse else (1.0,):
        straight = u - 0.5 * base * abs(d_w) + way * d_v
        if straight <= 0.0:
            continue
        off = math.remainder(math.atan2(way * trip[1], way * trip[0]) - heading, 2 * math.pi)
        for turn in (off, off - math.copysign(2 * math.pi, off)):   # either way round
            rate = 2 * u / base + math.copysign(1.0, turn) * d_w
            if rate > 0.0:
                best = min(best, abs(turn) / rate + distance / straight)
    return best


def settling(result):
    data = metrics.result_metrics(result)
    return [p['settle_time'] for p in data['phases']], data


def arena_table(name, seeds):
    case = load_experiment(resolve_config(name))
    rows = []
    for seed in seeds:
        start = seeded_start(case, seed)
        ours = simulate(with_start(case, start))
        alone = simulate(with_start(point_robots(case), start))
        times, data = settling(ours)
        off, _ = settling(alone)
        rows.append({'seed': seed, 'times': times, 'off': off, 'bound': lower_bounds(ours),
                     'turn_bound': lower_bounds(ours, turning=True),
                     'drift_time': lower_bounds(ours, drift=True),
                     'off_bound': lower_bounds(alone),
                     'contacts': ours.contacts['count'], 'gap': ours.contacts['smallest_gap'],
                     'off_gap': body_metrics.closest_approach(alone.poses)[0] - 2 * case.radius,
                     'reassigned': [p['reassignments'] for p in data['phases']],
                     'standstill': standstill(ours)})
    phases = len(case.phases)
    print(f'\n{name}: {len(seeds)} random starts, 10 Hz, bodies of radius {case.radius} m, '
          f'margin {case.avoidance.margin} m')
    print(f'{"phase":>5s} {"settled":>8s} {"median s":>9s} {"max s":>7s} '
          f'{"vs alone: settled, worst ratio":>31s} {"vs bound: median, worst":>24s} '
          f'{"alone vs bound: median, worst":>30s} '
          f'{"vs turn+straight bound: median, worst":>38s}')
    for k in range(phases):
        times = [r['times'][k] for r in rows]
        done = [t for t in times if t is not None]
        ratios = [r['times'][k] / r['off'][k] for r in rows
                  if r['times'][k] is not None and r['off'][k] is not None]
        bound = [r['times'][k] / r['bound'][k] for r in rows if r['times'][k] is not None]
        off_bound = [r['off'][k] / r['off_bound'][k] for r in rows if r['off'][k] is not None]
        turn_bound = [r['times'][k] / r['turn_bound'][k] for r in rows
                      if r['times'][k] is not None]
        alone = sum(r['off'][k] is not None for r in rows)
        worst = max(range(len(rows)), key=lambda q: (rows[q]['times'][k] or math.inf)
                    / rows[q]['bound'][k])
        print(f'{k:5d} {len(done):4d}/{len(rows):<3d} {np.median(done):9.1f} {max(done):7.1f} '
              f'{alone:10d}/{len(rows)}, {max(ratios) if ratios else math.nan:14.2f} '
              f'{np.median(bound):13.2f}, {max(bound):8.2f} '
              f'{np.median(off_bound):19.2f}, {max(off_bound):8.2f} '
              f'{np.median(turn_bound):27.2f}, {max(turn_bound):8.2f}   (worst: seed '
              f'{rows[worst]["seed"]})')
        # What any differential drive at the wheel limit needs, over the straight trip.
        floor = np.array([r['turn_bound'][k] / r['bound'][k] for r in rows])
        print(f'{"":5s} the turn-and-straight bound itself: {np.median(floor):.2f}x the straight '
              f'trip median, {floor.max():.2f}x at most; {int(np.sum(floor >= 1.3))} of '
              f"{len(rows)} starts at 1.3x or more: out of any robot's reach there")
        # The same with the robots' drift (arena_demo's on-robot disturbance): an estimate.
        drifting = np.array([r['drift_time'][k] / r['bound'][k] for r in rows])
        ours = [r['times'][k] / r['drift_time'][k] for r in rows if r['times'][k] is not None]
        print(f'{"":5s} turn and straight with the drift on the robot (an estimate): '
              f'{drifting.max():.2f}x the straight trip at most (seed '
              f'{rows[int(np.argmax(drifting))]["seed"]}), {int(np.sum(drifting >= 1.3))} of '
              f'{len(rows)} starts at 1.3x or more; settling {np.median(ours):.2f}x it median, '
              f'{max(ours):.2f}x worst')
    print(f'contacts: {sum(r["contacts"] for r in rows)} in all; smallest surface gap '
          f'{min(r["gap"] for r in rows) * 1000:.2f} mm (law alone: '
          f'{min(r["off_gap"] for r in rows) * 1000:.1f} mm, i.e. bodies overlapping); '
          f're-assignments per run: median {np.median([sum(r["reassigned"]) for r in rows]):g},'
          f' max {max(sum(r["reassigned"]) for r in rows)}')
    longest = max(rows, key=lambda r: r['standstill'][0])
    seconds, robot, end = longest['standstill']
    print(f'longest a robot stood still over 3 cm from its target (giving way or stuck): '
          f'{seconds:.1f} s (seed {longest["seed"]}, robot {robot + 1}, until {end:.1f} s); '
          f'median over the starts {np.median([r["standstill"][0] for r in rows]):.1f} s')
    return rows


def standstill(result):
    """body_metrics.longest_standstill of a simulation: (s, robot index, end s)."""
    errors = metrics.target_errors(result.poses, result.phase, result.experiment, result.gains,
                                   result.t)
    return body_metrics.longest_standstill(result.t, result.poses, np.linalg.norm(errors, axis=2))


def hard_cases():
    print("\nhard cases (simulator, the file's start)")
    for path in HARD_CASES:
        case = load_experiment(path)
        result = simulate(case)
        times, _ = settling(result)
        bound = lower_bounds(result)
        print(f'  {case.name} ({case.n} robots): settling per phase '
              + ', '.join('-' if t is None else f'{t:.1f} s ({t / b:.1f}x bound)'
                          for t, b in zip(times, bound, strict=False))
              + f'; contacts {result.contacts["count"]}, smallest gap '
              f'{result.contacts["smallest_gap"] * 1000:.2f} mm')


def filter_cost(sizes=(9, 50), ticks=200):
    """Per robot per tick (us): agent_command as the node runs it (plain Python), with the
    safety filter on and off, robots packed in the arena at random (bodies apart).
    """
    case = load_experiment(resolve_config('arena_demo'))
    law = case.gains.tick_law(10.0)
    rng = np.random.default_rng(0)
    print('\nfilter cost per robot per tick, plain Python as in formation_controller')
    for n in sizes:
        poses = _packed(rng, n, case)
        config = agent_configs(case, 10.0)[0]
        costs = {}
        for label, avoidance in (('on', config.avoidance), ('off', AVOIDANCE_OFF)):
            started = time.perf_counter()
            for k in range(ticks):
                i = k % n
                agent_command(0.1, -0.05, 0.0, 0.0, 0.1, -0.05, *poses[i], 0.0, 0.0, 0.0, 0.0,
                              0.0, 0.0, law, case.limits, poses, i, avoidance)
            costs[label] = (time.perf_counter() - started) / ticks * 1e6
        print(f'  N = {n:3d}: {costs["on"]:7.1f} us with the filter, {costs["off"]:6.1f} us '
              f'without ({costs["on"] - costs["off"]:.1f} us for the filter)')


def _packed(rng, n, case):
    """n poses in the arena, bodies at least 2 radius + margin apart (as the filter keeps)."""
    width, height = case.spec.arena.size
    safe = 2 * case.radius + case.avoidance.margin
    points = []
    while len(points) < n:
        p = rng.uniform([case.radius, case.radius], [width - case.radius, height - case.radius])
        if all(np.hypot(*(p - q)) >= safe for q in points):
            points.append(p)
    return np.column_stack([np.array(points), rng.uniform(-np.pi, np.pi, n)])


def simulator_speed(repeats=3):
    print('\nsimulator speed, mona_arena (120 s at 10 Hz, dt 1 ms)')
    case = load_experiment(resolve_config('mona_arena'))
    for label, experiment in (('avoidance on', case), ('law alone', point_robots(case))):
        simulate(experiment, duration=1.0)   # compile
        best = math.inf
        for _ in range(repeats):
            started = time.perf_counter()
            simulate(experiment)
            best = min(best, time.perf_counter() - started)
        duration = experiment.spec.simulation.duration
        print(f'  {label:13s}: {best:.3f} s, {duration / best:.0f}x real time')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--quick', action='store_true', help='5 seeds')
    parser.add_argument('--first', type=int, default=0, help='first seed (default 0)')
    args = parser.parse_args()
    seeds = range(args.first, args.first + (5 if args.quick else args.seeds))
    for name in ARENA_CASES:
        arena_table(name, seeds)
    hard_cases()
    filter_cost()
    simulator_speed()


if __name__ == '__main__':
    main()
