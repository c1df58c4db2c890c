"""Schema of an experiment YAML file (pydantic): keys, types, ranges and defaults.

Every model forbids unknown keys, so a misspelt key is refused with its path. Units: metres,
seconds, radians, m/s and rad/s throughout (cases 1-3 of the paper are in abstract units).
The camera's and the physics' sections are in config.camera_schema and
config.physics_schema.
"""

import math
from typing import Literal, Optional

from pydantic import Field, field_validator, model_validator

from curve_formation.core.config.camera_schema import CameraSpec
from curve_formation.core.config.physics_schema import PhysicsSpec
from curve_formation.core.config.strict import Pair, Strict
from curve_formation.core.formation.curves import MAX_HARMONICS, MAX_ORDER


MAX_FIT_ENTRIES = 50_000_000   # samples x basis functions of one fit (400 MB of float64)


class RandomStart(Strict):
    """Uniform random start in a box, uniform random headings, from a fixed seed."""

    seed: int = 0
    center: Pair = Field(description='centre of the box (m)')
    half_width: Pair = Field(description='half side lengths of the box (m)')
    min_separation: float = Field(0.0, ge=0, description='least distance between two '
                                  'robots (m), e.g. a robot diameter; 0 = robots are points')

    @field_validator('half_width')
    @classmethod
    def _positive(cls, value):
        if min(value) <= 0:
            raise ValueError('half widths must be > 0')
        return value


class Initial(Strict):
    """Initial poses: exactly one of `random` or `poses` ([x, y, theta] per agent)."""

    random: Optional[RandomStart] = None
    poses: Optional[list[tuple[float, float, float]]] = None

    @model_validator(mode='after')
    def _one_of(self):
        if (self.random is None) == (self.poses is None):
            raise ValueError('give exactly one of `random` or `poses`')
        return self


class Agents(Strict):
    count: int = Field(ge=1, le=10_000, description='number of agents n; agent 1 is the '
                       'leader (the graph is held as a dense n x n matrix)')
    spacing: Literal['uniform_s', 'arc_length'] = 'uniform_s'
    assignment: Literal['fixed', 'nearest'] = Field(
        'fixed', description="which agent takes which of the spacing's points: 'fixed' (the "
        "paper: agent i the i-th), 'nearest' (for each curve, the order that minimises the "
        'longest distance from where the agents are: their start for the first curve, the '
        "previous curve's targets after a switch)")
    initial: Initial
    reassign_every: Optional[float] = Field(
        None, gt=0, description='with nearest assignment: every this many seconds the targets '
        'are re-assigned among the agents from where they are, if that shortens the squared '
        'trips by 10 % (the curve server; robots whose ways cross swap targets); null = never')

    @model_validator(mode='after')
    def _reassign_nearest(self):
        if self.reassign_every is not None and self.assignment != 'nearest':
            raise ValueError('reassign_every needs assignment: nearest (with fixed assignment '
                             'agent i keeps the i-th point)')
        return self


class EdgeSpec(Strict):
    """`to` receives from `from` with weight `weight` (a_{to,from})."""

    source: int = Field(alias='from', ge=1)
    target: int = Field(alias='to', ge=1)
    weight: float = Field(1.0, gt=0)


class GraphSpec(Strict):
    leader: int = Field(1, ge=1)
    edges: list[EdgeSpec]
    pinning: float = Field(
        0.0, ge=0, allow_inf_nan=False,
        description="weight b of each follower's own target error in its feedback, "
        "b e_i + sum_j a_ij (e_i - e_j) (the leader's is 1); 0 = the paper's consensus law")


class TailSpec(Strict):
    """The finite-time tail of the approach (control.tail_feedback)."""

    radius: float = Field(gt=0, allow_inf_nan=False, description='feedback size (m) below '
                          'which the law speeds up as the square root of it instead of linearly')
    gain: float = Field(ge=1, allow_inf_nan=False,
                        description='cap on the speed-up (the gain is at most k1 gain)')


