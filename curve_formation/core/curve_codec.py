"""The curve's wire layout and planar quaternions, free of any message library.

A curve travels as a flat array xi (2H values, the paper's layout) with three labelled
dimensions: ('xi', 2H, 2H), ('basis=<fourier|polynomial>', K or p, 0), ('curve_id=<k>', 0, 0).
"""

import math

import numpy as np

from curve_formation.core.curves import Curve, make_basis


class CodecError(ValueError):
    """A curve message that cannot be decoded."""


def encode_curve(curve, curve_id):
    """(dims, data): dims [(label, size, stride)], data the 2H coefficients."""
    basis = curve.basis
    size = basis.K if basis.kind == 'fourier' else basis.p
    dims = [('xi', 2 * basis.H, 2 * basis.H), (f'basis={basis.kind}', int(size), 0),
            (f'curve_id={int(curve_id)}', 0, 0)]
    return dims, [float(v) for v in curve.xi]


def decode_curve(dims, data):
    """(Curve, curve_id) from [(label, size)] and the coefficients; CodecError if malformed."""
    labels = {label.split('=')[0]: (label, size) for label, size in dims}
    try:
        kind = labels['basis'][0].split('=', 1)[1]
        curve_id = int(labels['curve_id'][0].split('=', 1)[1])
        basis = make_basis(kind, labels['basis'][1])
    except (KeyError, IndexError, ValueError) as exc:
        raise CodecError(f'curve message layout not understood: {exc}') from None
    xi = np.array(data, dtype=float)
    if len(xi) != 2 * basis.H:
        raise CodecError(f'curve message has {len(xi)} coefficients, {basis.describe()} '
                         f'needs {2 * basis.H}')
    if not np.all(np.isfinite(xi)):
        raise CodecError('curve message has NaN or infinite coefficients')
    return Curve(basis, xi), curve_id


def yaw_from_quaternion(x, y, z, w):
    """Heading (rad) about +z of a quaternion."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_from_yaw(theta):
    """(x, y, z, w) of a rotation by theta (rad) about +z."""
    return 0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0)
