import numpy as np
import pytest

from curve_formation.core.formation.curve_sources import (
    bezier_samples,
    chord_length_parameters,
    expression_samples,
)
from curve_formation.core.formation.curves import (
    CurveError,
    fit_curve,
    FourierBasis,
    make_basis,
    PolynomialBasis,
)


def paper_fourier_g(s, harmonics):
    """G(s) written out exactly as in the paper: [g_1 .. g_K, I_2]."""
    blocks = []
    for h in range(1, harmonics + 1):
        c, sn = np.cos(2 * np.pi * h * s), np.sin(2 * np.pi * h * s)
        blocks.append(np.array([[c, sn, 0, 0], [0, 0, c, sn]]))
    blocks.append(np.eye(2))
    return np.hstack(blocks)


def test_fourier_g_matches_paper_layout():
    basis = FourierBasis(6)
    s = np.array([0.0, 0.13, 0.5, 0.91])
    got = basis.G(s)
    assert got.shape == (4, 2, 26)
    for k, sk in enumerate(s):
        np.testing.assert_allclose(got[k], paper_fourier_g(sk, 6), atol=1e-15)


def test_polynomial_g_is_kron_with_identity():
    basis = PolynomialBasis(6)
    for s in (0.0, 0.3, 1.0):
        np.testing.assert_allclose(basis.G(s)[0], np.kron(s ** np.arange(7), np.eye(2)))


@pytest.mark.parametrize('basis', [FourierBasis(1), FourierBasis(8), PolynomialBasis(1),
                                   PolynomialBasis(6)])
def test_fit_recovers_known_coefficients_exactly(basis):
    rng = np.random.default_rng(0)
    xi = rng.normal(size=2 * basis.H)
    s = np.linspace(0, 1, 5 * basis.H, endpoint=not basis.closed)
    points = np.einsum('mij,j->mi', basis.G(s), xi)
    fit = fit_curve(basis, s, points)
    np.testing.assert_allclose(fit.curve.xi, xi, atol=1e-10)
    assert fit.max_residual < 1e-10


def test_derivative_matches_finite_difference():
    for basis in (FourierBasis(3), PolynomialBasis(4)):
        xi = np.random.default_rng(1).normal(size=2 * basis.H)
        s = np.linspace(0.1, 0.9, 5)
        fit = fit_curve(basis, np.linspace(0, 1, 50, endpoint=False),
                        np.einsum('mij,j->mi', basis.G(np.linspace(0, 1, 50, endpoint=False)),
                                  xi))
        h = 1e-6
        fd = (fit.curve.points(s + h) - fit.curve.points(s - h)) / (2 * h)
        np.testing.assert_allclose(fit.curve.tangents(s), fd, rtol=1e-5, atol=1e-6)


def test_paper_closed_curve_is_fitted_with_tiny_residual():
    s, pts = expression_samples('(8 + sin(4*pi*s)) * cos(2*pi*s) + 4',
                                '(8 + cos(4*pi*s)) * sin(2*pi*s) + 4', 400, closed=True)
    fit = fit_curve(FourierBasis(6), s, pts)
    assert fit.rms_residual < 1e-10
    # Harmonics 1 and 3 only, centre (4, 4): x = 8 cos + (sin 3 - sin 1)/2 ...
    np.testing.assert_allclose(fit.curve.xi[-2:], [4, 4], atol=1e-12)


def test_non_representable_curve_has_reported_residual():
    s, pts = expression_samples('abs(cos(2*pi*s))', 'sin(2*pi*s)', 400, closed=True)
    fit = fit_curve(FourierBasis(2), s, pts)
    assert 1e-3 < fit.rms_residual < 0.2


def test_bezier_is_exact_in_a_sixth_order_polynomial():
    s, pts = bezier_samples([[3.5, 3], [-0.5, -4], [-2, 6], [-2, -1]], 200)
    fit = fit_curve(PolynomialBasis(6), s, pts)
    assert fit.max_residual < 1e-12
    np.testing.assert_allclose(fit.curve.points([0.0, 1.0]), [[3.5, 3], [-2, -1]], atol=1e-12)


def test_fit_refuses_too_few_samples():
    with pytest.raises(CurveError, match='more than H = 13'):
        fit_curve(FourierBasis(6), np.linspace(0, 1, 13, endpoint=False), np.zeros((13, 2)))


def test_fit_refuses_nan():
    pts = np.zeros((20, 2))
    pts[3, 1] = np.nan
    with pytest.raises(CurveError, match='NaN'):
        fit_curve(PolynomialBasis(2), np.linspace(0, 1, 20), pts)


def test_chord_length_parameters_of_a_closed_square():
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    np.testing.assert_allclose(chord_length_parameters(square, closed=True), [0, .25, .5, .75])
    np.testing.assert_allclose(chord_length_parameters(square, closed=False), [0, 1 / 3, 2 / 3, 1])


def test_observed_points_are_fitted_by_their_shape_not_their_spacing():
    """Points of the arena flower (8 harmonics), unevenly spaced: chord-length parameters
    alone leave the 8-harmonic fit 3 mm off the flower; moving each point's parameter to its
    foot on the fit and refitting brings it to 0.1 mm.
    """
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.core.formation.curve_sources import (
        fit_points,
        point_samples,
        polyline_rms_distance,
    )
    from curve_formation.paths import resolve_config
    flower = load_experiment(resolve_config('arena_demo')).phases[0].curve
    u = np.linspace(0, 1, 300, endpoint=False)
    points = flower.points(u + 0.03 * np.sin(2 * np.pi * u))
    _, truth = flower.sample(5000)
    basis = make_basis('fourier', 8)
    chord = fit_curve(basis, *point_samples(points, True)).curve
    shape = fit_points(basis, points).curve
    assert polyline_rms_distance(chord.sample(3000)[1], truth, True) > 0.002
    assert polyline_rms_distance(shape.sample(3000)[1], truth, True) < 0.0001
    # an open curve too (7 mm -> under 1 mm off), its ends staying at the first and last point
    s = np.linspace(0, 1, 200) ** 1.3
    arc = np.column_stack([s, np.sin(3 * s)])
    t = np.linspace(0, 1, 5000)
    truth = np.column_stack([t, np.sin(3 * t)])
    basis = make_basis('polynomial', 8)
    chord = fit_curve(basis, *point_samples(arc, False)).curve
    shape = fit_points(basis, arc).curve
    assert polyline_rms_distance(chord.sample(3000)[1], truth, False) > 0.005
    assert polyline_rms_distance(shape.sample(3000)[1], truth, False) < 0.001
    np.testing.assert_allclose(shape.points([0.0, 1.0]), arc[[0, -1]], atol=0.005)


@pytest.mark.parametrize('basis', [FourierBasis(3), PolynomialBasis(4)])
def test_the_stacked_basis_puts_each_agents_g_under_the_last(basis):
    """G_bar xi stacks the agents' points: rows 2i, 2i + 1 are G(s_i)."""
    s = np.array([0.1, 0.45, 0.8])
    xi = np.random.default_rng(0).normal(size=2 * basis.H)
    g_bar = basis.stacked(s)
    assert g_bar.shape == (6, 2 * basis.H)
    np.testing.assert_allclose((g_bar @ xi).reshape(3, 2), basis.G(s) @ xi)
