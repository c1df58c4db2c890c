"""Schema of an experiment YAML file (pydantic): keys, types, ranges and defaults.

Every model forbids unknown keys, so a misspelt key is refused with its path. Units: metres,
seconds, radians, m/s and rad/s throughout (cases 1-3 of the paper are in abstract units).
The camera's and the physics' sections are in config.camera_schema and
config.physics_schema.
"""

from typing import Any, Literal, Optional

from pydantic import Field, field_validator, model_validator, ValidationInfo

from curve_formation.core.config.camera_schema import CameraSpec
from curve_formation.core.config.physics_schema import PhysicsSpec
from curve_formation.core.config.strict import Pair, Strict
from curve_formation.core.controller.settings import SETTINGS
from curve_formation.core.formation.curves import MAX_HARMONICS, MAX_ORDER


MAX_FIT_ENTRIES = 50_000_000   # samples x basis functions of one fit (400 MB of float64)


def setting(key: str) -> Any:
    """The schema field of a controller setting, from its one declaration
    (controller.settings.SETTINGS): default (none where the file must give it), bounds and
    description; choices are checked by `checked`.
    """
    declared = SETTINGS[key]
    bounds: dict[str, Any] = {}
    if declared.low is not None:
        bounds['ge'] = declared.low
    if declared.above is not None and declared.kind != 'double[]':
        bounds['gt'] = declared.above
    if declared.high is not None:
        bounds['le'] = declared.high
    if declared.unlimited:
        bounds['allow_inf_nan'] = True   # infinity: no limit (NaN fails every bound)
    default = ... if declared.required else declared.default
    return Field(default, description=declared.description, **bounds)


def checked(key: str, value: Any) -> Any:
    """`value` if setting `key` takes it (choices, a pair's bounds), else ValueError."""
    problem = SETTINGS[key].problem(value)
    if problem is not None:
        raise ValueError(problem)
    return value


class RandomStart(Strict):
    """Uniform random start in a box, uniform random headings, from a fixed seed."""

    seed: int = 0
    center: Pair = Field(description='centre of the box (m)')
    half_width: Pair = Field(description='half side lengths of the box (m)')
    min_separation: float = Field(0.0, ge=0, description='least distance between two '
                                  'robots (m), e.g. a robot diameter; 0 = robots are points')

    @field_validator('half_width')
    @classmethod
    def _positive(cls, value: Pair) -> Pair:
        if min(value) <= 0:
            raise ValueError('half widths must be > 0')
        return value


class Initial(Strict):
    """Initial poses: exactly one of `random` or `poses` ([x, y, theta] per agent)."""

    random: Optional[RandomStart] = None
    poses: Optional[list[tuple[float, float, float]]] = None

    @model_validator(mode='after')
    def _one_of(self) -> 'Initial':
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
    def _reassign_nearest(self) -> 'Agents':
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
    pinning: float = setting('graph.pinning')


class TailSpec(Strict):
    """The finite-time tail of the approach (law.tail_feedback)."""

    radius: float = setting('controller.tail.radius')
    gain: float = setting('controller.tail.gain')


class ControllerSpec(Strict):
    law: str = setting('controller.law')
    adaptation: Pair = setting('controller.adaptation')
    heading: str = setting('controller.heading')
    observer_rate: float = setting('controller.observer_rate')
    observer_growth: float = setting('controller.observer_growth')
    estimate_latency: bool = setting('controller.estimate_latency')
    estimate_motors: bool = setting('controller.estimate_motors')
    motor_check: bool = setting('controller.motor_check')
    observer_order: int = setting('controller.observer_order')
    k1: float = setting('controller.k1')
    k2: float = setting('controller.k2')
    offset: float = setting('controller.offset')
    rate_hz: Optional[float] = Field(
        None, gt=0, description='control rate with zero-order hold; null = continuous')
    predict_pose: bool = setting('controller.predict_pose')
    command_latency: float = setting('controller.command_latency')
    feed_forward: bool = setting('controller.feed_forward')
    tail: Optional[TailSpec] = Field(
        None, description="near the target the law's speed shrinks as the square root of the "
        'error instead of linearly, so the approach ends in finite time instead of an '
        "exponential tail; null = the paper's linear law")
    reverse: bool = setting('controller.reverse')

    @field_validator('law', 'heading', 'observer_order', 'adaptation')
    @classmethod
    def _declared(cls, value: Any, info: ValidationInfo) -> Any:
        return checked(f'controller.{info.field_name}', value)


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
    def _fields_of_kind(self) -> 'VariationSpec':
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
    def _one_of(self) -> 'DisturbanceSpec':
        if self.value is not None and self.per_agent is not None:
            raise ValueError('give at most one of `value` or `per_agent`')
        return self