class ControllerSpec(Strict):
    law: Literal['paper', 'adaptive', 'observer'] = Field(
        'paper', description="disturbance estimator: 'paper' (the paper's adaptive law), "
        "'adaptive' (per-channel gains `adaptation`), 'observer' (from the measured motion)")
    adaptation: Pair = Field((1.0, 1.0), description='law adaptive: multipliers (gamma_v, '
                             "gamma_w) of the paper's estimator rate per channel")
    heading: Literal['paper', 'sampled'] = Field(
        'paper', description="'sampled': with rate_hz, each command turns the heading as the "
        "continuous law would over one period, so it cannot overshoot; 'paper': holds the "
        'continuous-time turn rate')
    observer_rate: float = Field(5.0, gt=0, description='law observer: bandwidth of the '
                                 'disturbance observer (1/s)')
    observer_growth: float = Field(
        1.0, ge=1, allow_inf_nan=False, description='law observer with a disturbance '
        "injected on_pc: while the wheel limits saturate the command, the robot's motion "
        "shows the disturbance's direction but not its size; the observer then searches "
        'along that direction, its step doubling each tick up to this factor '
        '(control.ray_growth; needs limits.wheel_base and max_wheel_speed); 1 = off')
    estimate_latency: bool = Field(
        False, description='estimate command_latency online, every 1 s (0.5 s until a first '
        'value) from the last 6 s of commands and poses, each fit added to those of about '
        'the last minute (core.controller.link_estimate), starting from command_latency; a '
        'new value is '
        'taken when 3 estimates in a row agree within 20 ms; in the nodes and their tick '
        'pipeline')
    observer_order: Literal[1, 2] = Field(
        1, description='law observer: 2 = it also estimates how fast the disturbance changes '
        '(an alpha-beta filter critically damped at observer_rate) and follows one that '
        'drifts without lag; runs in the nodes and their tick pipeline (sim runs that); 1 = '
        'the first-order observer')
    k1: float = Field(gt=0, description='gain on the target error (1/s)')
    k2: float = Field(ge=0, description='estimator gain; 0 = estimator off (every law '
                      'estimates d / k2, as the paper)')
    offset: float = Field(description='offset l of the control point ahead of the axle (m)')
    rate_hz: Optional[float] = Field(
        None, gt=0, description='control rate with zero-order hold; null = continuous')
    predict_pose: bool = Field(
        False, description="ROS controllers: carry the robot's pose forward from its stamp "
        '(capture time) to the tick, through the commands sent since, so a pose that is '
        '80 ms old does not make an 80 ms old command (PCs with synchronised clocks)')
    command_latency: float = Field(
        0.0, ge=0, le=0.5, allow_inf_nan=False, description="ROS controllers: the delay (s) "
        "from a command leaving the PC to the robot's wheels (the link's, e.g. Wi-Fi and the "
        'bridge): with predict_pose the pose (and the other robots, for the safety filter) is '
        'carried forward to when the command acts; the observer compares each motion with '
        'the commands acting over it and waits for the motion that answers its estimate')
    feed_forward: bool = Field(
        True, description="a moving curve's velocity at each target, G(s_i) xi-dot, is added "
        'to the command, so the formation keeps up instead of lagging (curves[].motion)')
    tail: Optional[TailSpec] = Field(
        None, description="near the target the law's speed shrinks as the square root of the "
        'error instead of linearly, so the approach ends in finite time instead of an '
        "exponential tail; null = the paper's linear law")
    reverse: bool = Field(
        False, description='a robot may drive backwards, steering the point behind its axle '
        'onto its target, when turning round and driving forwards would take longer (needs '
        "limits.wheel_base and max_wheel_speed to time both); false = the paper's forwards only")

    @field_validator('adaptation')
    @classmethod
    def _positive_gains(cls, value):
        if min(value) <= 0 or not all(math.isfinite(g) for g in value):
            raise ValueError('adaptation gains must be finite and > 0')
        return value

    @field_validator('offset')
    @classmethod
    def _nonzero(cls, value):
        if value == 0 or not math.isfinite(value):
            raise ValueError('the offset l must be finite and non-zero')
        return value

    @model_validator(mode='after')
    def _tail_within_the_period(self):
        if self.tail is not None and self.rate_hz and self.k1 * self.tail.gain >= self.rate_hz:
            raise ValueError(f'tail.gain {self.tail.gain:g} times k1 {self.k1:g} must stay '
                             f'below rate_hz {self.rate_hz:g}: a sampled command would '
                             'overshoot the target')
        return self


