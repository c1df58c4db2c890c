"""What the paper proves, checked along simulated trajectories; and what it does not show."""

import dataclasses
import os
import re

import numpy as np
import pytest
from scipy.linalg import expm

from conftest import DATA_DIR, ROOT
from curve_formation.core.config.experiment import point_robots
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.controller.limits import NO_LIMITS
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


CASES = ['closed_curve', 'open_curve', 'shape_change', 'mona_arena']


@pytest.fixture(scope='module', params=CASES)
def case(request):
    """The paper's cases with the formation law alone (point robots: the law's proofs)."""
    return point_robots(load_experiment(resolve_config(request.param)))


LAWS = {
    'paper': lambda g: g.paper_law(),
    'adaptive': lambda g: dataclasses.replace(g.paper_law(), law='adaptive',
                                              adaptation=(3.0, 1.0 / g.offset ** 2)),
    'observer': lambda g: dataclasses.replace(g, law='observer'),
}


@pytest.mark.parametrize('law', LAWS)
def test_lyapunov_never_increases_along_continuous_trajectories(case, law):
    """V' <= 0 for each law's V (docs/control-laws.md): continuous law, no wheel limits.

    paper: V' = -k1 xe^T (Q kron I2) xe (Proposition 1); adaptive: the same V with the
    estimate weighted by Gamma^-1; observer: the cascade function W.
    """
    result = simulate(case, rate_hz=None, limits=NO_LIMITS, duration=min(
        30.0, case.spec.simulation.duration), gains=LAWS[law](case.gains))
    v = result.lyapunov
    for k in range(len(case.phases)):
        window = v[result.phase == k]
        if len(window) < 2:
            continue
        rises = np.diff(window)
        # RK4 at dt = 1 ms: anything beyond round-off would be a violation.
        assert rises.max() <= 1e-9 * window[0], (case.name, rises.max())
        assert window[-1] < window[0]


def test_without_disturbance_error_decays_as_the_closed_form(case):
    """d = 0, k2 = 0, the paper's linear law (no finite-time tail): the offset point is a
    single integrator, e(t) = exp(-k1 (L+B) t) e0.

    Checked tightly at dt = 0.1 ms; at the shipped dt = 1 ms the substepped RK4 stays within
    1e-3 of the initial error while the heading turns at up to k1 |e| / l.
    """
    k1 = case.gains.k1
    kw = dict(rate_hz=None, limits=NO_LIMITS, disturbance=[0.0, 0.0],
              gains=dataclasses.replace(case.gains, k2=0.0, tail_radius=0.0))
    m = case.graph.feedback_matrix
    for dt, duration, rtol in ((1e-4, 3.0, 1e-7), (1e-3, 20.0, 1e-3)):
        result = simulate(case, dt=dt, duration=duration, **kw)
        e0 = result.errors[0]
        for k in range(0, len(result.t), 17):
            expected = expm(-k1 * m * result.t[k]) @ e0
            np.testing.assert_allclose(result.errors[k], expected,
                                       atol=rtol * np.abs(e0).max())
    # Exponential convergence at the rate of the slowest mode of k1 (L + B).
    rate = k1 * np.linalg.eigvals(m).real.min()
    late = result.t > duration / 2
    slope = np.polyfit(result.t[late], np.log(result.error_norm[late]), 1)[0]
    assert slope == pytest.approx(-rate, rel=0.1)


def test_error_jumps_at_a_curve_switch():
    case = load_experiment(resolve_config('shape_change'))
    result = simulate(case, rate_hz=None, disturbance=[0, 0], gains=dataclasses.replace(
        case.gains, k2=0.0), duration=80.0)
    norm = result.error_norm
    before = norm[np.searchsorted(result.t, 75.0) - 1]
    after = norm[np.searchsorted(result.t, 75.0)]
    assert before < 1e-3 * case.phases[0].curve.size()
    assert after > 1000 * before
    assert after > 30.0   # the second curve is centred 36 away from the first


