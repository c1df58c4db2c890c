"""The formation against robots with mass, motors and friction (MuJoCo), and the worlds' speed.

Run: scripts/bench physics            (20 random starts of each arena experiment; ~8 min)
     scripts/bench physics --seeds 3  (a quick look)
     scripts/bench physics --part speed

Part `starts`: for each random start (experiment.seeded_start, seeds 1..N) of arena_demo and
mona_arena, the nodes' tick pipeline (core.sim.pipeline) runs in three worlds:
- kinematic: the paper's unicycles with the experiment's disturbance (the reference);
- mujoco: MuJoCo bodies, no imperfection, the experiment's disturbance on the wheel commands,
  the controllers told the motors' time constant (limits.motor_time_constant), as a lab
  measures it (goal: every phase settles, no contact, within 1.15x of kinematic);
- imperfect: MuJoCo bodies with IMPERFECTIONS (each start its own draw of them) and no
  injected disturbance: the observer learns a physical one; the controllers are told the
  motors' dead band and time constant (limits.min_wheel_speed, motor_time_constant), as a lab
  measures them (goal: every phase settles, no contact, within 1.3x of mujoco);
- untold (with --worlds ...,untold): the imperfect robots, nothing told, nothing learnt;
- learnt (with --worlds ...,learnt): the imperfect robots, nothing told, the controllers
  estimating their link's latency and their motors' lag online (controller.estimate_latency,
  estimate_motors; goal: every phase within 1.2x of mujoco, no contact); the estimates
  are reported against the motors' 50 ms;
- checked (with --worlds ...,checked): as learnt, and each robot first turns in place while
  its controller measures its wheel gains and dead band (controller.motor_check), before the
  schedule's t = 0 as the nodes run it (the curve server waits for every controller's check:
  8.2 s from the first pose, not counted); goal: every phase within 1.2x of mujoco, no
  contact. Its estimates 10 s after the first pose (a second run, stopped at t = 2 s):
  wheel gains against the drawn ones (goal 3 %), dead band (20 %), and the motors' lag
  against their first-order part (15 ms).
- noisy_mujoco, noisy_told, noisy_learnt (with --worlds
  noisy_mujoco,noisy_told,noisy_learnt): mujoco, imperfect and learnt with a camera's noise
  on every pose (CAMERA_NOISE: 0.2 mm and 3 mrad), the settling judged on the true poses
  within NOISY_TOLERANCE of the curve's size (at the files' 1e-3, about 1 mm, the noise's
  jitter of nine robots together keeps most starts from settling), told and learnt against
  noisy_mujoco, and each world's steady error (steady_mm, every world): what a
  lab with such a camera gets told everything or learning online (no goal: a measurement).
Part `speed`: seconds of world per second of wall clock, MuJoCo and kinematic worlds alone,
9 robots (mona_arena) and 50 (a 5 m x 5 m arena), every robot driven on its own circle with
commands renewed at 10 Hz (goals: MuJoCo >= 20x for 9, >= 1x for 50).
Writes JSON to --out (default out/bench/physics).
"""

import argparse
import json
from multiprocessing import Pool
from pathlib import Path
import time

import numpy as np
import yaml

from curve_formation.core.config.loading import build_experiment, with_start
from curve_formation.core.config.physics_schema import PhysicsSpec
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.record import metrics
from curve_formation.core.sim.pipeline import Link, simulate_pipeline
from curve_formation.core.world.mujoco_world import draw_robots, SERVO_LAG
from curve_formation.core.world.worlds import make_world
from curve_formation.paths import resolve_config


CASES = ('arena_demo', 'mona_arena')
IMPERFECTIONS = {'wheel_radius_mismatch': 0.03, 'motor_gain_spread': 0.1, 'dead_band': 0.05,
                 'command_bits': 8, 'battery_sag': 0.1}
GOALS = {'mujoco': 1.15, 'imperfect': 1.3, 'untold': 1.3, 'learnt': 1.2, 'checked': 1.2}
CAMERA_NOISE = (0.0002, 0.003)   # m, rad: each pose's noise in the noisy worlds
NOISY_TOLERANCE = 0.003   # metrics.tolerance in the noisy worlds (of the curve's size)
STEADY = 10.0   # s: each phase's last, over which its error's norm is averaged (steady mm)
NOISY = {'noisy_mujoco': 'mujoco', 'noisy_told': 'imperfect',   # and the world each adds it to
         'noisy_learnt': 'learnt'}