class VariationSpec(Strict):
    """One relative change of the disturbance over time (s since the first curve): a sine
    (amplitude, period, phase), a step (change at `at`) or a ramp (change reached from
    `start` to `end`, held after), on the listed agents (default all).
    """

    kind: Literal['sine', 'step', 'ramp']
    amplitude: Optional[float] = Field(None, description='sine: relative amplitude (0.5: '
                                       '+-50 % of the value)')
    period: Optional[float] = Field(None, gt=0, description='sine: period (s)')
    phase: float = Field(0.0, description='sine: phase (rad) at t = 0')
    at: Optional[float] = Field(None, ge=0, description='step: when (s)')
    start: Optional[float] = Field(None, ge=0, description='ramp: when it begins (s)')
    end: Optional[float] = Field(None, description='ramp: when the change is reached (s)')
    change: Optional[float] = Field(None, description='step, ramp: relative change (-0.2: '
                                    'the value falls by 20 %)')
    agents: Optional[list[int]] = Field(None, description='the agents it acts on (1-based; '
                                        'default all)')

    @model_validator(mode='after')
    def _fields_of_kind(self):
        needs = {'sine': ('amplitude', 'period'), 'step': ('at', 'change'),
                 'ramp': ('start', 'end', 'change')}[self.kind]
        missing = [key for key in needs if getattr(self, key) is None]
        if missing:
            raise ValueError(f'a {self.kind} needs {", ".join(needs)}; missing: '
                             f'{", ".join(missing)}')
        unused = [key for key in ('amplitude', 'period', 'at', 'start', 'end', 'change')
                  if key not in needs and getattr(self, key) is not None]
        if unused or (self.kind != 'sine' and self.phase != 0.0):
            raise ValueError(f'a {self.kind} takes {", ".join(needs)}'
                             f'{", phase" if self.kind == "sine" else ""}; not '
                             f'{", ".join(unused or ["phase"])}')
        if (self.kind == 'ramp' and self.end is not None and self.start is not None
                and not self.end > self.start):
            raise ValueError(f'a ramp ends after it starts (start {self.start:g} s, end '
                             f'{self.end:g} s)')
        return self


class DisturbanceSpec(Strict):
    """Input disturbance d_i = [d_v, d_w], the same for all agents or per agent, constant or
    varying over time (`varies`: each agent's value times 1 + the sum of its variations).
    """

    value: Optional[Pair] = None
    per_agent: Optional[list[Pair]] = None
    injected: Literal['on_robot', 'on_pc'] = Field(
        'on_robot', description='on_robot: added after the wheel limits (physical); on_pc: '
        'added to the command before the limits, as in the arena experiment')
    varies: list[VariationSpec] = Field(
        default_factory=list, description='relative changes over time (s since the first '
        'curve): sines, steps, ramps, each on some agents or all')

    @model_validator(mode='after')
    def _one_of(self):
        if self.value is not None and self.per_agent is not None:
            raise ValueError('give at most one of `value` or `per_agent`')
        return self


# A Mona's wheel base (m): the bridge's default, and the emulated robots' when an experiment
# sets no wheel limits.
MONA_WHEEL_BASE = 0.08


class LimitsSpec(Strict):
    wheel_base: float = Field(gt=0, description='distance between the wheels (m)')
    max_wheel_speed: float = Field(gt=0, description='max linear speed of each wheel (m/s)')
    wheel_radius: float = Field(0.015, gt=0, description='wheel radius (m): the wheel speeds in '
                                'rad/s a robot bridge sends (Mona: 15 mm)')
    max_angular_rate: Optional[float] = Field(None, gt=0, description='max |w| (rad/s)')
    min_wheel_speed: Optional[float] = Field(
        None, gt=0, description="the slowest wheel speed (m/s) the robots' motors turn at: "
        'a smaller command leaves the wheel still (a dead band); the observer then expects '
        'no motion from it instead of learning a disturbance. Measure it on your robots')
    motor_time_constant: Optional[float] = Field(
        None, gt=0, le=1.0, description="the first-order lag (s) with which the robots' wheels "
        'follow their commands: the observer compares each measured motion with what the '
        'commands realised through it. Measure it on your robots (a step response)')
    max_linear_accel: Optional[float] = Field(None, gt=0, description='max dv/dt (m/s^2)')
    max_angular_accel: Optional[float] = Field(None, gt=0, description='max dw/dt (rad/s^2)')


class SafetySpec(Strict):
    """Watchdog timeouts of every controller (s) and the geofence margin (m)."""

    pose_timeout: float = Field(0.5, gt=0)
    neighbour_timeout: float = Field(0.5, gt=0)
    leader_timeout: float = Field(1.0, gt=0)
    geofence_margin: float = Field(0.05, ge=0, description='a robot further than this outside '
                                   'the arena is stopped')


class MotionSpec(Strict):
    """A curve that moves while it is followed (core/formation/motion.py): it translates, turns and
    grows from its phase's start, about `about`.
    """

    velocity: Pair = Field((0.0, 0.0), description='translation velocity (m/s)')
    rotation_rate: float = Field(0.0, description='turn rate (rad/s), counter-clockwise')
    scale_rate: float = Field(0.0, description='relative growth rate (1/s); negative shrinks')
    about: Optional[Pair] = Field(None, description='the point it turns and grows about (m); '
                                  "default: the curve's centre (mean of its points)")


