"""Every setting of a robot's controller, declared once: its key in an experiment file, its
ROS parameter, type, unit, default, range and meaning, and the rules that tie settings
together. The experiment schema (config.schema), the controller's own defaults (Gains,
WheelLimits, Avoidance, AgentConfig), the formation_controller node's parameters, the
parameters files, `--help` and the settings tables of docs/experiments.md and docs/nodes.md
are all made from this table.

A limit that is not set is infinite: left out of the file (or written `.inf`), `.inf` in a
parameters file, math.inf in code. A quantity that is not told (a dead band, a motor lag, a
latency) is 0.
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import math
from typing import Any

from curve_formation.core.controller.plausibility import MAX_COORDINATE


@dataclass(frozen=True)
class Setting:
    """One setting. kind: 'double', 'int', 'bool', 'string' or 'double[]' (a pair).

    default: its value when not given; required: an experiment file must give it when its
    section is there (default is then what a node or code that builds a controller takes).
    low/high: inclusive bounds; above: exclusive lower bound; choices: allowed values;
    unlimited: infinity is allowed and means no limit.
    """

    key: str
    parameter: str
    kind: str
    default: Any
    unit: str
    meaning: str
    low: float | None = None
    above: float | None = None
    high: float | None = None
    choices: tuple[Any, ...] = ()
    required: bool = False
    unlimited: bool = False

    @property
    def name(self) -> str:
        """The key's last part: the field's name in its section."""
        return self.key.rsplit('.', 1)[-1]

    @property
    def description(self) -> str:
        """The meaning with its unit, as the schema, the node and the docs state it."""
        unit = f' ({self.unit})' if self.unit else ''
        return self.meaning + unit

    def problem(self, value: Any) -> str | None:
        """What is wrong with `value` for this setting (range, choices, finiteness), or None.
        The default is always taken, also where it lies outside the range (0: off, for a
        setting whose file section may be left out).
        """
        items = list(value) if self.kind == 'double[]' else [value]
        for item in items:
            if item == self.default and self.kind != 'double[]':
                continue
            if self.choices and item not in self.choices:
                return (f'expected one of {", ".join(map(repr, self.choices))}, '
                        f'got {item!r}')
            if self.kind in ('double', 'double[]') and (
                    math.isnan(item) or (math.isinf(item) and not self.unlimited)):
                return f'expected a finite number, got {item!r}'
            if self.low is not None and item < self.low:
                return f'expected >= {self.low:g}, got {item!r}'
            if self.above is not None and not item > self.above:
                return f'expected > {self.above:g}, got {item!r}'
            if self.high is not None and item > self.high:
                return f'expected <= {self.high:g}, got {item!r}'
        return None


def _settings(*settings: Setting) -> dict[str, Setting]:
    return {s.key: s for s in settings}


LAW_NAMES = ('paper', 'adaptive', 'observer')
INF = math.inf
# The control rate (Hz) of a controller whose experiment controls continuously, and of a node
# told none.
DEFAULT_RATE_HZ = 10.0

SETTINGS = _settings(
    Setting('graph.pinning', 'pinning', 'double', 0.0, '',
            "weight b of each follower's own target error in its feedback, "
            "b e_i + sum_j a_ij (e_i - e_j) (the leader's is 1); 0 = the paper's consensus law",
            low=0.0),
    Setting('controller.k1', 'k1', 'double', 1.0, '1/s', 'gain on the target error',
            above=0.0, required=True),
    Setting('controller.k2', 'k2', 'double', 1.0, '', 'estimator gain; 0 = estimator off '
            '(every law estimates d / k2, as the paper)', low=0.0, required=True),
    Setting('controller.offset', 'offset', 'double', 0.01, 'm',
            'offset l of the control point ahead of the axle, non-zero', required=True,
            low=-MAX_COORDINATE, high=MAX_COORDINATE),
    Setting('controller.law', 'law', 'string', 'paper', '',
            "disturbance estimator: 'paper' (the paper's adaptive law), 'adaptive' "
            "(per-channel gains `adaptation`), 'observer' (from the measured motion)",
            choices=LAW_NAMES),
    Setting('controller.adaptation', 'adaptation', 'double[]', (1.0, 1.0), '',
            "law adaptive: multipliers (gamma_v, gamma_w) of the paper's estimator rate per "
            'channel', above=0.0),
    Setting('controller.heading', 'heading', 'string', 'paper', '',
            "'sampled': with rate_hz, each command turns the heading as the continuous law "
            "would over one period, so it cannot overshoot; 'paper': holds the continuous-time "
            'turn rate', choices=('paper', 'sampled')),
    Setting('controller.observer_rate', 'observer_rate', 'double', 5.0, '1/s',
            'law observer: bandwidth of the disturbance observer', above=0.0),
    Setting('controller.observer_growth', 'observer_growth', 'double', 1.0, '',
            "law observer with a disturbance injected on_pc: while the wheel limits saturate "
            "the command, the robot's motion shows the disturbance's direction but not its "
            'size; the observer then searches along that direction, its step doubling each '
            'tick up to this factor (observer.ray_growth; needs limits.wheel_base and '
            'max_wheel_speed); 1 = off', low=1.0),
    Setting('controller.observer_order', 'observer_order', 'int', 1, '',
            'law observer: 2 = it also estimates how fast the disturbance changes (an '
            'alpha-beta filter critically damped at observer_rate) and follows one that drifts '
            'without lag; 1 = the first-order observer', choices=(1, 2)),
    Setting('controller.estimate_latency', 'estimate_latency', 'bool', False, '',
            'estimate command_latency online, every 1 s (0.5 s until a first value) from the '
            'last 6 s of commands and poses, each fit added to those of about the last minute '
            '(core.controller.link_estimate), starting from command_latency; a new value is '
            'taken when 3 estimates in a row agree within 20 ms'),
    Setting('controller.estimate_motors', 'estimate_motors', 'bool', False, '',
            "estimate the motors' lag (limits.motor_time_constant) online where it is not "
            'told, fitted with the latency (as estimate_latency fits it; 0 to 140 ms); a new '
            "value is taken when 3 estimates in a row agree within 10 ms; and each wheel's "
            "gain (every 5 s, commands compensated once told) and the motors' dead band "
            '(limits.min_wheel_speed, every 5 s, taken when 2 fits in a row agree within 20 %: '
            'core.controller.dead_band_estimate); told values win'),
    Setting('controller.motor_check', 'motor_check', 'bool', False, '',
            'before the first curve, each robot turns in place for about 8 s while its '
            "controller measures each wheel's gain and the motors' dead band "
            '(core.controller.motor_probe; the curve server starts the schedule once every '
            'controller is done); they are then used as estimate_motors uses its estimates '
            '(told values win). Needs limits.wheel_base and max_wheel_speed'),
    Setting('controller.predict_pose', 'predict_pose', 'bool', False, '',
            "carry the robot's pose forward from its stamp (capture time) to the tick, through "
            'the commands sent since, so a pose that is 80 ms old does not make an 80 ms old '
            'command (pose source and controllers with synchronised clocks)'),
    Setting('controller.command_latency', 'command_latency', 'double', 0.0, 's',
            "the delay from a command leaving the PC to the robot's wheels (the link's, e.g. "
            'Wi-Fi and the bridge): with predict_pose the pose (and the other robots, for the '
            'safety filter) is carried forward to when the command acts; the observer compares '
            'each motion with the commands acting over it and waits for the motion that '
            'answers its estimate', low=0.0, high=0.5),
    Setting('controller.feed_forward', 'feed_forward', 'bool', True, '',
            "a moving curve's velocity at each target, G(s_i) xi-dot, is added to the command, "
            'so the formation keeps up instead of lagging (curves[].motion)'),
    Setting('controller.reverse', 'reverse', 'bool', False, '',
            'a robot may drive backwards, steering the point behind its axle onto its target, '
            'when turning round and driving forwards would take longer (needs '
            "limits.wheel_base and max_wheel_speed to time both); false = the paper's forwards "
            'only'),
    Setting('controller.tail.radius', 'tail_radius', 'double', 0.0, 'm',
            'feedback size below which the law speeds up as the square root of it instead of '
            'linearly (a finite-time tail); 0 (no `tail`) = off', above=0.0, required=True),
    Setting('controller.tail.gain', 'tail_gain', 'double', 1.0, '',
            'cap on the finite-time speed-up (the gain is at most k1 gain)', low=1.0,
            required=True),
    Setting('limits.wheel_base', 'wheel_base', 'double', 0.0, 'm',
            'distance between the wheels; 0 (no `limits`) = no wheel limit', above=0.0,
            required=True),
    Setting('limits.max_wheel_speed', 'max_wheel_speed', 'double', INF, 'm/s',
            'max linear speed of each wheel', above=0.0, required=True, unlimited=True),
    Setting('limits.max_angular_rate', 'max_angular_rate', 'double', INF, 'rad/s',
            'max |w|', above=0.0, unlimited=True),
    Setting('limits.max_linear_accel', 'max_linear_accel', 'double', INF, 'm/s^2',
            'max dv/dt', above=0.0, unlimited=True),
    Setting('limits.max_angular_accel', 'max_angular_accel', 'double', INF, 'rad/s^2',
            'max dw/dt', above=0.0, unlimited=True),
    Setting('limits.min_wheel_speed', 'min_wheel_speed', 'double', 0.0, 'm/s',
            "the slowest wheel speed the robots' motors turn at: a smaller command leaves the "
            'wheel still (a dead band); the observer then expects no motion from it instead of '
            "learning a disturbance, and the paper's estimator does not integrate. Measure "
            'it on your robots (measure-link) or estimate it online (estimate_motors); 0 = '
            'none', low=0.0),
    Setting('limits.motor_time_constant', 'motor_time_constant', 'double', 0.0, 's',
            "the first-order lag with which the robots' wheels follow their commands: the "
            'observer compares each measured motion with what the commands realised through '
            'it. Measure it on your robots (a step response); 0 = none', low=0.0, high=1.0),
    Setting('safety.pose_timeout', 'pose_timeout', 'double', 0.5, 's',
            "a robot's own pose older than this stops it", above=0.0),
    Setting('safety.neighbour_timeout', 'neighbour_timeout', 'double', 0.5, 's',
            "an in-neighbour's state older than this stops the robot", above=0.0),
    Setting('safety.leader_timeout', 'leader_timeout', 'double', 1.0, 's',
            'no news from the leader (relayed by the neighbours) for this long stops a '
            'follower', above=0.0),
    Setting('robots.radius', 'radius', 'double', 0.0, 'm',
            'body radius: a disc around the axle centre that no other body or wall may enter; '
            '0 = points that pass through each other (the paper)', low=0.0),
    Setting('avoidance.margin', 'avoidance_margin', 'double', 0.02, 'm',
            'extra distance kept between two bodies and from the walls: covers pose latency '
            'and the arc a robot draws within a tick', low=0.0),
    Setting('avoidance.rate', 'avoidance_rate', 'double', 5.0, '1/s',
            'barrier rate alpha: how fast a robot may close the distance to the safe one; at '
            'most the control rate', above=0.0),
    Setting('avoidance.passing', 'passing', 'double', 0.0, '',
            'passing rule: sideways speed to the right per unit of approach speed towards a '
            'robot nearby; 0 = none', low=0.0),
    Setting('avoidance.passing_range', 'passing_range', 'double', 0.0, 'm',
            'gap above the safe distance within which a robot steers around others and gives '
            'way; 0 = one body diameter', low=0.0),
    Setting('avoidance.drift', 'avoidance_drift', 'double', 0.0, 'm/s',
            "forward drift the barriers hold against beyond what the command cancels: a bound "
            "on the robots' drift before the observer has learnt it; 0 = none", low=0.0),
)


def default(key: str) -> Any:
    """The default of setting `key` (KeyError naming it if there is no such setting)."""
    return SETTINGS[key].default


def by_parameter() -> dict[str, Setting]:
    """The settings by their ROS parameter's name."""
    return {s.parameter: s for s in SETTINGS.values()}


