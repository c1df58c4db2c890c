"""The ROS graph's tick pipeline without ROS: what the nodes do, in one process, in time order.

One agent.AgentController per robot, as each formation_controller node runs it; the curve
schedule the curve server steps (core.schedule.curve_schedule: each phase at its start, a moving
curve
renewed at MOVING_RATE, targets re-assigned every agents.reassign_every from the robots' poses);
poses sampled from the world at the camera's rate and handed to every controller, each
controller's state passed on to its out-neighbours when its pose comes (as the node
publishes it); every controller ticking at the control rate at its own phase of the period
(unsynchronised nodes), its command handed to the world. The world is a worlds.World: the
paper's unicycles or MuJoCo bodies.

Everything happens at exact event times on one clock (s), in this order at equal times:
curves, poses, ticks, records. A Link delays, jitters and loses commands on their way to the
robots and poses on their way to the controllers (the camera and Wi-Fi a lab has); the
default link delivers everything at once. The graph's own messages (curves, neighbours'
states) arrive the instant they are sent. With controller.motor_check the schedule starts
once every controller can have checked its motors (as the curve server waits for their
ready reports): poses and ticks run that long before its t = 0.
"""

import dataclasses
from dataclasses import dataclass
import heapq
import math
from typing import Literal

import numpy as np

from curve_formation.core.base.shapes import BoolArray, FloatArray
from curve_formation.core.config.agents import agent_configs
from curve_formation.core.config.experiment import (
    ANNOUNCE_AHEAD,
    Experiment,
    Phase,
    phase_index,
)
from curve_formation.core.config.experiment import pose_rate as experiment_pose_rate
from curve_formation.core.config.loading import control_rate
from curve_formation.core.controller.agent import AgentController
from curve_formation.core.controller.motor_probe import CHECK_SECONDS
from curve_formation.core.formation import dynamics
from curve_formation.core.schedule.curve_schedule import CurveSchedule, Publication
from curve_formation.core.sim.batch import SimResult, simulate
from curve_formation.core.sim.estimate_replay import EstimateTakenError
from curve_formation.core.world.worlds import make_world, World


# How often (Hz) the curve server renews a moving curve (its moving_rate_hz default).
MOVING_RATE = 10.0
# Event kinds, in their order at equal times.
CURVE, REASSIGN, POSE, TICK, RECORD = range(5)


@dataclass(frozen=True)
class Link:
    """What lies between the PC and the robots: each command reaches its robot
    command_latency (s) plus a uniform jitter of +-command_jitter (s) after it was sent (never
    before the one sent before it: the newest wins), or is lost (command_loss, a
    probability); each pose reaches its controller pose_latency (s) after it was taken, or is
    lost (pose_loss), off the truth by Gaussian noise of pose_noise standard deviations (m in
    x and y, rad in heading; a camera's). seed: the draws.
    """

    command_latency: float = 0.0
    command_jitter: float = 0.0
    command_loss: float = 0.0
    pose_latency: float = 0.0
    pose_loss: float = 0.0
    pose_noise: tuple[float, float] = (0.0, 0.0)
    seed: int = 0


def _times(period: float, offset: float, end: float) -> list[float]:
    """offset, offset + period, ... below end (s)."""
    count = int(math.floor((end - offset) / period - 1e-9)) + 1
    return [offset + k * period for k in range(max(count, 0))]


