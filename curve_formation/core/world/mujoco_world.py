"""The robots as MuJoCo bodies: mass, driven wheels, motors, casters, friction and contacts.

The world is generated from an experiment (`physics:` for the bodies and motors, `limits:`
for the wheels, `robots.radius` and `arena.size` for bodies and walls) as an MJCF model
(`arena_mjcf`). Each robot is a body moving on the floor (x, y, z and heading joints): a disc
of the configured radius carried by two wheels on hinges (limits.wheel_base apart,
limits.wheel_radius) and casters that keep it level and drag. Each wheel is driven by a motor
that follows its speed command as a first-order lag (physics.motor_time_constant) through a
wheel-speed servo with integral action and a torque limit (physics.motor_torque).
docs/physics.md says why each part is modelled as it is.

A velocity command (v, w) (m/s, rad/s) reaches the wheels as the firmware would turn it into
wheel speeds: with its latency and watchdog (dynamics.CommandQueue), the robot-side
disturbance of the experiment (added while driven), quantised and dead-banded as
physics.imperfections says, through each motor's gain (spread, battery sag) and over each
wheel's own radius (mismatch). Contacts, the smallest gap between two bodies and the
pushes are read from MuJoCo's contact list.

Frames and units: arena frame, origin at a corner, z up; m, s, rad, kg, N.
"""

from dataclasses import dataclass
import math
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.config.experiment import wheel_base, wheel_radius
from curve_formation.core.config.physics_schema import WHEEL_MASS
from curve_formation.core.formation.dynamics import CommandQueue


if TYPE_CHECKING:
    from curve_formation.core.config.experiment import Experiment


# Geometry the experiment does not set (m): the wheels' width (the bodies' clearance of
# them without robots.radius), the body's centre of mass below the axle, the casters'
# distance in from the body's rim, wall thickness and height.
WHEEL_WIDTH = 0.006
COM_DROP = 0.003
CASTER_INSET = 0.008
# MuJoCo's friction is soft: a wheel pushing against drag creeps (about 0.1 mm/s here);
# this many no-slip iterations remove that creep.
NOSLIP = 3
WALL = (0.02, 0.05)
# The wheel-speed servo behind each motor's lag: its own lag (s), small beside a motor time
# constant, sets its gains from the inertia a wheel drives; the lag filter before it takes
# the rest of the motor's time constant (2 SERVO_LAG less).
SERVO_LAG = 0.005
# Two bodies in contact again within this many seconds of parting are one contact: MuJoCo's
# soft contacts flicker in and out while robots push on each other.
REJOIN = 0.1
# The speed (m/s) caster_drag is given at when the wheels have no limit.
DRAG_SPEED = 0.05
# Anti-windup (rad): a wheel held back (blocked, torque-limited) lags its integrated command
# by at most this, as firmware clamps its integral.
WINDUP = 0.2
# The smallest gap between two bodies is MuJoCo's distance between their geoms
# (mj_geomDistance), looked up every GAP_EVERY steps up to GAP_RANGE (m; further is reported
# as None).
GAP_EVERY = 10
GAP_RANGE = 0.1
# A wheel's contact with the floor: stiff (N/m per kg of contact mass, MuJoCo's direct
# solref), damped and with its impedance near 1, so that a wheel sinks in by microns: MuJoCo's
# default soft contact sinks it 0.14 mm and it rolls on a radius 1 % short.
WHEEL_SOLREF = (-1e5, -632.0)
WHEEL_SOLIMP = (0.99, 0.999, 1e-4)
# Contact types: the floor touches the wheels; bodies touch bodies and walls.
FLOOR_BIT, BODY_BIT = 1, 2


@dataclass(frozen=True)
class Robots:
    """Each robot's drawn imperfections: wheel radii (n, 2) (m, left and right) and motor
    gains (n, 2); the nominal wheel radius (m) the firmware converts speeds with.
    """

    wheel_radii: FloatArray
    gains: FloatArray
    nominal_radius: float

    @property
    def wheel_gains(self) -> FloatArray:
        """(n, 2) each wheel's speed per unit of command (left, right): its radius over the
        nominal one times its motor's gain, the battery full (what the controllers estimate).
        """
        return self.wheel_radii / self.nominal_radius * self.gains


