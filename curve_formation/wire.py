"""What goes over the last link to a robot: wheel speeds, as the text its firmware reads.

Units: body velocities v (m/s), w (rad/s); wheel speeds as the wheels' rim speed (m/s) or their
angular speed (rad/s, rim speed over the wheel radius); wheel base B and radius r in metres.

A wire format is a line template with named fields, `{left}`, `{right}` (wheel speeds in the
format's unit) and `{seq}` (a sequence number), and a stop line; both end with their
terminator. The same format parses the lines back (the emulated robot, and tests), so what the
bridge writes and what a robot reads cannot drift apart.
"""

from dataclasses import dataclass
import functools
import math
import re
import string

from curve_formation.core.controller.limits import saturate
from curve_formation.core.formation.dynamics import wheel_speeds


class WireError(ValueError):
    """A wire format that cannot be used; the message says why."""


@dataclass(frozen=True)
class WireFormat:
    """command: template with {left} and {right} (and optionally {seq}); stop: the stop line
    (may use {seq}); unit: 'rad/s' or 'm/s' for the wheel speeds; both with terminators.
    """

    command: str
    stop: str
    unit: str = 'rad/s'


# The formats we know of. mona-serial: a published closed-loop wheel-speed firmware for Mona
# (serial, 115200 baud): `set <left_rad_s> <right_rad_s>` and `stop`. wheel-m-s: rim speeds with
# a sequence number, for a UDP firmware that drops out-of-order datagrams. json: one JSON
# object a line.
PRESETS = {
    'mona-serial': WireFormat('set {left:.3f} {right:.3f}\n', 'stop\n', 'rad/s'),
    'wheel-m-s': WireFormat('W {seq} {left:.5f} {right:.5f}\n', 'S {seq}\n', 'm/s'),
    'json': WireFormat('{{"seq": {seq}, "left": {left:.5f}, "right": {right:.5f}}}\n',
                       '{{"seq": {seq}, "stop": true}}\n', 'm/s'),
}
FIELDS = ('left', 'right', 'seq')
DEFAULT_PRESET = 'mona-serial'   # what a robot bridge writes unless told


def wire_format(preset='', command='', stop='', unit='rad/s'):
    """The WireFormat of a preset name, or of templates given in full; WireError if unusable."""
    if preset:
        if preset not in PRESETS:
            raise WireError(f'unknown wire format {preset!r}; presets: {", ".join(PRESETS)}')
        return PRESETS[preset]
    fmt = WireFormat(command, stop, unit)
    check(fmt)
    return fmt


def check(fmt):
    """Refuse a format the bridge could not fill or the robot could not read back."""
    if fmt.unit not in ('rad/s', 'm/s'):
        raise WireError(f"wire unit must be 'rad/s' or 'm/s', got {fmt.unit!r}")
    for name, template, needed in (('command', fmt.command, {'left', 'right'}),
                                   ('stop', fmt.stop, set())):
        fields = _fields(template, name)
        if not needed <= fields:
            raise WireError(f'the {name} template {template!r} lacks {sorted(needed - fields)}')
        if not template:
            raise WireError(f'the {name} template is empty')
    if _pattern(fmt.command).pattern == _pattern(fmt.stop).pattern:
        raise WireError('the command and stop templates cannot be told apart')


def _fields(template, name):
    try:
        fields = {field for _, field, _, _ in string.Formatter().parse(template) if field}
    except ValueError as exc:
        raise WireError(f'the {name} template {template!r}: {exc}') from None
    unknown = fields - set(FIELDS)
    if unknown:
        raise WireError(f'the {name} template {template!r} has unknown fields '
                        f'{sorted(unknown)}; known: {", ".join(FIELDS)}')
    return fields


def saturated_wheel_speeds(v, w, wheel_base, max_wheel_speed):
    """(left, right) rim speeds (m/s) of (v, w), scaled down together (keeping the curvature
    w / v) when a wheel would exceed max_wheel_speed (0 or infinity: no limit).
    """
    v, w = saturate(v, w, wheel_base, max_wheel_speed, math.inf)
    return wheel_speeds(v, w, wheel_base)


def encode(fmt, left, right, seq, wheel_radius):
    """The command line (bytes) for rim speeds left, right (m/s) and sequence number seq."""
    scale = 1.0 / wheel_radius if fmt.unit == 'rad/s' else 1.0
    return fmt.command.format(left=left * scale, right=right * scale, seq=seq).encode()


def encode_stop(fmt, seq):
    return fmt.stop.format(seq=seq).encode()


def decode(fmt, line, wheel_radius):
    """What a line of `fmt` says: ('command', left, right, seq) with rim speeds in m/s,
    ('stop', seq), or None for a line that is neither (seq None where the format has none).
    """
    text = line.decode(errors='replace') if isinstance(line, bytes) else line
    match = _pattern(fmt.command).fullmatch(text)
    if match:
        scale = wheel_radius if fmt.unit == 'rad/s' else 1.0
        left, right = float(match['left']) * scale, float(match['right']) * scale
        if not (math.isfinite(left) and math.isfinite(right)):
            return None
        return 'command', left, right, _seq(match)
    match = _pattern(fmt.stop).fullmatch(text)
    if match:
        return 'stop', _seq(match)
    return None


def _seq(match):
    return int(match['seq']) if 'seq' in match.groupdict() else None


_NUMBER = r'[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?'


@functools.lru_cache(maxsize=64)
def _pattern(template):
    """A regex that matches the lines the template produces."""
    parts = []
    for literal, field, _, _ in string.Formatter().parse(template):
        parts.append(re.escape(literal))
        if field == 'seq':
            parts.append(r'(?P<seq>\d+)')
        elif field:
            parts.append(f'(?P<{field}>{_NUMBER})')
    return re.compile(''.join(parts))


def is_reply(line):
    """Whether a line from a robot is a firmware's answer to one of ours: 'ok' (or 'ok ...',
    e.g. with a battery voltage) or 'err'.
    """
    text = (line.decode(errors='replace') if isinstance(line, bytes) else line).strip()
    return text in ('ok', 'err') or text.startswith('ok ')


def battery(line):
    """The battery voltage (V) an answer 'ok <volts>' carries, else None."""
    parts = (line.decode(errors='replace') if isinstance(line, bytes) else line).split()
    if len(parts) == 2 and parts[0] == 'ok':
        try:
            volts = float(parts[1])
        except ValueError:
            return None
        return volts if math.isfinite(volts) else None
    return None