class Pipeline:
    """The controllers, the curve schedule and the world of one run (see the module)."""

    def __init__(self, experiment: Experiment, world: World, rate_hz: float,
                 tick_phases: FloatArray, pose_rate: float, link: Link = Link(),
                 origin: float = 0.0) -> None:
        self.experiment = experiment
        self.origin = origin   # s: the schedule's t = 0 on the pipeline's clock (preflight)
        self.link = link
        self.rng = np.random.default_rng(link.seed)
        self.due = np.full(experiment.n, -math.inf)   # each robot's last command's arrival
        self.in_flight: dict[int, tuple[float, FloatArray, BoolArray]] = {}   # poses
        self.sent_poses = 0
        self.world = world
        n = experiment.n
        self.controllers = [AgentController(dataclasses.replace(config, compiled=True))
                            for config in agent_configs(experiment, rate_hz)]
        self.out_neighbours: list[list[int]] = [[] for _ in range(n)]
        for i, controller in enumerate(self.controllers):
            for j, _ in controller.config.neighbours:
                self.out_neighbours[j - 1].append(i)
        self.avoidance = experiment.avoidance.on
        self.rate_hz = rate_hz
        self.tick_phases = tick_phases
        self.pose_rate = pose_rate
        self.commands = np.zeros((n, 2))
        self.schedule = CurveSchedule(experiment)
        self.schedule.begin(origin)
        self.followed: tuple[Phase, ...] = ()   # the phases as followed, once run

    def publish_due(self, now: float) -> None:
        """The curve server's scheduled curves due by `now` (s), a curve that only begins to
        move ANNOUNCE_AHEAD before its start (core.schedule.curve_schedule), each assigned
        by the robots' top speeds as their controllers know them then (the topic they
        publish them on has no delay here).
        """
        self.schedule.robots_now(self._points(),
                                 np.array([c.robot.top_speed for c in self.controllers]))
        for publication in self.schedule.due(now):
            self._hand_out(now, publication)

    def renew(self, now: float) -> None:
        """A moving curve published where it is now, with its rate (same id)."""
        publication = self.schedule.renewal(now)
        if publication is not None:
            self._hand_out(now, publication)

    def reassign(self, now: float) -> None:
        """The curve server's re-assignment from the robots' poses (same id)."""
        publication = self.schedule.reassign(self._points(), now)
        if publication is not None:
            self._hand_out(now, publication)

    def _points(self) -> FloatArray:
        """The robots' control points now (n, 2; m, arena frame), as the curve server has
        them from /formation/robot_poses.
        """
        return dynamics.offset_points(self.world.poses(), self.experiment.gains.offset)

    def _hand_out(self, now: float, publication: Publication) -> None:
        """A curve message reaches every controller at `now` (s)."""
        for controller in self.controllers:
            controller.set_curve(publication.curve, publication.curve_id, publication.s,
                                 publication.rate, received=now,
                                 valid_at=publication.clock.valid_at)

    def poses_taken(self, now: float) -> list[tuple[float, int, int]]:
        """Every robot's pose taken at `now`: delivered at once, or (with the link's pose
        latency) the event of its delivery, to be scheduled.
        """
        poses = self.world.poses().copy()
        arrives = self.rng.random(len(poses)) >= self.link.pose_loss
        if any(self.link.pose_noise):
            xy, heading = self.link.pose_noise
            poses += self.rng.normal(size=poses.shape) * (xy, xy, heading)
        if self.link.pose_latency <= 0.0:
            self.deliver_poses(now, poses, arrives, now)
            return []
        key = self.sent_poses = self.sent_poses + 1
        self.in_flight[key] = (now, poses, arrives)
        return [(now + self.link.pose_latency, POSE, key)]

    def deliver_poses(self, stamp: float, poses: FloatArray, arrives: BoolArray,
                      now: float) -> None:
        """Poses taken at `stamp` reach the controllers at `now`, those that arrive; each
        controller then passes its state on to its out-neighbours (as the node does).
        """
        for i, controller in enumerate(self.controllers):
            if not arrives[i]:
                continue
            x, y, theta = poses[i]
            if self.avoidance:
                controller.on_others(poses, stamp, now)
            if not controller.on_pose(float(x), float(y), float(theta), stamp, now):
                continue
            state = controller.state()
            if state is None:
                continue
            for k in self.out_neighbours[i]:
                self.controllers[k].on_neighbour(i + 1, *state.error, state.curve_id,
                                                 state.stamp, state.leader_age, now)

    def tick(self, i: int, now: float) -> None:
        experiment = self.experiment
        if experiment.variations:   # held over the control period, as the batch simulator
            d = experiment.disturbance_at(now - self.origin)[i]
            if experiment.spec.disturbance.injected == 'on_pc':
                self.controllers[i].pc_disturbance = (float(d[0]), float(d[1]))
            else:
                self.world.disturb(i, d)
        tick = self.controllers[i].tick(now)
        self.commands[i] = tick.v, tick.w
        link = self.link
        if link.command_loss and self.rng.random() < link.command_loss:
            return
        delay = link.command_latency
        if link.command_jitter:
            delay += self.rng.uniform(-link.command_jitter, link.command_jitter)
        self.due[i] = max(now + max(delay, 0.0), self.due[i])
        self.world.command(i, tick.v, tick.w, float(self.due[i]))

    def run(self, duration: float, record_dt: float, reassign_every: float | None
            ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Run to `duration` (s) after the schedule's start, `origin` s on the pipeline's
        clock (poses and ticks before it: the motor check); (t, poses, dhat, commands)
        recorded every record_dt from the schedule's start (t from 0).
        """
        events: list[tuple[float, int, int]] = []
        for index, phase in enumerate(self.experiment.phases):
            if phase.start < duration:
                events.append((phase.start, CURVE, index))
            if phase.motion is not None and index > 0 and phase.start < duration:
                events.append((phase.start - ANNOUNCE_AHEAD, CURVE, index))   # if announced
            if phase.motion is not None:
                end = (self.experiment.phases[index + 1].start
                       if index + 1 < len(self.experiment.phases) else duration)
                events += [(t, CURVE, -1) for t in
                           _times(1.0 / MOVING_RATE, phase.start + 1.0 / MOVING_RATE,
                                  min(end, duration))]
        if reassign_every:
            events += [(t, REASSIGN, 0) for t in _times(reassign_every, reassign_every,
                                                           duration)]
        records = _times(record_dt, 0.0, duration)
        events += [(t, RECORD, k) for k, t in enumerate(records)]
        origin, end = self.origin, self.origin + duration
        events = [(t + origin, kind, index) for t, kind, index in events]
        events += [(t, POSE, -1) for t in _times(1.0 / self.pose_rate, 0.0, end)]
        period = 1.0 / self.rate_hz
        for i, phase in enumerate(self.tick_phases):
            events += [(t, TICK, i) for t in _times(period, float(phase) * period, end)]
        heapq.heapify(events)
        n = self.experiment.n
        rec_poses = np.zeros((len(records), n, 3))
        rec_dhat = np.zeros((len(records), n, 2))
        rec_cmd = np.zeros((len(records), n, 2))
        while events:
            now, kind, index = heapq.heappop(events)
            self.world.advance(now)
            if kind == CURVE:
                self.publish_due(now) if index >= 0 else self.renew(now)
            elif kind == REASSIGN:
                self.reassign(now)
            elif kind == POSE and index < 0:
                for event in self.poses_taken(now):
                    heapq.heappush(events, event)
            elif kind == POSE:
                self.deliver_poses(*self.in_flight.pop(index), now)
            elif kind == TICK:
                self.tick(index, now)
            else:
                rec_poses[index] = self.world.poses()
                rec_dhat[index] = [c.dhat for c in self.controllers]
                rec_cmd[index] = self.commands
        self.followed = self.schedule.close()
        return np.asarray(records), rec_poses, rec_dhat, rec_cmd


def simulate_pipeline(experiment: Experiment, engine: Literal['kinematic', 'mujoco'] | None
                      = None, rate_hz: float | None = None, duration: float | None = None,
                      record_dt: float | None = None, seed: int = 0,
                      pose_rate: float | None = None, link: Link | None = None,
                      synchronous: bool = False) -> SimResult:
    """Run an experiment through the nodes' tick pipeline (module doc) in a world of
    `engine` (None: the experiment's physics.engine); a SimResult as simulator.simulate
    gives.

    rate_hz: control rate (Hz; default the experiment's, checked as the file's); seed:
    each controller's phase of the control period (uniform in [0, 1)); pose_rate: poses per
    second (Hz; default config.experiment.pose_rate); link: the link's delays and
    losses (default: a link as long as the controllers are told, controller.command_latency,
    and no loss); synchronous: every controller ticks at the start of the period (no
    phases drawn), as the batch simulator's do by default.
    """
    spec = experiment.spec
    rate = control_rate(experiment, rate_hz)
    duration = spec.simulation.duration if duration is None else duration
    record_dt = spec.simulation.record_dt if record_dt is None else record_dt
    if pose_rate is None:
        pose_rate = experiment_pose_rate(experiment)
    world = make_world(experiment, engine)
    phases = (np.zeros(experiment.n) if synchronous
              else np.random.default_rng(seed).random(experiment.n))
    if link is None:
        link = Link(command_latency=spec.controller.command_latency, seed=seed)
    # the curve server starts the schedule once every controller has checked its motors
    # (formation_controller's ready report): a check begins at the first tick with a pose
    origin = (CHECK_SECONDS + link.pose_latency + 2.0 / rate if spec.controller.motor_check
              else 0.0)
    pipeline = Pipeline(experiment, world, rate, phases, pose_rate, link, origin)
    learns = spec.controller.estimate_motors or spec.controller.motor_check   # the wheels
    t, poses, dhat, commands = pipeline.run(duration, record_dt,
                                            spec.agents.reassign_every)
    sample_phase = phase_index([p.start for p in experiment.phases], t)
    followed = tuple(pipeline.followed)
    return SimResult(dataclasses.replace(experiment, phases=followed
                                         + experiment.phases[len(followed):]),
                     rate, experiment.gains, experiment.limits,
                     experiment.disturbance_at(t) if experiment.variations
                     else np.asarray(experiment.disturbance, float), t, poses, dhat, commands,
                     sample_phase, experiment.radius, world.contact_summary(),
                     [c.latency for c in pipeline.controllers],
                     [c.motor_time_constant for c in pipeline.controllers]
                     if spec.controller.estimate_motors else None,
                     [c.robot.wheel_gains for c in pipeline.controllers] if learns else None,
                     [c.robot.min_wheel_speed or None for c in pipeline.controllers]
                     if learns else None,
                     [c.robot.estimates() for c in pipeline.controllers])


def simulate_kinematic(experiment: Experiment,
                       rate_hz: float | None | Literal['config'] = 'config',
                       duration: float | None = None) -> tuple[SimResult, str | None]:
    """The paper's unicycles: the batch simulator, or the nodes' tick pipeline where an
    online estimate (of the latency or the motors) that the batch run shows would have been
    taken changes the controllers (estimate_replay.EstimateTakenError). rate_hz as
    simulator.simulate takes it. Returns the result and why the pipeline ran (None: the batch
    simulator ran).
    """
    try:
        return simulate(experiment, rate_hz=rate_hz, duration=duration), None
    except EstimateTakenError as taken:
        why = str(taken)
    if rate_hz is None:
        raise ValueError(f"--continuous: {why} needs the nodes' tick pipeline, at a control "
                         'rate (--rate, or controller.rate_hz)')
    return simulate_pipeline(experiment, 'kinematic', None if rate_hz == 'config' else rate_hz,
                             duration), why