WORLDS = ('kinematic', 'mujoco', 'imperfect')


def experiment(name, seed, world):
    """The shipped experiment `name` from random start `seed`, set up for `world`."""
    path = resolve_config(name)
    data = yaml.safe_load(Path(path).read_text())
    if world in NOISY:
        data['metrics'] = {**data.get('metrics', {}), 'tolerance': NOISY_TOLERANCE}
        world = NOISY[world]
    if world != 'kinematic':
        data['physics'] = {'engine': 'mujoco'}
    if world in ('mujoco', 'imperfect'):   # the motors' lag, measured on the robots, told
        data['limits']['motor_time_constant'] = PhysicsSpec().motor_time_constant
    if world in ('imperfect', 'untold', 'learnt', 'checked'):
        data['physics']['imperfections'] = {**IMPERFECTIONS, 'seed': seed}
        data['disturbance'] = {**data.get('disturbance', {}), 'value': [0.0, 0.0]}
        data['disturbance'].pop('per_agent', None)
    if world in ('learnt', 'checked'):   # nothing told: learnt online
        data['controller'].update(estimate_latency=True, estimate_motors=True,
                                  motor_check=world == 'checked')
    if world == 'imperfect':   # and their dead band
        limits = data['limits']
        limits['min_wheel_speed'] = IMPERFECTIONS['dead_band'] * limits['max_wheel_speed']
    case = build_experiment(data, str(path))
    return with_start(case, seeded_start(case, seed))


def early_estimates(case):
    """A checked world's estimates 10 s after the first pose (t = 2 s: the check's 8.2 s
    before t = 0): each robot's wheel gains over the drawn ones less 1, its dead band over
    the drawn one, its motor lag less the motors' first-order part (s; None while none).
    """
    result = simulate_pipeline(case, 'mujoco', duration=2.0)
    data = metrics.result_metrics(result)
    robots = draw_robots(case)
    drawn = robots.wheel_gains
    band = IMPERFECTIONS['dead_band'] * result.limits.max_wheel_speed
    first_order = PhysicsSpec().motor_time_constant - 2.0 * SERVO_LAG
    return {
        'gain_error': [None if g is None else float(np.abs(np.divide(g, d) - 1.0).max())
                       for g, d in zip(data['estimated_wheel_gains'], drawn, strict=True)],
        'dead_band_share': [None if b is None else b / band
                            for b in data['estimated_dead_band']],
        'lag_error': [lag - first_order if lag > 0.0 else None
                      for lag in data['estimated_motor_time_constant']]}


def one_start(job):
    """Every world's run of one (experiment, seed): settle times, contacts, wall time."""
    name, seed, worlds = job
    row = {'case': name, 'seed': seed}
    for world in worlds:
        begin = time.perf_counter()
        case = experiment(name, seed, world)
        link = Link(pose_noise=CAMERA_NOISE, seed=seed) if world in NOISY else Link()
        result = simulate_pipeline(case, 'kinematic' if world == 'kinematic' else 'mujoco',
                                   link=link)
        data = metrics.result_metrics(result)
        if world == 'checked':
            row['checked_at_10_s'] = early_estimates(case)
        row[world] = {'settle': [p['settle_time'] for p in data['phases']],
                      'final_mm': [1000 * p['final_max_agent_error'] for p in data['phases']],
                      'steady_mm': steady_mm(result, len(data['phases'])),
                      'contacts': result.contacts, 'wall_s': time.perf_counter() - begin,
                      'motor_lags': data.get('estimated_motor_time_constant'),
                      'latencies': data.get('estimated_latency'),
                      'dead_band_share': None if not data.get('estimated_dead_band') else [
                          None if v is None else v / (IMPERFECTIONS['dead_band']
                                                      * result.limits.max_wheel_speed)
                          for v in data['estimated_dead_band']]}
    return row


def steady_mm(result, phases):
    """Each phase's error norm over all robots (mm, metrics.error_norm) averaged over its
    last STEADY s: how far the formation stays from still where it has settled (a camera's
    noise keeps it jittering).
    """
    t, phase = np.asarray(result.t), np.asarray(result.phase)
    norm = metrics.error_norm(np.asarray(result.errors))
    out = []
    for k in range(phases):
        inside = phase == k
        last = inside & (t >= t[inside].max() - STEADY) if inside.any() else inside
        out.append(1000 * float(norm[last].mean()) if last.any() else None)
    return out