def test_a_switch_between_steps_takes_effect_at_the_next_step_not_before():
    """A recorded run's switch time (analyze --compare-sim) falls between simulation steps:
    at 6.000107 s the sample at 6.00 s must still be on the first curve, which the robots
    have reached (it was labelled with the second curve's targets, so the first phase never
    settled: seen once in a test run).
    """
    case = load_experiment(DATA_DIR / 'nearest_switch.yaml')
    switch = 6.000107
    phases = (case.phases[0], dataclasses.replace(case.phases[1], start=switch))
    result = simulate(dataclasses.replace(case, phases=phases))
    assert np.all((result.phase == 1) == (result.t >= switch))
    data = metrics.result_metrics(result)
    assert [p['settled'] for p in data['phases']] == [True, True], data['phases']


def test_paper_settings_stall_with_agents_circling():
    """Reference behaviour of the paper's law (paper-notes.md): reproduced, not hidden."""
    case = load_experiment(resolve_config('closed_curve'))
    result = simulate(case, rate_hz=None, duration=60.0, gains=case.gains.paper_law())
    data = metrics.result_metrics(result)
    assert not data['all_settled']
    norm = result.error_norm
    assert norm[np.searchsorted(result.t, 5.0)] < 0.15 * norm[0]   # fast approach ...
    assert 0.1 < data['final_error_norm'] < 1.0                    # ... then a stall
    assert data['final_orientation_rates_max'] > 0.1                # robots keep turning
    v = result.lyapunov
    assert np.all(np.diff(v) <= 1e-9 * v[0])                         # while V still decreases


def test_zero_order_hold_at_10hz_needs_a_bounded_turn_rate():
    """At 10 Hz with l = 0.01 the unbounded law turns too far between ticks and never gets
    anywhere (measured: ||e|| 25.6 -> 19 after 60 s); bounding |w| to 10 rad/s converges.
    """
    case = load_experiment(resolve_config('closed_curve'))
    kw = dict(rate_hz=10.0, disturbance=[0, 0], gains=dataclasses.replace(
        case.gains.paper_law(), k2=0.0), duration=60.0)
    free = simulate(case, limits=NO_LIMITS, **kw).error_norm
    assert not np.isfinite(free[-1]) or free[-1] > 0.5 * free[0]
    bounded = simulate(case, limits=NO_LIMITS._replace(max_angular_rate=10.0),
                       **kw).error_norm
    assert bounded[-1] < 1e-3 * bounded[0]


def test_zero_order_hold_converges_to_continuous_as_the_rate_grows():
    case = load_experiment(resolve_config('open_curve'))
    kw = dict(disturbance=[0, 0], gains=dataclasses.replace(case.gains, offset=0.3, k2=0.0),
              duration=5.0, limits=NO_LIMITS)
    cont = simulate(case, rate_hz=None, **kw).poses
    gaps = [np.abs(simulate(case, rate_hz=r, **kw).poses - cont).max() for r in (50, 200, 1000)]
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[2] < 0.05   # first order in the control period: 0.96, 0.14, 0.025 measured


def test_records_are_consistent():
    case = load_experiment(resolve_config('mona_arena'))
    result = simulate(case, duration=2.0)
    assert result.poses.shape == (200, 9, 3)
    np.testing.assert_allclose(result.poses[0], case.initial_poses)
    # Commands sent to the robots respect the configured wheel limits.
    wheel = np.abs(result.commands[..., 0]) + 0.5 * case.limits.wheel_base * np.abs(
        result.commands[..., 1])
    assert wheel.max() <= case.limits.max_wheel_speed * (1 + 1e-9)


def test_metrics_use_the_settings_the_run_used():
    """Overriding l must move the measured offset point too (it once used the file's l)."""
    case = load_experiment(resolve_config('closed_curve'))
    result = simulate(case, rate_hz=None, disturbance=[0, 0], limits=NO_LIMITS, duration=30.0,
                      gains=dataclasses.replace(case.gains, offset=0.5, k2=0.0))
    assert result.error_norm[-1] < 1e-4 * result.error_norm[0]
    data = metrics.result_metrics(result)
    assert data['all_settled'] and data['final_error_norm'] < 1e-3