def draw_robots(experiment: 'Experiment') -> Robots:
    """The per-robot wheel radius mismatch and motor gains of physics.imperfections."""
    spec = experiment.spec
    imperfect = spec.physics.imperfections
    rng = np.random.default_rng(imperfect.seed)
    n = experiment.n
    radius = wheel_radius(experiment)
    mismatch = rng.uniform(-1.0, 1.0, n) * imperfect.wheel_radius_mismatch
    radii = radius * np.column_stack([1.0 + 0.5 * mismatch, 1.0 - 0.5 * mismatch])
    gains = 1.0 + rng.uniform(-1.0, 1.0, (n, 2)) * imperfect.motor_gain_spread
    return Robots(radii, gains, radius)


def body_radius(experiment: 'Experiment') -> float:
    """The disc of a robot's body (m): robots.radius, or just round its wheels for points."""
    return experiment.radius or 0.5 * wheel_base(experiment) + WHEEL_WIDTH


def servo_gains(experiment: 'Experiment') -> tuple[float, float]:
    """(kp N m/rad, kv N m s/rad) of a wheel's servo: critically damped at 1 / SERVO_LAG on
    the inertia one wheel drives (its share of the robot's mass, the wheel, the rotor).
    """
    physics = experiment.spec.physics
    r = wheel_radius(experiment)
    inertia = 0.5 * physics.mass * r * r + 0.5 * WHEEL_MASS * r * r + physics.motor_inertia
    return inertia / SERVO_LAG ** 2, 2.0 * inertia / SERVO_LAG


def arena_mjcf(experiment: 'Experiment', robots: Robots | None = None) -> str:
    """The MJCF model of the experiment's arena with its robots at their start poses."""
    robots = draw_robots(experiment) if robots is None else robots
    physics = experiment.spec.physics
    base = wheel_base(experiment)
    radius = body_radius(experiment)
    r0 = robots.nominal_radius
    body_mass = physics.mass - 2 * WHEEL_MASS
    disc_side = body_mass * (0.25 * radius ** 2 + physics.height ** 2 / 12.0)
    max_speed = experiment.limits.max_wheel_speed
    max_speed = max_speed if math.isfinite(max_speed) else DRAG_SPEED
    kp, kv = servo_gains(experiment)
    width, height = (experiment.spec.arena.size if experiment.spec.arena is not None
                     else (0.0, 0.0))
    extent = max(width, height, 2.0) + 2.0
    out = ['<mujoco model="curve_formation arena">',
           _element('compiler', angle='radian', autolimits='true'),
           _element('option', timestep=physics.timestep, integrator='implicitfast',
                    noslip_iterations=NOSLIP),
           '<worldbody>',
           # the floor's own friction is the least (a contact takes the larger of its two
           # geoms'): the wheels set theirs
           _element('geom', name='floor', type='plane', size=(extent, extent, 0.1),
                    pos=(0.5 * width, 0.5 * height, 0), contype=FLOOR_BIT, conaffinity=0,
                    condim=1, friction=(1e-4, 0, 0))]
    if width > 0 and height > 0:
        t, h = WALL
        for name, (x, y, sx, sy) in {
                'wall_west': (-t / 2, height / 2, t / 2, height / 2 + t),
                'wall_east': (width + t / 2, height / 2, t / 2, height / 2 + t),
                'wall_south': (width / 2, -t / 2, width / 2 + t, t / 2),
                'wall_north': (width / 2, height + t / 2, width / 2 + t, t / 2)}.items():
            out.append(_element('geom', name=name, type='box', pos=(x, y, h / 2),
                                size=(sx, sy, h / 2), contype=BODY_BIT, conaffinity=0))
    # The casters' drag (viscous: caster_drag times the robot's weight at the wheels' top
    # speed, along the floor and, at their distance from the axle, against turning).
    drag = physics.caster_drag * physics.mass * 9.81 / max_speed
    arm = radius - CASTER_INSET
    for i in range(1, experiment.n + 1):
        # Joints at the axle centre: x, y and z along the floor's axes and the heading
        # (unwrapped); the casters keep the body level (no pitch or roll: a robot on two
        # wheels and two casters does not tip on a flat floor); the start pose is set in
        # their positions (MujocoWorld).
        out += [_element('body', name=f'robot{i}', pos=(0, 0, r0), close=False),
                _element('joint', name=f'x{i}', type='slide', axis=(1, 0, 0),
                         damping=drag),
                _element('joint', name=f'y{i}', type='slide', axis=(0, 1, 0),
                         damping=drag),
                _element('joint', name=f'z{i}', type='slide', axis=(0, 0, 1)),
                _element('joint', name=f'heading{i}', type='hinge', axis=(0, 0, 1),
                         damping=drag * arm * arm),
                # a disc of the body's radius and height, its centre of mass below the axle
                # (the robot hangs between its wheels instead of rocking on them)
                _element('inertial', pos=(0, 0, -COM_DROP), mass=body_mass,
                         diaginertia=(disc_side, disc_side, 0.5 * body_mass * radius ** 2)),
                # a sphere at axle height: its horizontal section is the body's disc
                _element('geom', name=f'body{i}', type='sphere', size=radius,
                         contype=BODY_BIT, conaffinity=BODY_BIT)]
        for side, sign, r in (('left', 1.0, robots.wheel_radii[i - 1, 0]),
                              ('right', -1.0, robots.wheel_radii[i - 1, 1])):
            out += [_element('body', name=f'{side}{i}', pos=(0, sign * 0.5 * base, r - r0),
                             close=False),
                    _element('joint', name=f'{side}{i}', type='hinge', axis=(0, 1, 0),
                             armature=physics.motor_inertia),
                    # a sphere: a thin wheel meets the floor at one point, as a sphere does
                    # (and MuJoCo collides it with the plane at half a cylinder's cost)
                    _element('geom', type='sphere', size=r, mass=WHEEL_MASS, contype=0,
                             conaffinity=FLOOR_BIT, condim=3,
                             solref=WHEEL_SOLREF, solimp=WHEEL_SOLIMP,
                             friction=(physics.floor_friction, 0, 0)),
                    '</body>']
        out.append('</body>')
    out += ['</worldbody>', '<actuator>']
    for i in range(1, experiment.n + 1):
        for side in ('left', 'right'):
            # act' = speed command, force = kp (act - angle) - kv speed: a wheel-speed loop
            # with integral action, as closed-loop firmware runs (no steady error under drag)
            out.append(_element('general', name=f'{side}{i}', joint=f'{side}{i}',
                                dyntype='integrator', gaintype='fixed', gainprm=kp,
                                biastype='affine', biasprm=(0, -kp, -kv),
                                forcerange=(-physics.motor_torque, physics.motor_torque)))
    out += ['</actuator>', '</mujoco>']
    return '\n'.join(out) + '\n'


