"""The robots a run drives over their links, as robot_bridge and pre-flight take them: the
lab's (robots.fleet of the experiment file) or fake_arena's emulated ones (`run --bridge`).

Lengths in m, speeds in m/s.
"""

from dataclasses import dataclass

from curve_formation import wire
from curve_formation.core.config.experiment import Experiment, wheel_base, wheel_radius
from curve_formation.core.config.fleet import check_fleet, fleet_markers, LinkAddress, parse_link


@dataclass(frozen=True)
class FleetRobot:
    """One robot behind its link: agent (1-based), marker id (None: not tracked by a camera),
    link, the firmware's wire format (a wire.PRESETS name), whether it answers each line,
    and its wheels.
    """

    agent: int
    marker: int | None
    address: LinkAddress
    format: str
    replies: bool
    wheel_base: float
    wheel_radius: float

    @property
    def name(self) -> str:
        return f'robot {self.agent}'


def fleet_robots(experiment: Experiment) -> list[FleetRobot]:
    """The experiment's robots.fleet (empty if none is listed); ConfigError naming the file
    and key for a fleet that cannot be driven, a wire format not known among them.
    """
    spec = experiment.spec
    check_fleet(spec, experiment.source, tuple(wire.PRESETS))
    markers = fleet_markers(spec)
    return [FleetRobot(agent=i, marker=None if markers is None else markers[i - 1],
                       address=parse_link(robot.link),
                       format=robot.format or wire.DEFAULT_PRESET,
                       replies=robot.replies,
                       wheel_base=float(robot.wheel_base or wheel_base(experiment)),
                       wheel_radius=float(robot.wheel_radius or wheel_radius(experiment)))
            for i, robot in enumerate(spec.robots.fleet, 1)]


def emulated_fleet(experiment: Experiment, links: list[str]) -> list[FleetRobot]:
    """fake_arena's emulated robots behind `links` (one per agent), as a fleet."""
    markers = fleet_markers(experiment.spec)
    return [FleetRobot(agent=i, marker=None if markers is None else markers[i - 1],
                       address=parse_link(link), format=wire.DEFAULT_PRESET, replies=True,
                       wheel_base=wheel_base(experiment), wheel_radius=wheel_radius(experiment))
            for i, link in enumerate(links, 1)]


def bridge_parameters(experiment: Experiment, rate: float, robot: FleetRobot) -> dict:
    """robot_bridge's parameters for a robot: its link (a pseudo-terminal as a serial line),
    baud, wire format, wheels, the file's wheel speed limit and the control rate (Hz).
    """
    address = robot.address
    return {'link': address.bridge_text, 'baud': address.baud, 'wire_format': robot.format,
            'wheel_base': robot.wheel_base, 'wheel_radius': robot.wheel_radius,
            'max_wheel_speed': float(experiment.limits.max_wheel_speed),
            'rate_hz': float(rate),
            # 0: the firmware does not answer, so its silence is no lost link
            **({} if robot.replies else {'reply_timeout': 0.0})}

