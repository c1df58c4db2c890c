"""Curves that move: a phase's curve carried by a similarity transform that changes in time.

At time tau (s) after its phase starts, a moving curve is c_tau(s) = A(tau) (c_0(s) - p) + p +
v tau, with A(tau) = exp(sigma tau) R(omega tau): it translates at v (m/s), turns at omega
(rad/s) and grows at the relative rate sigma (1/s), about the point p (m, arena frame). The
map is affine in the points, so a curve's coefficients, every target point and their
velocities (the feed-forward G(s_i) xi-dot of the law) follow from the same A, A-dot.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray, Point
from curve_formation.core.formation.curves import Basis, Curve


@dataclass(frozen=True)
class CurveMotion:
    """velocity (m/s), rotation_rate (rad/s), scale_rate (1/s) about `about` (m)."""

    velocity: Point = (0.0, 0.0)
    rotation_rate: float = 0.0
    scale_rate: float = 0.0
    about: Point = (0.0, 0.0)

    def matrices(self, tau: float) -> tuple[FloatArray, FloatArray]:
        """(A(tau), dA/dtau) (2 x 2)."""
        angle = self.rotation_rate * tau
        grow = math.exp(self.scale_rate * tau)
        rotation = np.array([[math.cos(angle), -math.sin(angle)],
                             [math.sin(angle), math.cos(angle)]])
        turn = np.array([[0.0, -self.rotation_rate], [self.rotation_rate, 0.0]])
        return grow * rotation, grow * (self.scale_rate * rotation + rotation @ turn)

    def points(self, points: ArrayLike, tau: float) -> FloatArray:
        """Where points (k, 2) of the curve at tau = 0 are at tau (m)."""
        a, _ = self.matrices(tau)
        p = np.asarray(self.about, float)
        return (np.asarray(points, float) - p) @ a.T + p + np.asarray(self.velocity) * tau

    def points_each(self, points: ArrayLike, taus: ArrayLike) -> FloatArray:
        """Where each of points (k, 2) of the curve at tau = 0 is at its own taus[k] (s), m."""
        taus = np.asarray(taus, float)
        angle = self.rotation_rate * taus
        grow = np.exp(self.scale_rate * taus)
        rel = np.asarray(points, float) - np.asarray(self.about, float)
        cos, sin = grow * np.cos(angle), grow * np.sin(angle)
        moved = np.stack([cos * rel[:, 0] - sin * rel[:, 1], sin * rel[:, 0] + cos * rel[:, 1]],
                         axis=-1)
        return moved + np.asarray(self.about, float) + np.outer(taus, self.velocity)

    def velocities(self, points: ArrayLike, tau: float) -> FloatArray:
        """Velocities (k, 2) (m/s) at tau of the points (k, 2) given at tau = 0."""
        _, rate = self.matrices(tau)
        return ((np.asarray(points, float) - np.asarray(self.about, float)) @ rate.T
                + np.asarray(self.velocity))

    def curve(self, curve: Curve, tau: float) -> Curve:
        """The curve at tau, in the same basis (exact: the basis holds the constant)."""
        a, _ = self.matrices(tau)
        shift = np.asarray(self.about, float) + np.asarray(self.velocity) * tau
        return self._mapped(curve, a, shift - np.asarray(self.about, float) @ a.T)

    def rate(self, curve: Curve, tau: float) -> Curve:
        """d/dtau of the curve's coefficients at tau as a Curve: its points(s) are the
        velocities G(s) xi-dot (m/s) of the curve's points.
        """
        _, rate = self.matrices(tau)
        return self._mapped(curve, rate, np.asarray(self.velocity)
                            - np.asarray(self.about, float) @ rate.T)

    def elapsed(self, curve: Curve, moved: Curve, guess: float, window: float = 5.0
                ) -> float | None:
        """tau (s) at which this motion takes `curve` (tau = 0) to `moved`, searched within
        `window` s of `guess`; None where the motion does not tell: `moved` is the curve as
        it is, or no curve of this motion (its coefficients 1 um or more from the nearest).
        """
        # Imported here: only a run's analysis needs it, not a node's start-up.
        from scipy.optimize import minimize_scalar
        if np.allclose(moved.coeffs, curve.coeffs, rtol=0.0, atol=1e-15):
            return None

        def mismatch(tau: float) -> float:
            return float(((self.curve(curve, tau).coeffs - moved.coeffs) ** 2).sum())

        found = minimize_scalar(mismatch, bounds=(max(0.0, guess - window), guess + window),
                                method='bounded', options={'xatol': 1e-7})
        return float(found.x) if math.sqrt(found.fun) < 1e-6 else None

    @staticmethod
    def _mapped(curve: Curve, linear: FloatArray, shift: FloatArray) -> Curve:
        """The curve s -> linear c(s) + shift."""
        basis = curve.basis
        coeffs = curve.coeffs @ linear.T + np.outer(constant_coefficients(basis), shift)
        return Curve(basis, basis.from_matrix(coeffs))


def constant_coefficients(basis: Basis) -> FloatArray:
    """(H,) the coefficients w with phi(s) w = 1 for every s (Fourier and polynomial bases
    both hold the constant function).
    """
    s = np.linspace(0.0, 1.0, 2 * basis.H + 1)
    w, *_ = np.linalg.lstsq(basis.phi(s), np.ones(len(s)), rcond=None)
    return np.where(np.abs(w) < 1e-12, 0.0, w)