def _element(tag: str, close: bool = True, **attributes: object) -> str:
    """An MJCF element: numbers plain (12 significant digits), tuples space-separated."""
    def text(value: object) -> str:
        if isinstance(value, str):
            return value
        if isinstance(value, tuple):
            return ' '.join(text(v) for v in value)
        return f'{float(value):.12g}'   # type: ignore[arg-type]
    attrs = ''.join(f' {key}={quoteattr(text(value))}' for key, value in attributes.items())
    return f'<{tag}{attrs}{"/" if close else ""}>'


class MujocoWorld:
    """Every robot of an experiment as a MuJoCo body on driven wheels (see the module).

    command(i, v, w, now) hands robot i (0-based) a velocity command received at `now` (s);
    advance(until) steps the engine to `until`; poses() are the axle centres and headings
    (n, 3; headings unwrapped). latency (s) and timeout (s, 0 = none) are the link's delay
    and the robot's watchdog, as for the kinematic robots.
    """

    def __init__(self, experiment: 'Experiment', latency: float = 0.0,
                 timeout: float = 0.0, jitter: float = 0.0, seed: int = 0) -> None:
        spec = experiment.spec
        self.n = experiment.n
        self.robots = draw_robots(experiment)
        self.model = mujoco.MjModel.from_xml_string(arena_mjcf(experiment, self.robots))
        self.data = mujoco.MjData(self.model)
        self.dt = self.model.opt.timestep
        self.time: float | None = None
        self.steps = 0
        self.base = wheel_base(experiment)
        limits = experiment.limits
        imperfect = spec.physics.imperfections
        self.dead_band = imperfect.dead_band * limits.max_wheel_speed
        bits = imperfect.command_bits
        self.quantum = (limits.max_wheel_speed / (2 ** (bits - 1) - 1)
                        if bits is not None and math.isfinite(limits.max_wheel_speed) else 0.0)
        self.sag = imperfect.battery_sag / 600.0   # gain lost per s
        on_robot = self.on_robot = spec.disturbance.injected == 'on_robot'
        # a copy: disturb() changes it, never the experiment's own (a varying disturbance
        # is the experiment's value times its variation, taken afresh each time)
        self.disturbance = (np.array(experiment.disturbance, float) if on_robot
                            else np.zeros((self.n, 2)))
        self.queues = [CommandQueue(latency, timeout, jitter, (seed, i)) for i in range(self.n)]
        self.wheels = np.zeros((self.n, 2))   # wheel speed commands in force (m/s)
        self.target: FloatArray = np.zeros(2 * self.n)   # the motors' speed commands (rad/s)
        self.motor = np.zeros(2 * self.n)     # ... after their lag (rad/s)
        self.lagging = False                  # the motors have not caught up yet
        lag = max(spec.physics.motor_time_constant - 2.0 * SERVO_LAG, 1e-6)
        self.follow = 1.0 - math.exp(-self.dt / lag)
        self.next_change = -math.inf   # s: when a command falls due or a watchdog fires
        self.pose_qpos = np.array([[self.model.jnt_qposadr[self.model.joint(f'{axis}{i}').id]
                                    for axis in ('x', 'y', 'heading')]
                                   for i in range(1, self.n + 1)])
        self.data.qpos[self.pose_qpos] = np.asarray(experiment.initial_poses, float)
        self.wheel_dofs = np.array([[self.model.jnt_dofadr[self.model.joint(f'{s}{i}').id]
                                     for s in ('left', 'right')] for i in range(1, self.n + 1)])
        self.wheel_qpos = np.array([self.model.jnt_qposadr[self.model.joint(f'{s}{i}').id]
                                    for i in range(1, self.n + 1) for s in ('left', 'right')])
        # geom id -> robot index (bodies), -2 for walls, -1 otherwise
        self.body_geoms = [self.model.geom(f'body{i + 1}').id for i in range(self.n)]
        self.geom_owner = np.full(self.model.ngeom, -1)
        self.geom_owner[self.body_geoms] = np.arange(self.n)
        for g in range(self.model.ngeom):
            if self.model.geom(g).name.startswith('wall_'):
                self.geom_owner[g] = -2
        self.body_ids = [self.model.body(f'robot{i + 1}').id for i in range(self.n)]
        self.pairs = np.triu_indices(self.n, 1)
        self.near = 2.0 * body_radius(experiment) + GAP_RANGE
        self.touching: set[tuple[int, int]] = set()
        self.last_touch: dict[tuple[int, int], int] = {}   # pair -> step it last touched
        self.rejoin = REJOIN / self.dt
        self.floor_contacts = 2 * self.n
        self.contacts = 0
        self.wall_contacts = 0
        self.contact_steps = 0
        self.smallest_gap = math.inf
        self.largest_push = 0.0
        self._force = np.zeros(6)
        mujoco.mj_forward(self.model, self.data)

    def disturb(self, i: int, d: FloatArray) -> None:
        """Robot i's (0-based) disturbance [d_v, d_w] (m/s, rad/s) from the next step on (a
        disturbance that varies; none where it is injected on the PC).
        """
        if self.on_robot:
            self.disturbance[i] = d
            self.next_change = min(self.next_change, self.time or 0.0)

    def command(self, i: int, v: float, w: float, now: float) -> None:
        """Robot i's (0-based) velocity command (m/s, rad/s) received at `now` (s)."""
        self.queues[i].push(v, w, now)
        self.next_change = min(self.next_change, now + self.queues[i].latency)

    def advance(self, until: float) -> list[int]:
        """Step the engine up to `until` (s, to within half a step); the robots (0-based)
        whose watchdog turned their motors off on the way.
        """
        if self.time is None:
            self.time = until
        stopped: list[int] = []
        while self.time + 0.5 * self.dt <= until:
            end = self.time + self.dt
            if end >= self.next_change or self.sag > 0:
                if end >= self.next_change:
                    stopped += self._take_commands(end)
                self.target = self.motor_commands(self.wheels, self.time).ravel()
                self.lagging = True
            if self.lagging:   # the motors' lag, until they have caught up
                ahead = self.target - self.motor
                self.motor += ahead * self.follow
                self.lagging = bool(np.abs(ahead).max() > 1e-9)
                self.data.ctrl[:] = self.motor
            mujoco.mj_step(self.model, self.data)
            if self.steps % GAP_EVERY == 0:   # anti-windup
                angle = self.data.qpos[self.wheel_qpos]
                np.clip(self.data.act, angle - WINDUP, angle + WINDUP, out=self.data.act)
            self.time = end
            self.steps += 1
            self._tally()
        return stopped

    def _take_commands(self, end: float) -> list[int]:
        """Wheel speed commands in force at `end` (s): the robots whose watchdog fired."""
        stopped = []
        self.next_change = math.inf
        for i, queue in enumerate(self.queues):
            if queue.segments(end)[1]:
                stopped.append(i)
            v, w = queue.command
            self.wheels[i] = 0.0
            if v != 0.0 or w != 0.0:
                v += self.disturbance[i, 0]
                w += self.disturbance[i, 1]
                self.wheels[i] = v - 0.5 * self.base * w, v + 0.5 * self.base * w
            self.next_change = min(self.next_change, queue.next_change())
        return stopped

    def motor_commands(self, wheels: FloatArray, now: float) -> FloatArray:
        """(n, 2) motor speed commands (rad/s) for wheel speed commands (n, 2; m/s, left and
        right) as the firmware and motors turn them: quantised, dead-banded, over the
        nominal radius, times each motor's gain and the battery's.
        """
        if self.quantum > 0:
            wheels = np.round(wheels / self.quantum) * self.quantum
        if self.dead_band > 0:
            wheels = np.where(np.abs(wheels) < self.dead_band, 0.0, wheels)
        battery = max(0.0, 1.0 - self.sag * now)
        return wheels / self.robots.nominal_radius * self.robots.gains * battery

    def wheel_speeds(self) -> FloatArray:
        """(n, 2) wheel angular speeds (rad/s), left and right."""
        return self.data.qvel[self.wheel_dofs]

    def poses(self) -> FloatArray:
        """(n, 3) x, y (m) of each axle centre and its heading (rad, unwrapped)."""
        return self.data.qpos[self.pose_qpos]

    def _tally(self) -> None:
        """Contacts of the step just taken, from MuJoCo's contact list; every GAP_EVERY
        steps, the smallest gap between two bodies from MuJoCo's geom distance.
        """
        if self.steps % GAP_EVERY == 0:
            centres = self.data.xpos[self.body_ids, :2]
            a, b = self.pairs
            near = np.flatnonzero(np.sum((centres[a] - centres[b]) ** 2, axis=1)
                                  < self.near ** 2)   # only these can be within GAP_RANGE
            for k in near:
                gap = mujoco.mj_geomDistance(self.model, self.data, self.body_geoms[a[k]],
                                             self.body_geoms[b[k]], GAP_RANGE, None)
                self.smallest_gap = min(self.smallest_gap, gap)
        if self.data.ncon == self.floor_contacts and not self.touching:
            return   # only the wheels on the floor (one contact each), as nearly always
        contact = self.data.contact
        owners = self.geom_owner[contact.geom]   # (ncon, 2)
        touching = set()
        for k in np.flatnonzero(owners.max(axis=1) > -1):
            i, j = int(owners[k, 0]), int(owners[k, 1])
            if i >= 0 and j >= 0:
                touching.add((min(i, j), max(i, j)))
                self.smallest_gap = min(self.smallest_gap, float(contact.dist[k]))
            else:
                touching.add((max(i, j), -1))
            mujoco.mj_contactForce(self.model, self.data, int(k), self._force)
            self.largest_push = max(self.largest_push, abs(float(self._force[0])))
        for pair in touching - self.touching:
            # a pair pushing on flickers in and out of contact: one contact until it has
            # been apart for REJOIN s
            if self.steps - self.last_touch.get(pair, -math.inf) > self.rejoin:
                if pair[1] >= 0:
                    self.contacts += 1
                else:
                    self.wall_contacts += 1
        for pair in touching:
            self.last_touch[pair] = self.steps
        self.contact_steps += bool(touching)
        self.touching = touching

    def contact_summary(self) -> dict[str, float | int | None]:
        """{'count' (new robot-robot contacts), 'walls' (new robot-wall contacts), 'time' (s
        with any), 'smallest_gap' (m between two bodies; None when none came within
        GAP_RANGE), 'largest_push' (N, the largest contact force)} so far.
        """
        return {'count': self.contacts, 'walls': self.wall_contacts,
                'time': self.contact_steps * self.dt,
                'smallest_gap': self.smallest_gap if math.isfinite(self.smallest_gap)
                else None,
                'largest_push': self.largest_push}
