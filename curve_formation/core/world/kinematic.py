"""The robots as the paper's unicycles in one arena: exact motion, discs pushed apart.

Each robot moves as a dynamics.DrivenUnicycle under its velocity commands (with the link's
latency, its watchdog and the experiment's robot-side disturbance). The world advances in
steps of at most `physics_dt`, and after each step bodies that overlap are pushed apart,
bodies through a wall put back and the contacts tallied (core.world.bodies.touch, compiled as the
batch simulator runs it); in one step while no two bodies, nor a body and a wall, can meet
before its end.

The same interface as mujoco_world.MujocoWorld: command(i, v, w, now), advance(until),
poses(), contact_summary(). Frames and units: arena frame, m, s, rad.
"""

import math
from typing import TYPE_CHECKING

import numpy as np

from curve_formation.core.base.jit import compiled
from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.formation.dynamics import DrivenUnicycle
from curve_formation.core.world import bodies


if TYPE_CHECKING:
    from curve_formation.core.config.experiment import Experiment


# Longest step between two contact resolutions (s).
PHYSICS_DT = 0.005


class KinematicWorld:
    """Every robot of an experiment as a unicycle body (see the module)."""

    def __init__(self, experiment: 'Experiment', latency: float = 0.0, timeout: float = 0.0,
                 physics_dt: float = PHYSICS_DT, jitter: float = 0.0, seed: int = 0) -> None:
        spec = experiment.spec
        on_robot = self.on_robot = spec.disturbance.injected == 'on_robot'
        self.robots = [DrivenUnicycle(pose, d if on_robot else (0.0, 0.0), latency, timeout,
                                      jitter, (seed, i))
                       for i, (pose, d) in enumerate(zip(experiment.initial_poses,
                                                         experiment.disturbance, strict=True))]
        self.n = experiment.n
        self.radius = experiment.radius
        self.physics_dt = physics_dt
        self.size = tuple(spec.arena.size) if spec.arena is not None else (0.0, 0.0)
        self.contacts = bodies.contacts_of(self.n, self.radius, *self.size)
        self.clearance = -math.inf   # the smallest gap, or twice a body's room to a wall (m)
        self.time: float | None = None
        self.touch = compiled(bodies.touch)
        if self.radius > 0:   # compile now
            self.touch(np.zeros((0, 3)), bodies.contacts_of(0, 1.0, 0.0, 0.0), 0.0)

    def disturb(self, i: int, d: FloatArray) -> None:
        """Robot i's (0-based) disturbance [d_v, d_w] (m/s, rad/s) from its next step on (a
        disturbance that varies; none where it is injected on the PC).
        """
        if self.on_robot:
            self.robots[i].disturbance = (float(d[0]), float(d[1]))

    def command(self, i: int, v: float, w: float, now: float) -> None:
        """Robot i's (0-based) velocity command (m/s, rad/s) received at `now` (s); taken up,
        at its time, by the next advance().
        """
        self.robots[i].drive(v, w, now, advance=False)

    def top_speed(self, until: float) -> float:
        """The fastest (m/s) any centre moves up to `until`."""
        return max(robot.top_speed(until) for robot in self.robots)

    def advance(self, until: float) -> list[int]:
        """Move every robot up to `until` (s), resolving contacts every physics_dt; the
        robots (0-based) whose watchdog turned their motors off on the way.
        """
        if self.time is None:
            self.time = until
        stopped = []
        while self.time < until:
            step = min(self.physics_dt, until - self.time)
            if self._apart_over(until - self.time):
                step = until - self.time
            self.time += step
            stopped += [i for i, robot in enumerate(self.robots) if robot.advance(self.time)]
            self._touch(step)
        return stopped

    def poses(self) -> FloatArray:
        """(n, 3) x, y (m), theta (rad) of every robot."""
        return np.array([r.pose for r in self.robots])

    def _apart_over(self, span: float) -> bool:
        """Whether no contact can happen in the next `span` s: the bodies' smallest gap and
        twice their room to the walls exceed twice the fastest robot's travel.
        """
        if self.radius <= 0:
            return True
        assert self.time is not None
        return self.clearance > 2.0 * self.top_speed(self.time + span) * span

    def _touch(self, step: float) -> None:
        if self.radius <= 0:
            return
        poses = self.poses()
        self.clearance = self.touch(poses, self.contacts, step)
        for axis, size in enumerate(self.size):   # walls: 0 <= x <= width, 0 <= y <= height
            if size > 0:
                room = np.minimum(poses[:, axis], size - poses[:, axis]) - self.radius
                self.clearance = min(self.clearance, 2.0 * float(room.min()))
        for robot, pose in zip(self.robots, poses, strict=True):
            robot.pose = (float(pose[0]), float(pose[1]), float(pose[2]))

    def contact_summary(self) -> dict[str, float | int | None]:
        """{'count', 'time' (s), 'smallest_gap' (m, None without bodies)} so far."""
        return bodies.contact_summary(self.contacts)