# A Mona's wheel base (m): the bridge's default, and the emulated robots' when an experiment
# sets no wheel limits.
MONA_WHEEL_BASE = 0.08


class LimitsSpec(Strict):
    """The robots' wheels and motors; a limit left out (or `.inf`) is no limit."""

    wheel_base: float = setting('limits.wheel_base')
    max_wheel_speed: float = setting('limits.max_wheel_speed')
    wheel_radius: float = Field(0.015, gt=0, description='wheel radius (m): the wheel speeds in '
                                'rad/s a robot bridge sends (Mona: 15 mm)')
    max_angular_rate: float = setting('limits.max_angular_rate')
    min_wheel_speed: float = setting('limits.min_wheel_speed')
    motor_time_constant: float = setting('limits.motor_time_constant')
    max_linear_accel: float = setting('limits.max_linear_accel')
    max_angular_accel: float = setting('limits.max_angular_accel')


class SafetySpec(Strict):
    """Watchdog timeouts of every controller (s) and the geofence margin (m)."""

    pose_timeout: float = setting('safety.pose_timeout')
    neighbour_timeout: float = setting('safety.neighbour_timeout')
    leader_timeout: float = setting('safety.leader_timeout')
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
    def _consistent(self) -> 'CurveSpec':
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
    def size(self) -> int:
        """K for Fourier, p for polynomial."""
        size = self.harmonics if self.basis == 'fourier' else self.order
        assert size is not None   # _consistent
        return size


class SimulationSpec(Strict):
    duration: float = Field(gt=0, description='simulated time (s)')
    dt: float = Field(0.001, gt=0, description='integration step (s)')
    record_dt: float = Field(0.01, gt=0, description='recording interval (s)')


class ArenaSpec(Strict):
    size: Pair = Field(description='arena width and height (m), origin at a corner')


class FleetRobotSpec(Strict):
    """One robot of the lab's fleet (robots.fleet lists them in agent order): its marker, the
    link its robot_bridge writes and the firmware's wire format, and what differs from the
    file's limits for this robot (left out: the limits').
    """

    marker: Optional[int] = Field(None, ge=0, description='ArUco id of the marker on the '
                                  'robot (default: camera.robot_ids, where listed)')
    link: str = Field(description="where the robot's radio hangs: 'serial:DEVICE' (e.g. "
                      "serial:/dev/ttyUSB0@115200, 115200 baud when no @BAUD) or "
                      "'udp:HOST:PORT'")
    format: Optional[str] = Field(None, description="the firmware's wire format: a preset "
                                  'of wire.PRESETS (mona-serial, wheel-m-s, json; left out: '
                                  'mona-serial)')
    replies: bool = Field(True, description="the firmware answers each line ('ok' or "
                          "'err'): pre-flight and robot_bridge expect answers")
    wheel_base: Optional[float] = Field(None, gt=0, description='distance between its '
                                        'wheels (m)')
    wheel_radius: Optional[float] = Field(None, gt=0, description='its wheel radius (m)')
    motor_time_constant: Optional[float] = Field(None, ge=0, description="its motors' "
                                                 'measured first-order lag (s)')
    min_wheel_speed: Optional[float] = Field(None, ge=0, description='its measured dead band: '
                                             'the smallest rim speed that moves a wheel (m/s)')


class RobotsSpec(Strict):
    """The robots' bodies, and the lab's robots with their links (fleet; empty: simulated
    robots only, or robots whose drivers are started by hand).
    """

    radius: float = setting('robots.radius')
    fleet: list[FleetRobotSpec] = Field([], description='one entry per agent, agent 1 first')


class AvoidanceSpec(Strict):
    """The safety filter in every controller (core.controller.safety); `avoidance: on` takes
    these defaults, `off` (or leaving the section out) the formation law alone.
    """

    margin: float = setting('avoidance.margin')
    rate: float = setting('avoidance.rate')
    passing: float = setting('avoidance.passing')
    passing_range: float = setting('avoidance.passing_range')
    drift: float = setting('avoidance.drift')


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

    @model_validator(mode='after')
    def _markers_from_fleet(self) -> 'ExperimentSpec':
        """camera.robot_ids left out: the fleet's markers, where it lists every one."""
        markers = [robot.marker for robot in self.robots.fleet]
        if (self.camera is not None and not self.camera.robot_ids and markers
                and None not in markers):
            self.camera.robot_ids = [int(m) for m in markers if m is not None]
        return self

    @field_validator('avoidance', mode='before')
    @classmethod
    def _on_off(cls, value: Any) -> Any:
        """`avoidance: on` (YAML true) = the defaults, `off` (false) = none."""
        if value is True:
            return {}
        if value is False:
            return None
        return value