@dataclass(frozen=True)
class Rule:
    """A rule that ties settings together: check(values) says what breaks it, or None;
    values maps setting keys (and 'controller.rate_hz', 'avoidance.on') to their values.
    `key` names the setting a broken rule is reported on.
    """

    key: str
    check: Callable[[Mapping[str, Any]], str | None]


def _wheel_limits_time(values: Mapping[str, Any]) -> bool:
    return (values['limits.wheel_base'] > 0.0
            and 0.0 < values['limits.max_wheel_speed'] < math.inf)


RULES = (
    Rule('controller.offset', lambda v: 'the offset l must be non-zero'
         if v['controller.offset'] == 0.0 else None),
    Rule('controller.tail.gain', lambda v: (
        f"tail.gain {v['controller.tail.gain']:g} times k1 {v['controller.k1']:g} must stay "
        f"below rate_hz {v['controller.rate_hz']:g}: a sampled command would overshoot the "
        'target')
        if v['controller.tail.radius'] > 0.0 and v['controller.rate_hz']
        and v['controller.k1'] * v['controller.tail.gain'] >= v['controller.rate_hz']
        else None),
    Rule('controller.reverse', lambda v: 'needs limits.wheel_base and limits.max_wheel_speed '
         '(> 0) to time a trip forwards and backwards'
         if v['controller.reverse'] and not _wheel_limits_time(v) else None),
    Rule('controller.motor_check', lambda v: 'needs limits.wheel_base and '
         'limits.max_wheel_speed (> 0): the check turns each robot at a share of its fastest '
         'wheel speed' if v['controller.motor_check'] and not _wheel_limits_time(v) else None),
    Rule('controller.observer_growth', lambda v: 'needs limits.wheel_base and '
         'limits.max_wheel_speed (> 0): it acts while the wheel limits saturate the command'
         if v['controller.observer_growth'] > 1.0 and not _wheel_limits_time(v) else None),
    Rule('avoidance.rate', lambda v: (
        f"the barrier rate must not exceed the control rate ({v['controller.rate_hz']:g} Hz), "
        f"got {v['avoidance.rate']:g} /s: a robot could close more than the whole distance "
        'to the safe one in one tick')
        if v['avoidance.on'] and v['controller.rate_hz']
        and v['avoidance.rate'] > v['controller.rate_hz'] else None),
)


def broken_rules(values: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(key, what is wrong) of every rule that `values` break (Rule)."""
    found = []
    for rule in RULES:
        problem = rule.check(values)
        if problem is not None:
            found.append((rule.key, problem))
    return found