def ratio(a, b):
    return None if a is None or b is None else a / b


def starts_report(rows):
    out = {}
    for name in CASES:
        case_rows = [r for r in rows if r['case'] == name]
        phases = len(next(v['settle'] for v in case_rows[0].values()
                          if isinstance(v, dict) and 'settle' in v))   # any world run
        print(f"\n{name}: {len(case_rows)} random starts, nodes' tick pipeline")
        print(f'{"phase":>5} {"world":>12} {"settled":>8} {"median s":>9} {"max s":>7} '
              f'{"worst ratio":>12} {"goal":>5} {"contacts":>9} {"worst final mm":>15} '
              f'{"steady mm":>10}')
        summary = {}
        for k in range(phases):
            for world, against in (('kinematic', None), ('mujoco', 'kinematic'),
                                   ('imperfect', 'mujoco'), ('untold', 'mujoco'),
                                   ('learnt', 'mujoco'), ('checked', 'mujoco'),
                                   ('noisy_mujoco', None), ('noisy_told', 'noisy_mujoco'),
                                   ('noisy_learnt', 'noisy_mujoco')):
                if world not in case_rows[0]:
                    continue
                against = against if against in case_rows[0] else None
                times = [r[world]['settle'][k] for r in case_rows]
                done = [t for t in times if t is not None]
                ratios = [ratio(r[world]['settle'][k], r[against]['settle'][k])
                          for r in case_rows] if against else []
                worst = (None if not ratios else
                         float('inf') if None in ratios else max(ratios))
                contacts = sum(int(r[world]['contacts']['count'])
                               + int(r[world]['contacts'].get('walls') or 0) for r in case_rows)
                final = max(r[world]['final_mm'][k] for r in case_rows)
                steady = float(np.median([r[world]['steady_mm'][k] for r in case_rows]))
                goal = GOALS.get(world)
                summary[f'{world}/{k}'] = {'settled': len(done), 'of': len(times),
                                           'median': float(np.median(done)) if done else None,
                                           'max': max(done) if done else None,
                                           'worst_ratio': worst, 'contacts': contacts,
                                           'worst_final_mm': final,
                                           'median_steady_mm': steady}
                print(f'{k:>5} {world:>12} {len(done):>4}/{len(times):<3} '
                      f'{np.median(done) if done else float("nan"):9.1f} '
                      f'{max(done) if done else float("nan"):7.1f} '
                      f'{"" if worst is None else f"{worst:.2f}x":>12} '
                      f'{"" if goal is None else f"{goal}x":>5} {contacts:>9} {final:15.2f} '
                      f'{steady:10.2f}')
        for world in ('learnt', 'noisy_learnt'):
            lags = [1000 * v for r in case_rows if r.get(world, {}).get('motor_lags')
                    for v in r[world]['motor_lags']]
            if lags:
                summary[f'{world}_motor_lag_ms'] = {
                    'min': min(lags), 'median': float(np.median(lags)), 'max': max(lags)}
                print(f"{world} motor lags (ms, the motors' 50): min {min(lags):.1f}, median "
                      f'{np.median(lags):.1f}, max {max(lags):.1f} over {len(lags)} robots')
        for world in ('learnt', 'checked', 'noisy_learnt'):
            shares = [v for r in case_rows if r.get(world, {}).get('dead_band_share')
                      for v in r[world]['dead_band_share']]
            taken = [v for v in shares if v is not None]
            if not shares:
                continue
            band = summary[f'{world}_dead_band_share'] = {
                'robots': len(shares), 'taken': len(taken),
                'within_20_percent': sum(abs(v - 1.0) <= 0.2 for v in taken),
                'min': min(taken, default=None), 'max': max(taken, default=None)}
            print(f'{world} dead bands: taken by {len(taken)} of {len(shares)} robots, '
                  f'{band["within_20_percent"]} within 20 % of the drawn band'
                  + (f' ({min(taken):.2f}x to {max(taken):.2f}x)' if taken else ''))
        early = [r['checked_at_10_s'] for r in case_rows if 'checked_at_10_s' in r]
        if early:
            summary['checked_at_10_s'] = early_report(early)
        out[name] = summary
    return out