class CurveSpec(Strict):
    """One desired curve and the time it becomes active.

    Source: exactly one of `x` and `y` (expressions in s), `bezier` (control points) or
    `points` (ordered sampled points). Basis: `fourier` with `harmonics`, or `polynomial` with
    `order`.
    """

    start: float = Field(0.0, ge=0, description='time this curve becomes active (s)')
    basis: Literal['fourier', 'polynomial']
    harmonics: Optional[int] = Field(None, ge=1, le=MAX_HARMONICS)
    order: Optional[int] = Field(None, ge=1, le=MAX_ORDER, description='beyond ~30 a monomial '
                                 'basis is numerically singular')
    x: Optional[str] = None
    y: Optional[str] = None
    bezier: Optional[list[Pair]] = None
    points: Optional[list[Pair]] = None
    samples: int = Field(400, ge=3, le=1_000_000,
                         description='samples taken from x/y or bezier for the fit')
    motion: Optional[MotionSpec] = Field(None, description='the curve moves while it is '
                                         'followed (scripted: a rope being moved)')

    @model_validator(mode='after')
    def _consistent(self):
        size_key = 'harmonics' if self.basis == 'fourier' else 'order'
        other = 'order' if self.basis == 'fourier' else 'harmonics'
        if getattr(self, size_key) is None:
            raise ValueError(f'basis {self.basis} needs `{size_key}`')
        if getattr(self, other) is not None:
            raise ValueError(f'`{other}` does not apply to basis {self.basis}')
        sources = [name for name, given in (('x/y', self.x is not None or self.y is not None),
                                            ('bezier', self.bezier is not None),
                                            ('points', self.points is not None)) if given]
        if len(sources) != 1:
            raise ValueError(f'give exactly one curve source (x and y, bezier, or points), '
                             f'got {sources or "none"}')
        if sources == ['x/y'] and (self.x is None or self.y is None):
            raise ValueError('an expression curve needs both `x` and `y`')
        h = 2 * self.size + 1 if self.basis == 'fourier' else self.size + 1
        if self.samples * h > MAX_FIT_ENTRIES:
            raise ValueError(f'samples x basis functions = {self.samples * h} exceeds '
                             f'{MAX_FIT_ENTRIES} (the fit matrix would not fit in memory)')
        return self

    @property
    def size(self):
        """K for Fourier, p for polynomial."""
        return self.harmonics if self.basis == 'fourier' else self.order


class SimulationSpec(Strict):
    duration: float = Field(gt=0, description='simulated time (s)')
    dt: float = Field(0.001, gt=0, description='integration step (s)')
    record_dt: float = Field(0.01, gt=0, description='recording interval (s)')


class ArenaSpec(Strict):
    size: Pair = Field(description='arena width and height (m), origin at a corner')


class RobotsSpec(Strict):
    """The robots' bodies."""

    radius: float = Field(0.0, ge=0, description='body radius (m): a disc around the axle '
                          'centre that no other body or wall may enter; 0 = points that pass '
                          'through each other (the paper)')


class AvoidanceSpec(Strict):
    """The safety filter in every controller (core.controller.safety); `avoidance: on` takes these
    defaults, `off` (or leaving the section out) the formation law alone.
    """

    margin: float = Field(0.02, ge=0, description='extra distance kept between two bodies and '
                          'from the walls (m): covers pose latency and the arc a robot draws '
                          'within a tick')
    rate: float = Field(5.0, gt=0, description='barrier rate alpha (1/s): how fast a robot '
                        'may close the distance to the safe one; at most the control rate')
    passing: float = Field(0.0, ge=0, description='passing rule: sideways speed to the right '
                           'per unit of approach speed towards a robot nearby (0 = none)')
    passing_range: Optional[float] = Field(None, gt=0, description='gap above the safe '
                                           'distance within which a robot steers around others '
                                           'and gives way (m); default: one body diameter')
    drift: float = Field(0.0, ge=0, description='forward drift (m/s) the barriers hold '
                         "against beyond what the command cancels: a bound on the robots' "
                         'drift before the observer has learnt it (0 = none)')


class MetricsSpec(Strict):
    tolerance: float = Field(1e-3, gt=0, description='settling tolerance, relative to the '
                             'size (bounding-box diagonal) of the active curve')


class ExperimentSpec(Strict):
    name: str
    description: str = ''
    agents: Agents
    graph: GraphSpec
    controller: ControllerSpec
    disturbance: DisturbanceSpec = DisturbanceSpec()
    limits: Optional[LimitsSpec] = None
    curves: list[CurveSpec] = Field(min_length=1)
    simulation: SimulationSpec
    arena: Optional[ArenaSpec] = None
    safety: SafetySpec = SafetySpec()
    metrics: MetricsSpec = MetricsSpec()
    camera: Optional[CameraSpec] = None
    robots: RobotsSpec = RobotsSpec()
    avoidance: Optional[AvoidanceSpec] = None
    physics: PhysicsSpec = PhysicsSpec()

    @field_validator('avoidance', mode='before')
    @classmethod
    def _on_off(cls, value):
        """`avoidance: on` (YAML true) = the defaults, `off` (false) = none."""
        if value is True:
            return {}
        if value is False:
            return None
        return value
