"""Planar parametric curves c(s) = G(s) xi, s in [0, 1], and least-squares fitting.

Coefficient layout follows the paper exactly:

- Fourier (closed), K harmonics, H = 2K + 1: G(s) = [g_1 .. g_K, I_2] with
  g_h = [[cos 2 pi h s, sin 2 pi h s, 0, 0], [0, 0, cos 2 pi h s, sin 2 pi h s]], so
  xi = [ax_1, bx_1, ay_1, by_1, ..., ax_K, bx_K, ay_K, by_K, x_0, y_0].
- Polynomial (open), order p, H = p + 1: G(s) = [1, s, .., s^p] kron I_2, so
  xi = [x_0, y_0, x_1, y_1, ..., x_p, y_p].

Internally both are written as c(s) = C^T phi(s) with a scalar basis phi(s) (H values) and a
coefficient matrix C (H x 2); :meth:`Basis.to_matrix` and :meth:`Basis.from_matrix` convert
between C and the paper's xi. Units of c and xi are those of the arena (metres on the robots).
"""

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray, IntArray


# The largest bases: an experiment's curves (config_schema) and a curve message
# (curve_codec) are held to them. Beyond order ~30 a monomial basis is numerically singular.
MAX_HARMONICS = 5_000
MAX_ORDER = 30


class CurveError(ValueError):
    """A basis or fit that cannot be built as asked."""


_LAYOUTS: dict[tuple[type, int], tuple[IntArray, IntArray]] = {}   # Basis._layout's