def test_every_module_compiled_into_the_simulator_is_watched_for_changes():
    """A core module whose functions the kernels compile in must be among the SOURCES whose
    change drops numba's cache (else an edit of it would leave the old code running).
    """
    from curve_formation.core.base import jit  # noqa: F401 (compiles its kernels)
    compiled_in = {function.__module__.split('.core.', 1)[1].replace('.', '/') + '.py'
                   for function in jit._COMPILED}
    assert 'controller/driving.py' in compiled_in
    assert compiled_in <= set(jit.SOURCES)


def test_compiled_cache_is_dropped_when_a_law_source_changes(tmp_path):
    """numba would keep running a stepping loop compiled from an older control.py."""
    import shutil

    from curve_formation.core.base import jit
    for name in jit.SOURCES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(jit.CORE / name, tmp_path / name)
    cache = jit.cache_folder(tmp_path / 'sim')   # NUMBA_CACHE_DIR's, as bootstrap.sh sets it
    cache.mkdir(parents=True)
    (cache / 'simulator._run-1.py311.nbi').write_text('compiled')
    assert jit.drop_stale_cache(tmp_path)            # no record of the sources yet
    assert not list(cache.glob('*.nbi'))
    (cache / 'simulator._run-1.py311.nbi').write_text('compiled')
    assert not jit.drop_stale_cache(tmp_path)        # unchanged: the cache stays
    with open(tmp_path / 'controller' / 'law.py', 'a') as f:
        f.write('# edited\n')
    assert jit.drop_stale_cache(tmp_path)
    assert not list(cache.glob('*.nbi'))
    shutil.rmtree(cache)


_COMPILE_ONE = """
from curve_formation.core.config.agents import agent_configs
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.controller.agent import compiled_step
step = compiled_step(agent_configs(load_experiment('config/mona_arena.yaml'), 10.0)[1])
print(sum(step.stats.cache_misses.values()), sum(step.stats.cache_hits.values()))
"""


def test_controller_processes_starting_together_on_a_cold_cache_compile_once(tmp_path):
    """A grouped team's processes all compile the controllers' law at start: on a fresh
    install each used to compile it at once (a hundred robots' twelve processes took minutes
    on two cores and the run timed out). One compiles; the others load its cache.
    """
    import subprocess
    import sys

    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path)}
    processes = [subprocess.Popen([sys.executable, '-c', _COMPILE_ONE], env=env, text=True,
                                  stdout=subprocess.PIPE, cwd=ROOT)
                 for _ in range(3)]
    counts = sorted(tuple(map(int, p.communicate(timeout=300)[0].split()))
                    for p in processes)
    assert [p.returncode for p in processes] == [0, 0, 0]
    compiled = [misses for misses, _ in counts]
    assert compiled == [0, 0, 1], counts   # one compiled, two loaded what it cached
    assert all(hits == 1 for misses, hits in counts if misses == 0), counts


def test_the_simulator_keeps_the_acceleration_limits_as_the_node_does():
    """The one tick pipeline (control.agent_command) ramps each command from the previous
    one in the simulator too: at 10 Hz under limits of 0.5 m/s^2 and 2 rad/s^2 no command
    changes by more than 0.05 m/s or 0.2 rad/s from one tick to the next, where without them
    the law's commands jump by far more (case 1, no wheel limits).
    """
    case = point_robots(load_experiment(resolve_config('closed_curve')))
    ramped = NO_LIMITS._replace(max_linear_accel=0.5, max_angular_accel=2.0)
    steps = {}
    for label, limits in (('free', NO_LIMITS), ('ramped', ramped)):
        result = simulate(case, rate_hz=10.0, duration=5.0, limits=limits)
        steps[label] = np.abs(np.diff(result.commands, axis=0)).max(axis=(0, 1))
    assert np.all(steps['ramped'] <= np.array([0.05, 0.2]) + 1e-12), steps
    assert np.all(steps['free'] > 4 * np.array([0.05, 0.2])), steps