def early_report(early):
    """The checked world's estimates 10 s after the first pose, over every robot of every
    start: how many are within the goals, and the worst.
    """
    out = {}
    for key, aim, goal, unit, scale in (('gain_error', 0.0, 0.03, '%', 100.0),
                                        ('dead_band_share', 1.0, 0.2, 'x', 1.0),
                                        ('lag_error', 0.0, 0.015, 'ms', 1000.0)):
        values = [v for row in early for v in row[key]]
        taken = [v for v in values if v is not None]
        off = [abs(v - aim) for v in taken]
        within = sum(v <= goal + 1e-12 for v in off)
        out[key] = {'robots': len(values), 'taken': len(taken), 'within_goal': within,
                    'worst': max(off, default=None)}
        worst = '' if not off else f', worst {scale * max(off):.1f} {unit} off'
        print(f'checked at 10 s, {key}: {within} of {len(values)} robots within '
              f'{scale * goal:g} {unit} ({len(taken)} taken{worst})')
    return out


def circling(n, size):
    """An experiment of n robots on a grid in a size x size m arena, for the speed part."""
    side = int(np.ceil(np.sqrt(n)))
    pitch = size / side
    poses = [[pitch * (0.5 + k % side), pitch * (0.5 + k // side), 0.0] for k in range(n)]
    return build_experiment({
        'name': f'circling_{n}', 'agents': {'count': n, 'initial': {'poses': poses}},
        'graph': {'edges': [{'from': i, 'to': i + 1} for i in range(1, n)]},
        'controller': {'law': 'observer', 'k1': 0.5, 'k2': 0.5, 'offset': 0.01,
                       'rate_hz': 10.0},
        'limits': {'wheel_base': 0.08, 'max_wheel_speed': 0.0225},
        'arena': {'size': [size, size]}, 'robots': {'radius': 0.04},
        'physics': {'engine': 'mujoco'},
        'curves': [{'basis': 'fourier', 'harmonics': max(1, n // 2), 'samples': 3 * n + 400,
                    'x': f'{size / 2} + {size / 3} * cos(2*pi*s)',
                    'y': f'{size / 2} + {size / 3} * sin(2*pi*s)'}],
        'simulation': {'duration': 10.0}}, f'<circling {n}>')


def world_speed(case, engine, seconds, repeats=3):
    """Seconds of world per wall-clock second, robots circling at 2 cm/s: the best of
    `repeats` runs (what the machine does when nothing else runs on it).
    """
    best = 0.0
    for _ in range(repeats):
        world = make_world(case, engine)
        world.advance(0.0)
        begin = time.perf_counter()
        t = 0.0
        while t < seconds:
            for i in range(case.n):
                world.command(i, 0.02, 0.25, t)
            t += 0.1
            world.advance(t)
        best = max(best, seconds / (time.perf_counter() - begin))
    return best, world.contact_summary()


def speed_report(seconds):
    out = {}
    print(f'\nworld speed (robots circling, commands at 10 Hz, {seconds:g} s of world, '
          'best of 3)')
    print(f'{"robots":>6} {"engine":>10} {"x real time":>12} {"goal":>6}')
    for n, size, goal in ((9, 1.8, 20.0), (50, 5.0, 1.0)):
        case = circling(n, size)
        for engine in ('mujoco', 'kinematic'):
            speed, contacts = world_speed(case, engine, seconds)
            out[f'{n}/{engine}'] = {'x_real_time': speed, 'contacts': contacts}
            print(f'{n:>6} {engine:>10} {speed:12.1f} '
                  f'{f"{goal:g}x" if engine == "mujoco" else "":>6}')
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--part', choices=('starts', 'speed', 'all'), default='all')
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--worlds', default=','.join(WORLDS),
                        help='comma-separated, of kinematic, mujoco, imperfect, untold, learnt '
                        '(default %(default)s; the ratios need kinematic and mujoco)')
    parser.add_argument('--out', default='out/bench/physics')
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    if args.part in ('speed', 'all'):
        results['speed'] = speed_report(30.0)
    if args.part in ('starts', 'all'):
        worlds = tuple(args.worlds.split(','))
        jobs = [(name, seed, worlds) for name in CASES for seed in range(1, args.seeds + 1)]
        with Pool(args.workers) as pool:
            rows = pool.map(one_start, jobs, chunksize=1)
        results['runs'] = rows
        (out / 'physics.json').write_text(json.dumps(results, indent=2, default=float))
        results['starts'] = starts_report(rows)
    (out / 'physics.json').write_text(json.dumps(results, indent=2, default=float))
    print(f'\nwrote {out / "physics.json"}')


if __name__ == '__main__':
    main()
