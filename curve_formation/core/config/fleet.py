"""The lab's robots as an experiment file lists them (robots.fleet): how a link is written,
and the checks a fleet must pass before anything starts (one entry per agent, no marker or
link twice, markers that agree with the camera's).
"""

from typing import NamedTuple

from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.schema import ExperimentSpec


DEFAULT_BAUD = 115200   # bits/s of a serial link written without @BAUD


class LinkAddress(NamedTuple):
    """A parsed link: kind 'udp' (host, port), 'serial' (device, baud) or 'pty' (device, the
    emulated robot's end of a pseudo-terminal).
    """

    kind: str
    host: str = ''
    port: int = 0
    device: str = ''
    baud: int = DEFAULT_BAUD

    @property
    def text(self) -> str:
        """The link as robot_bridge's `link` parameter takes it (no baud)."""
        if self.kind == 'udp':
            return f'udp:{self.host}:{self.port}'
        return f'{self.kind}:{self.device}'

    @property
    def bridge_text(self) -> str:
        """The link as a robot bridge (or the pre-flight) opens it: an emulated robot's
        pseudo-terminal as a serial line.
        """
        return f'serial:{self.device}' if self.kind == 'pty' else self.text


def parse_link(text: str) -> LinkAddress:
    """The LinkAddress of 'udp:HOST:PORT', 'serial:DEVICE[@BAUD]' or 'pty:PATH'; ValueError
    saying what was expected otherwise.
    """
    kind, _, rest = str(text).partition(':')
    if kind == 'udp':
        host, _, port = rest.rpartition(':')
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f'expected udp:HOST:PORT, got {text!r}')
        return LinkAddress('udp', host=host, port=int(port))
    if kind == 'serial' and rest:
        device, at, baud = rest.partition('@')
        if at and (not baud.isdigit() or int(baud) <= 0):
            raise ValueError(f'expected serial:DEVICE@BAUD with BAUD in bits/s, got {text!r}')
        if not device:
            raise ValueError(f'expected serial:DEVICE[@BAUD], got {text!r}')
        return LinkAddress('serial', device=device, baud=int(baud) if at else DEFAULT_BAUD)
    if kind == 'pty' and rest:
        return LinkAddress('pty', device=rest)
    raise ValueError(f'expected udp:HOST:PORT, serial:DEVICE[@BAUD] or pty:PATH, got {text!r}')


def fleet_markers(spec: ExperimentSpec) -> list[int] | None:
    """Each agent's marker id: the fleet's, else camera.robot_ids; None if neither says."""
    fleet = spec.robots.fleet
    if fleet and all(robot.marker is not None for robot in fleet):
        return [int(robot.marker) for robot in fleet if robot.marker is not None]
    if spec.camera is not None:
        return list(spec.camera.robot_ids)
    return None


def check_fleet(spec: ExperimentSpec, source: str, formats: tuple[str, ...] = ()) -> None:
    """ConfigError (file, key, what was expected) for a fleet that cannot be driven: not one
    entry per agent, a link written wrongly or listed twice, a marker listed twice or other
    than the camera's robot_ids, a wire format not among `formats` (when given).
    """
    fleet = spec.robots.fleet
    if not fleet:
        return
    n = spec.agents.count
    if len(fleet) != n:
        raise ConfigError(source, 'robots.fleet', f'expected {n} robots (one per agent, agent 1 '
                          f'first), got {len(fleet)}')
    links: dict[tuple[str, str, str | int], int] = {}
    markers: dict[int, int] = {}
    for k, robot in enumerate(fleet):
        key = f'robots.fleet[{k}]'
        try:
            address = parse_link(robot.link)
        except ValueError as exc:
            raise ConfigError(source, f'{key}.link', str(exc)) from None
        if address.kind == 'pty':
            raise ConfigError(source, f'{key}.link', 'a real robot is behind serial:DEVICE or '
                              f'udp:HOST:PORT (pty: is for emulated robots), got {robot.link!r}')
        same = (address.kind, address.host or address.device, address.port)
        if same in links:
            raise ConfigError(source, f'{key}.link', f'{robot.link!r} is already robot '
                              f"{links[same] + 1}'s link")
        links[same] = k
        if formats and robot.format is not None and robot.format not in formats:
            raise ConfigError(source, f'{key}.format', f'unknown wire format {robot.format!r}; '
                              f'one of {", ".join(formats)}')
        if robot.marker is not None:
            if robot.marker in markers:
                raise ConfigError(source, f'{key}.marker', f'marker {robot.marker} is already '
                                  f"robot {markers[robot.marker] + 1}'s")
            markers[robot.marker] = k
    given = [robot.marker for robot in fleet]
    if any(m is not None for m in given) and any(m is None for m in given):
        missing = [k + 1 for k, m in enumerate(given) if m is None]
        raise ConfigError(source, 'robots.fleet', f'robots {missing} have no marker: give '
                          'every robot its marker, or none (camera.robot_ids then says)')
    camera = spec.camera
    if camera is not None and markers and list(camera.robot_ids) != given:
        raise ConfigError(source, 'robots.fleet', f'markers {given} differ from '
                          f'camera.robot_ids {list(camera.robot_ids)}: list them once, in the '
                          'fleet (leave robot_ids out) or in the camera')