class Basis:
    """Scalar basis phi(s) of H functions shared by both coordinates."""

    kind = ''
    closed = False

    def __init__(self, size: int) -> None:
        self.H = int(size)

    def phi(self, s: ArrayLike) -> FloatArray:
        """Scalar basis at s: array (m, H) for s of shape (m,)."""
        raise NotImplementedError

    def dphi(self, s: ArrayLike) -> FloatArray:
        """Derivative d phi / ds at s: array (m, H)."""
        raise NotImplementedError

    def to_matrix(self, xi: ArrayLike) -> FloatArray:
        """Paper coefficients xi (2H,) -> coefficient matrix C (H, 2)."""
        raise NotImplementedError

    def from_matrix(self, coeffs: ArrayLike) -> FloatArray:
        """Coefficient matrix C (H, 2) -> paper coefficients xi (2H,)."""
        raise NotImplementedError

    def G(self, s: ArrayLike) -> FloatArray:  # noqa: N802 - the paper's name
        """The paper's G(s): array (m, 2, 2H) for s of shape (m,), built from the layout."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        # Column k of G(s) is G(s) e_k = C_k^T phi(s) with C_k = to_matrix(e_k), whose one
        # non-zero entry (h_k, c_k) puts phi_{h_k}(s) in row c_k.
        rows, coords = self._layout()
        out = np.zeros((len(s), 2, 2 * self.H))
        out[:, coords, np.arange(2 * self.H)] = self.phi(s)[:, rows]
        return out

    def stacked(self, s: ArrayLike) -> FloatArray:
        """The paper's G_bar (2m, 2H): G(s_i) for the m agents' s stacked row-wise."""
        return self.G(s).reshape(-1, 2 * self.H)

    def _layout(self) -> tuple[IntArray, IntArray]:
        """(h_k, c_k) for each coefficient k: where to_matrix puts e_k, found once a process
        for each kind and size (every curve message decodes to a basis of its own: rebuilt
        for each, it cost a grouped controller 1.3 ms of the 2 ms it took a new curve).
        """
        found = _LAYOUTS.get((type(self), self.H))
        if found is None:
            eye = np.eye(2 * self.H)
            where = [np.argwhere(self.to_matrix(eye[k]))[0] for k in range(2 * self.H)]
            found = (np.array([w[0] for w in where]), np.array([w[1] for w in where]))
            _LAYOUTS[type(self), self.H] = found
        return found

    def describe(self) -> str:
        """Short label such as 'fourier K=6 (H=13)'."""
        raise NotImplementedError


class FourierBasis(Basis):
    """Truncated Fourier series with K harmonics (closed curves), H = 2K + 1."""

    kind = 'fourier'
    closed = True

    def __init__(self, harmonics: int) -> None:
        if int(harmonics) < 1:
            raise CurveError(f'a Fourier basis needs at least 1 harmonic, got {harmonics}')
        self.K = int(harmonics)
        super().__init__(2 * self.K + 1)

    def phi(self, s: ArrayLike) -> FloatArray:
        angle = 2 * np.pi * np.multiply.outer(np.atleast_1d(s), np.arange(1, self.K + 1))
        out = np.empty(angle.shape[:-1] + (self.H,))
        out[..., 0:-1:2] = np.cos(angle)
        out[..., 1:-1:2] = np.sin(angle)
        out[..., -1] = 1.0
        return out

    def dphi(self, s: ArrayLike) -> FloatArray:
        h = 2 * np.pi * np.arange(1, self.K + 1)
        angle = np.multiply.outer(np.atleast_1d(s), h)
        out = np.empty(angle.shape[:-1] + (self.H,))
        out[..., 0:-1:2] = -h * np.sin(angle)
        out[..., 1:-1:2] = h * np.cos(angle)
        out[..., -1] = 0.0
        return out

    def to_matrix(self, xi: ArrayLike) -> FloatArray:
        xi = np.asarray(xi, dtype=float)
        harmonics = xi[:-2].reshape(self.K, 2, 2)   # [h, coordinate, cos/sin]
        return np.vstack([harmonics.transpose(0, 2, 1).reshape(2 * self.K, 2), xi[-2:]])

    def from_matrix(self, coeffs: ArrayLike) -> FloatArray:
        coeffs = np.asarray(coeffs, dtype=float)
        harmonics = coeffs[:-1].reshape(self.K, 2, 2).transpose(0, 2, 1)
        return np.concatenate([harmonics.ravel(), coeffs[-1]])

    def describe(self) -> str:
        return f'fourier K={self.K} (H={self.H})'


class PolynomialBasis(Basis):
    """Polynomial of order p in s (open curves), H = p + 1."""

    kind = 'polynomial'
    closed = False

    def __init__(self, order: int) -> None:
        if int(order) < 1:
            raise CurveError(f'a polynomial basis needs order >= 1, got {order}')
        self.p = int(order)
        super().__init__(self.p + 1)

    def phi(self, s: ArrayLike) -> FloatArray:
        return np.power.outer(np.atleast_1d(np.asarray(s, dtype=float)), np.arange(self.H))

    def dphi(self, s: ArrayLike) -> FloatArray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        k = np.arange(self.H)
        return k * np.power.outer(s, np.maximum(k - 1, 0))

    def to_matrix(self, xi: ArrayLike) -> FloatArray:
        return np.asarray(xi, dtype=float).reshape(self.H, 2)

    def from_matrix(self, coeffs: ArrayLike) -> FloatArray:
        return np.asarray(coeffs, dtype=float).ravel()

    def describe(self) -> str:
        return f'polynomial p={self.p} (H={self.H})'


def make_basis(kind: str, size: int) -> Basis:
    """Basis by name: ('fourier', K harmonics) or ('polynomial', order p)."""
    if kind == 'fourier':
        return FourierBasis(size)
    if kind == 'polynomial':
        return PolynomialBasis(size)
    raise CurveError(f"unknown basis {kind!r}; expected 'fourier' or 'polynomial'")


@dataclass(frozen=True)
class Curve:
    """A fitted curve: basis and paper coefficients xi (2H,)."""

    basis: Basis
    xi: FloatArray

    @property
    def coeffs(self) -> FloatArray:
        """Coefficient matrix C (H, 2)."""
        return self.basis.to_matrix(self.xi)

    def points(self, s: ArrayLike) -> FloatArray:
        """Positions c(s): array (m, 2)."""
        return self.basis.phi(s) @ self.coeffs

    def tangents(self, s: ArrayLike) -> FloatArray:
        """Derivatives dc/ds: array (m, 2)."""
        return self.basis.dphi(s) @ self.coeffs

    def matches(self, other: 'Curve', atol: float = 1e-12) -> bool:
        """The same basis and coefficients within atol (units of c): the same curve as sent
        again, or as the schedule has it.
        """
        return (self.basis.describe() == other.basis.describe()
                and np.allclose(self.xi, other.xi, rtol=0.0, atol=atol))

    def outline(self, count: int = 400) -> FloatArray:
        """(count or count + 1, 2) points to draw the curve through: `sample`'s, a closed
        curve's first point repeated last so that the line closes (m).
        """
        _, pts = self.sample(count)
        return np.vstack([pts, pts[:1]]) if self.basis.closed else pts

    def sample(self, count: int = 400) -> tuple[FloatArray, FloatArray]:
        """count points evenly spaced in s (closed curves exclude s = 1): (s, points)."""
        s = np.linspace(0.0, 1.0, count, endpoint=not self.basis.closed)
        return s, self.points(s)

    def size(self) -> float:
        """Characteristic size: diagonal of the bounding box of a dense sample (units of c)."""
        _, pts = self.sample(1000)
        return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))

    def arc_length_table(self, count: int = 4000) -> tuple[FloatArray, FloatArray]:
        """Cumulative arc length at s = linspace(0, 1, count): (s, length) by trapezoids."""
        s = np.linspace(0.0, 1.0, count)
        speed = np.linalg.norm(self.tangents(s), axis=1)
        length = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(s))])
        return s, length


@dataclass(frozen=True)
class Fit:
    """Result of a least-squares fit: the curve and its residuals at the samples (units of c)."""

    curve: Curve
    rms_residual: float
    max_residual: float
    samples: int


def fit_curve(basis: Basis, s: ArrayLike, points: ArrayLike) -> Fit:
    """Least-squares coefficients for sampled points.

    Solves G_h xi = C (the paper's eq. for xi) with lstsq. Because G_h is a row/column
    permutation of phi kron I_2, this is the same solution as lstsq(phi, points).

    Args:
        basis: the Basis to fit.
        s: (N,) curve parameters of the samples, in [0, 1].
        points: (N, 2) sampled positions.
    """
    s = np.asarray(s, dtype=float).ravel()
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) != len(s):
        raise CurveError(f'expected (N, 2) points matching {len(s)} parameters, '
                         f'got shape {points.shape}')
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(s))):
        raise CurveError('sampled points or parameters contain NaN or infinity')
    if len(s) <= basis.H:
        raise CurveError(f'fitting {basis.describe()} needs more than H = {basis.H} sampled '
                         f'points, got {len(s)}')
    phi = basis.phi(s)
    coeffs, _, rank, _ = np.linalg.lstsq(phi, points, rcond=None)
    if rank < basis.H:
        raise CurveError(f'the samples do not determine {basis.describe()}: the stacked basis '
                         f'has rank {rank} < H = {basis.H} (too few distinct s values?)')
    residual = np.linalg.norm(phi @ coeffs - points, axis=1)
    return Fit(Curve(basis, basis.from_matrix(coeffs)), float(np.sqrt(np.mean(residual ** 2))),
               float(residual.max()), len(s))
