"""The curve's wire layout and planar quaternions, free of any message library.

A curve travels as a flat array xi (2H values, the paper's layout) with three labelled
dimensions: ('xi', 2H, 2H), ('basis=<fourier|polynomial>', K or p, 0), ('curve_id=<k>', 0, 0);
for a moving curve, ('xi_dot', 2H, 2H): the coefficients' rate (per second) follows them; when
the sender dates the curve, ('clock', 3, 3): the time (s, the sender's ROS clock) at which the
coefficients are as given, how long (s) the curve had been moving then (the curve's own time,
0 for a still curve) and the run's time then (s since the first curve; a 2-value clock leaves
it unknown); and when the sender assigns the agents' parameters, ('s', n, n),
whose n values s_1..s_n come last.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.formation.curves import (
    Curve,
    FourierBasis,
    make_basis,
    MAX_HARMONICS,
    MAX_ORDER,
    PolynomialBasis,
)


class CodecError(ValueError):
    """A curve message that cannot be decoded."""


@dataclass(frozen=True)
class CurveClock:
    """When a curve message's coefficients hold: valid_at (s, the sender's ROS clock), and
    moving_for (s), how long the curve had then been moving (its own time; 0: still). A
    receiver on the same clock carries a moving curve from valid_at, not from the message's
    arrival, and dates the motion's start at valid_at - moving_for.
    """

    valid_at: float
    moving_for: float = 0.0
    run_time: float | None = None   # s since the run's first curve, at valid_at

    @property
    def motion_began(self) -> float:
        """When the curve began moving (s, the sender's clock)."""
        return self.valid_at - self.moving_for

    @property
    def run_start(self) -> float | None:
        """When the run's first curve was sent (s, the sender's clock), if known."""
        return None if self.run_time is None else self.valid_at - self.run_time

    def since(self, t0: float) -> 'CurveClock':
        """The same clock counted from t0 (s, the sender's clock)."""
        return CurveClock(self.valid_at - t0, self.moving_for, self.run_time)


# Curve ids are whole numbers 0..MAX_CURVE_ID; they also travel in doubles (a neighbour's
# state), which hold every such integer exactly.
MAX_CURVE_ID = 2 ** 31 - 1


def curve_id_from_text(text: str) -> int:
    """A curve id from its label text ('curve_id=<k>'); CodecError unless a whole number in
    0..MAX_CURVE_ID.
    """
    if not (text.isdigit() and len(text) <= 10 and int(text) <= MAX_CURVE_ID):
        raise CodecError(f'curve id {text[:20]!r}{"..." if len(text) > 20 else ""} is not a '
                         f'whole number in 0..{MAX_CURVE_ID}')
    return int(text)


def curve_id_from_float(value: float) -> int:
    """A curve id carried in a double; CodecError unless a whole number in 0..MAX_CURVE_ID."""
    if not (math.isfinite(value) and value == int(value) and 0 <= value <= MAX_CURVE_ID):
        raise CodecError(f'curve id {value!r} is not a whole number in 0..{MAX_CURVE_ID}')
    return int(value)


def encode_curve(curve: Curve, curve_id: int, s: Sequence[float] | FloatArray | None = None,
                 rate: Curve | None = None, clock: 'CurveClock | None' = None
                 ) -> tuple[list[tuple[str, int, int]], list[float]]:
    """(dims, data): dims [(label, size, stride)], data the 2H coefficients, then the 2H of
    `rate` (a Curve of the coefficients' rate, 1/s) if the curve moves, then `clock` if given
    (CurveClock), then s (n,) if given (the agents' curve parameters).
    """
    basis = curve.basis
    if isinstance(basis, FourierBasis):
        size = basis.K
    elif isinstance(basis, PolynomialBasis):
        size = basis.p
    else:
        raise CodecError(f'a curve of basis {basis.kind!r} cannot be encoded')
    dims = [('xi', 2 * basis.H, 2 * basis.H), (f'basis={basis.kind}', int(size), 0),
            (f'curve_id={int(curve_id)}', 0, 0)]
    data = [float(v) for v in curve.xi]
    if rate is not None:
        dims.append(('xi_dot', 2 * basis.H, 2 * basis.H))
        data += [float(v) for v in rate.xi]
    if clock is not None:
        values = [clock.valid_at, clock.moving_for] + (
            [] if clock.run_time is None else [clock.run_time])
        dims.append(('clock', len(values), len(values)))
        data += [float(v) for v in values]
    if s is not None:
        dims.append(('s', len(s), len(s)))
        data += [float(v) for v in s]
    return dims, data


def decode_curve(dims: Sequence[tuple[str, int]], data: Sequence[float]) -> tuple[Curve, int]:
    """(Curve, curve_id) from [(label, size)] and the coefficients; CodecError if malformed."""
    labels = {label.split('=')[0]: (label, size) for label, size in dims}
    try:
        kind = labels['basis'][0].split('=', 1)[1]
        curve_id = curve_id_from_text(labels['curve_id'][0].split('=', 1)[1])
        size = int(labels['basis'][1])
        largest = {'fourier': MAX_HARMONICS, 'polynomial': MAX_ORDER}.get(kind, 0)
        if not 1 <= size <= largest:
            raise CodecError(f'basis {kind[:20]!r} of size {size}: expected fourier of 1..'
                             f'{MAX_HARMONICS} harmonics or polynomial of order 1..{MAX_ORDER}')
        basis = make_basis(kind, size)
    except CodecError:
        raise
    except (KeyError, IndexError, ValueError) as exc:
        raise CodecError(f'curve message layout not understood: {exc}') from None
    values = np.array(data, dtype=float)
    n_s = labels['s'][1] if 's' in labels else 0
    n_rate = labels['xi_dot'][1] if 'xi_dot' in labels else 0
    n_clock = labels['clock'][1] if 'clock' in labels else 0
    if n_clock not in (0, 2, 3):
        raise CodecError(f'curve message has a clock of {n_clock} values, expected 2 or 3')
    xi = values[:len(values) - n_s - n_rate - n_clock]
    if n_rate not in (0, 2 * basis.H):
        raise CodecError(f'curve message has {n_rate} coefficient rates, {basis.describe()} '
                         f'needs {2 * basis.H}')
    if len(xi) != 2 * basis.H:
        raise CodecError(f'curve message has {len(xi)} coefficients, {basis.describe()} '
                         f'needs {2 * basis.H}')
    if not np.all(np.isfinite(values)):
        raise CodecError('curve message has NaN or infinite values')
    return Curve(basis, xi), curve_id


def decode_curve_rate(dims: Sequence[tuple[str, int]], data: Sequence[float]
                      ) -> Curve | None:
    """The coefficients' rate of a moving curve as a Curve (its points(s) are the velocities
    of the curve's points, m/s), or None for a still curve; call after decode_curve.
    """
    sizes = {label.split('=')[0]: size for label, size in dims}
    if 'xi_dot' not in sizes:
        return None
    curve, _ = decode_curve(dims, data)
    start = 2 * curve.basis.H
    return Curve(curve.basis, np.array(data[start:start + int(sizes['xi_dot'])], dtype=float))


def decode_curve_clock(dims: Sequence[tuple[str, int]], data: Sequence[float]
                       ) -> 'CurveClock | None':
    """The CurveClock a curve message carries, or None; call after decode_curve."""
    sizes = {label.split('=')[0]: size for label, size in dims}
    if 'clock' not in sizes:
        return None
    curve, _ = decode_curve(dims, data)
    start = 2 * curve.basis.H + int(sizes.get('xi_dot', 0))
    values = [float(v) for v in data[start:start + int(sizes['clock'])]]
    if values[1] < 0.0:
        raise CodecError(f'curve message says the curve has moved for {values[1]:g} s')
    if len(values) == 3 and values[2] < 0.0:
        raise CodecError(f'curve message says the run is {values[2]:g} s old')
    return CurveClock(*values)


def decode_agent_parameters(dims: Sequence[tuple[str, int]], data: Sequence[float]
                            ) -> FloatArray | None:
    """The agents' parameters s (n,) a curve message carries, or None if it has none."""
    sizes = {label: size for label, size in dims}
    if 's' not in sizes:
        return None
    n_s = int(sizes['s'])
    if n_s < 1 or n_s > len(data):
        raise CodecError(f'curve message announces {n_s} agent parameters but holds '
                         f'{len(data)} values')
    return np.array(data[len(data) - n_s:], dtype=float)


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Heading (rad) about +z of a quaternion."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_from_yaw(theta: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by theta (rad) about +z."""
    return 0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0)
