"""A batch run's online estimates of the latency and the motors' lag
(controller.estimate_latency, estimate_motors), replayed.

The batch simulator's commands act the latency told (controller.command_latency) after they
are sent, throughout. Each controller's OnlineLink is
replayed over the run on the commands it sent at its ticks and its poses there: while none
takes a value the run is exactly what estimating controllers do (they use command_latency
until they take one), and their latencies are reported; if one would have taken a value
the run is not theirs, and EstimateTakenError says which robot and when, so that the caller
runs the nodes' tick pipeline instead (pipeline.simulate_kinematic). Times in s.
"""

import numpy as np

from curve_formation.core.base.shapes import FloatArray, IntArray
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.experiment import Experiment
from curve_formation.core.controller.link_estimate import replay_online


KEY = 'controller.estimate_latency'


class EstimateTakenError(ConfigError):
    """An online latency estimate that a batch run shows would have been taken: the run is
    not what the estimating controllers would do.
    """


def check_replayable(experiment: Experiment, control_every: int, record_every: int,
                     dt: float) -> None:
    """ConfigError unless held_estimates can replay the estimate from the batch simulator's
    record (a tick every control_every fine steps of dt s, a record every record_every): a
    control rate, and records at least as frequent as the ticks.
    """
    if control_every == 0:
        raise ConfigError(experiment.source, KEY, 'needs a control rate: continuous control '
                          'sends no commands to time')
    if record_every > control_every:
        raise ConfigError(experiment.source, KEY, f'the batch simulator replays the estimate '
                          f'from its record: simulation.record_dt ({record_every * dt:g} s) '
                          f'must not exceed the control period ({control_every * dt:g} s)')


def _tick_records(tick_offsets: IntArray, start_steps: IntArray, control_every: int,
                  record_every: int, n_rec: int) -> list[tuple[IntArray, IntArray]]:
    """Per agent, its ticks' fine steps and the record at or after each, which holds the
    tick's command (held until the next tick, which no record before it can show: the
    records are at least as frequent as the ticks, check_replayable).
    """
    out = []
    last = (n_rec - 1) * record_every
    for offset, start in zip(tick_offsets, start_steps, strict=True):
        first = int(offset) + max(0, -(-(int(start) - int(offset)) // control_every)) \
            * control_every
        steps = np.arange(first, last + 1, control_every, dtype=np.int64)
        out.append((steps, -(-steps // record_every)))
    return out


def held_estimates(experiment: Experiment, rate_hz: float, clock: tuple[float, int, int],
                   t: FloatArray, poses: FloatArray, commands: FloatArray,
                   schedule: tuple[IntArray, IntArray]) -> list[float]:
    """Each controller's latency over a batch run, its estimator replayed (module doc):
    clock (dt s, control_every, record_every) as the simulator steps; t (R,) s, poses
    (R, n, 3) and commands (R, n, 2) as recorded; schedule: the ticks' (tick_offsets,
    start_steps) as the simulator's _run takes them. EstimateTakenError if an estimate would
    have been taken; else returns each controller's (unchanged) latency.
    """
    dt, control_every, record_every = clock
    controller = experiment.spec.controller
    initial = controller.command_latency
    latencies = []
    for i, (steps, rows) in enumerate(_tick_records(*schedule, control_every, record_every,
                                                    len(t))):
        keep = rows < len(t)
        steps, rows = steps[keep], rows[keep]
        online = replay_online(steps * dt, commands[rows, i], t[rows], poses[rows, i],
                               initial, rate_hz, 0.0, controller.estimate_latency,
                               controller.estimate_motors)
        if online.motor_taken:   # the batch simulator's robots have no motors
            when, value = online.motor_taken[0]
            raise EstimateTakenError(
                experiment.source, 'controller.estimate_motors', f'robot {i + 1} would have '
                f"taken a motor lag of {1000 * value:.0f} ms at {when:.1f} s, where the batch "
                "simulator's robots have no motors: simulate it with "
                'core.sim.pipeline.simulate_pipeline (as sim does)')
        if online.taken:
            when, value = online.taken[0]
            raise EstimateTakenError(
                experiment.source, KEY, f'robot {i + 1} would have taken an estimate of '
                f"{1000 * value:.0f} ms at {when:.1f} s, where the batch simulator's commands "
                'keep the latency told: simulate it with '
                'core.sim.pipeline.simulate_pipeline (as sim does)')
        latencies.append(online.latency)
    return latencies