@pytest.mark.parametrize('key', ['min_wheel_speed', 'motor_time_constant'])
def test_the_batch_simulator_refuses_settings_of_motors_it_does_not_have(key):
    """Told of real motors (a dead band, a lag), the controller expects what its unicycles
    do not do: the batch simulator names the setting and where to simulate it instead.
    """
    import yaml

    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import build_experiment
    data = yaml.safe_load(open('config/arena_demo.yaml'))
    data['limits'][key] = 0.001
    experiment = build_experiment(data, 'arena_demo.yaml')
    with pytest.raises(ConfigError, match=f'limits.{key}.*--physics mujoco'):
        simulate(experiment, duration=1.0)


def test_the_batch_simulator_refuses_a_command_latency_under_continuous_control():
    """Commands that act late are sent at ticks: under continuous control the batch
    simulator names the setting and asks for a control rate.
    """
    import yaml

    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import build_experiment
    data = yaml.safe_load(open('config/arena_demo.yaml'))
    data['controller'].update(command_latency=0.1, estimate_latency=False)
    experiment = build_experiment(data, 'arena_demo.yaml')
    with pytest.raises(ConfigError, match='controller.command_latency.*control rate'):
        simulate(experiment, rate_hz=None, duration=1.0)


def test_the_batch_simulators_commands_act_the_latency_told_after_they_are_sent():
    """A robot moves by the command sent `command_latency` before (the world's link), not by
    the one just sent: over its first 0.3 s nobody moves, then every robot does.
    """
    import yaml

    from curve_formation.core.config.loading import build_experiment
    data = yaml.safe_load(open('config/arena_demo.yaml'))
    data['controller'].update(command_latency=0.3, estimate_latency=False)
    result = simulate(build_experiment(data, 'arena_demo.yaml'), duration=1.0)
    moved = np.abs(result.poses - result.poses[0]).max(axis=2)   # (R, n)
    assert np.abs(result.commands[result.t < 0.3]).max() > 0.0   # sent from the first tick
    assert moved[result.t <= 0.3].max() < 1e-12
    assert (moved[-1] > 1e-4).all(), moved[-1]


def test_the_batch_simulator_replays_each_controllers_online_latency_estimate():
    """The arena files estimate their link's latency online (controller.estimate_latency).
    The batch simulator's commands keep the latency told: it replays each controller's
    estimate over the run and reports it (0: none taken, so the run is what estimating
    controllers do), as the nodes' pipeline with its live estimates ends; under continuous
    control, with no commands to time, it refuses the setting by name.
    """
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.sim.pipeline import simulate_pipeline
    experiment = load_experiment(resolve_config('arena_demo'))
    assert experiment.spec.controller.estimate_latency
    assert simulate(experiment, duration=30.0).latencies == [0.0] * experiment.n
    assert simulate_pipeline(experiment, duration=30.0).latencies == [0.0] * experiment.n
    with pytest.raises(ConfigError, match='controller.estimate_latency: needs a control rate'):
        simulate(experiment, rate_hz=None, duration=1.0)


@pytest.mark.parametrize('latency', [0.0, 0.1])
def test_a_batch_run_whose_commands_would_show_a_latency_is_refused_by_name(latency):
    """held_estimates on one robot's record (100 Hz, ticks at 10 Hz) whose commands act
    `latency` s late: a controller estimating online would take ~100 ms, which the batch
    simulator's robots (acting at once) cannot show, so it says which robot and when, and
    the first value it would have taken is within 20 ms of the truth.
    """
    from test_link_estimate import driven_robot

    from curve_formation.core.sim.estimate_replay import EstimateTakenError, held_estimates
    experiment = load_experiment(resolve_config('arena_demo'))
    sent, commands, seen, poses = driven_robot(latency, camera=100.0)
    held = np.repeat(commands, 10, axis=0)[:len(seen)]
    schedule = (np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64))
    args = (experiment, 10.0, (0.001, 100, 10), seen, poses[:, None, :],
            held[:, None, :], schedule)
    if latency == 0.0:
        assert held_estimates(*args) == [0.0]
    else:
        with pytest.raises(EstimateTakenError,
                           match=r'estimate_latency: robot 1 would have taken an estimate '
                                 r'of \d+ ms') as refused:
            held_estimates(*args)
        taken = int(re.search(r'estimate of (\d+) ms', str(refused.value)).group(1))
        assert abs(taken - 100) <= 20, taken
