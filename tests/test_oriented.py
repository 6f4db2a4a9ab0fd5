"""Oriented receptance and directional factors (stability/oriented.py).

Ground truth: the force model of formats.md differentiated numerically, the closed-form average
directional factors of Altintas & Budak (1995) (same convention with f = x, n = y), quadrature of
the pointwise integrands, and rotation invariance.
"""

import numpy as np
import pytest
from scipy.integrate import quad_vec

from oma.cutting import Cut, CuttingCoefficients, Tool, engagement_angles
from oma.modal import ModalModel
from stability.oriented import (
    average_directional_matrix,
    cut_receptance,
    directional_matrix,
    directional_matrix_step_mean,
    dynamic_coefficients,
    engaged_axial_integral,
    engaged_axial_step_mean,
    engaged_in_step,
    helix_lag_per_m,
    oriented_receptance,
)

# Closed-form trigonometric integrals evaluated in double precision: agreement to a few ulps of the
# largest term.
EXACT = 1e-12

COEF = CuttingCoefficients(Ktc_N_m2=7.0e8, Krc_N_m2=2.6e8, Kac_N_m2=1.1e8, Kte_N_m=2e3, Kre_N_m=3e3, Kae_N_m=4e2)

CUTS = [
    ("slot", 1.0, "down"),
    ("half-down", 0.5, "down"),
    ("half-up", 0.5, "up"),
    ("light-down", 0.05, "down"),
    ("light-up", 0.2, "up"),
]


def make_cut(ratio, milling, diameter=0.02):
    return Cut(feed_per_tooth_m=1e-4, radial_depth_m=ratio * diameter, milling=milling,
               feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])


def force_on_tool(phi, dq, coef, fz=0.0):
    """formats.md, per unit height: chip h = fz sin phi + dq . (sin phi, cos phi), forces on the
    tool F_f = -Ft cos - Fr sin, F_n = Ft sin - Fr cos, F_a = Fa (cutting part only)."""
    h = fz * np.sin(phi) + dq[0] * np.sin(phi) + dq[1] * np.cos(phi)
    ft, fr, fa = coef.Ktc_N_m2 * h, coef.Krc_N_m2 * h, coef.Kac_N_m2 * h
    return np.array([-ft * np.cos(phi) - fr * np.sin(phi), ft * np.sin(phi) - fr * np.cos(phi), fa])


def test_directional_matrix_is_the_derivative_of_the_force_model():
    tool = Tool(teeth=1, diameter_m=0.02)
    cut = make_cut(1.0, "down")  # slot: 0 < phi < pi engaged
    c = dynamic_coefficients(COEF)
    for phi in np.linspace(0.1, 3.0, 7):
        # the force is linear in dq, so a unit central difference is exact up to rounding
        numeric = np.column_stack([(force_on_tool(phi, e, COEF) - force_on_tool(phi, -e, COEF)) / 2
                                   for e in np.eye(2)])
        a = directional_matrix(tool, cut, COEF, phi, axial_depth_m=1.0)
        assert np.allclose(a, numeric, rtol=EXACT, atol=EXACT * COEF.Ktc_N_m2)
        basis = np.array([1, np.sin(phi), np.cos(phi), np.sin(phi) ** 2, np.cos(phi) ** 2,
                          np.sin(phi) * np.cos(phi)])
        assert np.allclose(c @ basis, numeric, rtol=EXACT, atol=EXACT * COEF.Ktc_N_m2)


def altintas_alpha(st, ex, kr):
    """Altintas & Budak (1995) / Altintas, Manufacturing Automation (2012), eq. 3.28: the
    average directional factors, with B0 = N Kt / (4 pi) alpha."""
    def at(p):
        return np.array([
            [np.cos(2 * p) - 2 * kr * p + kr * np.sin(2 * p), -np.sin(2 * p) - 2 * p + kr * np.cos(2 * p)],
            [-np.sin(2 * p) + 2 * p + kr * np.cos(2 * p), -np.cos(2 * p) - 2 * kr * p - kr * np.sin(2 * p)],
        ]) / 2
    return at(ex) - at(st)


@pytest.mark.parametrize("name,ratio,milling", CUTS)
def test_average_directional_matrix_is_the_textbook_alpha(name, ratio, milling):
    for teeth in (2, 3):
        tool = Tool(teeth=teeth, diameter_m=0.02, helix_rad=np.radians(30))
        cut = make_cut(ratio, milling)
        st, ex = engagement_angles(tool, cut)
        b0 = average_directional_matrix(tool, cut, COEF)
        ref = teeth * COEF.Ktc_N_m2 / (4 * np.pi) * altintas_alpha(st, ex, COEF.Krc_N_m2 / COEF.Ktc_N_m2)
        assert np.allclose(b0[:2], ref, rtol=EXACT, atol=EXACT * COEF.Ktc_N_m2)
        # axial row: N Ka / 2pi * [int sin, int cos]
        ax = teeth * COEF.Kac_N_m2 / (2 * np.pi) * np.array([np.cos(st) - np.cos(ex), np.sin(ex) - np.sin(st)])
        assert np.allclose(b0[2], ax, rtol=EXACT, atol=EXACT * COEF.Ktc_N_m2)


@pytest.mark.parametrize("helix_deg", [0.0, 35.0])
@pytest.mark.parametrize("name,ratio,milling", CUTS)
def test_time_varying_matrix_averages_to_the_mean(helix_deg, name, ratio, milling):
    tool = Tool(teeth=3, diameter_m=0.02, helix_rad=np.radians(helix_deg))
    cut = make_cut(ratio, milling)
    depth = 0.004
    pitch = 2 * np.pi / tool.teeth
    b0 = average_directional_matrix(tool, cut, COEF)
    # exact mean over a whole pitch
    whole = directional_matrix_step_mean(tool, cut, COEF, 0.0, pitch, axial_depth_m=depth)
    assert np.allclose(whole, depth * b0, rtol=1e-10, atol=1e-10 * depth * COEF.Ktc_N_m2)
    # independent: midpoint rule on the pointwise matrix; the matrix jumps at entry/exit, so the
    # rule errs by O(1/n): with 4e4 points, < 1e-4 of the largest entry
    n = 40_000
    phi = (np.arange(n) + 0.5) * pitch / n
    mean = directional_matrix(tool, cut, COEF, phi, axial_depth_m=depth).mean(axis=0)
    assert np.allclose(mean, depth * b0, atol=1e-4 * depth * COEF.Ktc_N_m2)


def test_helix_integral_matches_thin_slices():
    tool = Tool(teeth=4, diameter_m=0.016, helix_rad=np.radians(30))
    cut = make_cut(0.3, "down", diameter=0.016)
    depth = 0.01
    kappa = helix_lag_per_m(tool)
    phi = np.linspace(0.0, 2 * np.pi, 37)
    exact = engaged_axial_integral(tool, cut, phi, depth)
    straight = Tool(teeth=4, diameter_m=0.016)
    # midpoint rule over many thin straight slices, each lagging kappa z (as the simulator does);
    # an integrand with jumps: the rule errs by O(1/n), < 2e-5 of the depth with 20000 slices
    n = 20_000
    z = (np.arange(n) + 0.5) * depth / n
    slices = engaged_axial_integral(straight, cut, phi[:, None] - kappa * z[None, :], depth / n).sum(axis=1)
    assert np.allclose(exact, slices, atol=2e-5 * depth)


def test_step_mean_matches_quadrature():
    tool = Tool(teeth=2, diameter_m=0.02, helix_rad=np.radians(45))
    cut = make_cut(0.25, "up")
    depth = 0.003
    for lo, hi in [(0.1, 0.4), (1.0, 1.03), (2.5, 3.6)]:
        got = directional_matrix_step_mean(tool, cut, COEF, lo, hi, axial_depth_m=depth)
        ref = quad_vec(lambda p: directional_matrix(tool, cut, COEF, p, axial_depth_m=depth), lo, hi,
                       epsabs=1e-12 * depth * COEF.Ktc_N_m2, limit=400)[0] / (hi - lo)
        # adaptive quadrature of a piecewise-smooth integrand: 1e-9 of the scale
        assert np.allclose(got, ref, atol=1e-9 * depth * COEF.Ktc_N_m2)


def test_pitch_depth_makes_the_cut_time_invariant():
    """With an axial depth of one helical pitch, kappa a = 2 pi / N, every angle is cut at every
    instant: K(t) = a B0 exactly (why the ZOA is exact there; used again in test_sdm.py)."""
    tool = Tool(teeth=3, diameter_m=0.012, helix_rad=np.radians(40))
    cut = make_cut(1.0, "down", diameter=0.012)
    pitch_depth = 2 * np.pi / tool.teeth / helix_lag_per_m(tool)
    k = directional_matrix(tool, cut, COEF, np.linspace(0, 2 * np.pi, 50), axial_depth_m=pitch_depth)
    b0 = average_directional_matrix(tool, cut, COEF)
    assert np.allclose(k, pitch_depth * b0, rtol=1e-9, atol=1e-9 * np.abs(pitch_depth * b0).max())


def _rotation(rng):
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_oriented_receptance_projects_an_oblique_mode_with_cross_terms():
    fn, zeta, k = 300.0, 0.03, 2e7
    u = np.array([1.0, 1.0, 0.5]) / 1.5
    model = ModalModel([fn], [zeta], [k], [u])
    cut = Cut(1e-4, 0.01, "down", feed_direction=[0, 1, 0], normal_direction=[-1, 0, 0])
    f = np.array([0.0, 250.0, 300.0, 400.0])
    g = cut_receptance(model, cut, f)
    uc = cut.frame @ u  # mode shape in (f, n, a)
    r = f / fn
    modal = 1 / (k * (1 - r**2 + 2j * zeta * r))
    assert np.allclose(g, np.einsum("i,j,k->ijk", uc, uc, modal), rtol=EXACT)
    # the oblique mode couples feed and normal: the cross term is as large as the product of directions
    assert np.allclose(g[0, 1], uc[0] * uc[1] * modal, rtol=EXACT) and abs(uc[0] * uc[1]) > 0.3
    assert oriented_receptance(model, cut, f).shape == (2, 3, 4)


def test_oriented_receptance_is_invariant_under_a_common_rotation():
    rng = np.random.default_rng(7)
    dirs = rng.standard_normal((3, 3))
    model = ModalModel([120.0, 400.0, 900.0], [0.02, 0.04, 0.03], [3e6, 8e6, 2e7], dirs,
                       residual_compliance_m_N=np.diag([1e-9, 2e-9, 3e-9]))
    cut = Cut(1e-4, 0.01, "up", feed_direction=[1, 0, 0], normal_direction=[0, 0, 1])
    rot = _rotation(rng)
    model_r = ModalModel(model.natural_frequency_hz, model.damping_ratio, model.stiffness_N_m,
                         dirs @ rot.T, residual_compliance_m_N=rot @ model.residual_compliance_m_N @ rot.T)
    cut_r = Cut(1e-4, 0.01, "up", feed_direction=rot @ cut.feed_direction,
                normal_direction=rot @ cut.normal_direction)
    f = np.linspace(50, 1200, 40)
    assert np.allclose(cut_receptance(model, cut, f), cut_receptance(model_r, cut_r, f),
                       rtol=1e-10, atol=1e-10 * np.abs(cut_receptance(model, cut, f)).max())


def test_engaged_in_step_agrees_with_the_engaged_angle_measure():
    """The geometric test says a step cuts exactly when the engaged measure over it is positive
    (basis function 1 integrates the indicator: the angle-depth area being cut)."""
    rng = np.random.default_rng(11)
    tool = Tool(teeth=3, diameter_m=0.012, helix_rad=np.radians(30))
    for ratio, milling in [(0.05, "down"), (0.3, "up")]:
        cut = make_cut(ratio, milling, diameter=0.012)
        lo = rng.uniform(-7, 7, 400)
        hi = lo + rng.uniform(1e-3, 0.3, 400)
        depth = rng.uniform(0, 0.004, 400)
        flag = engaged_in_step(tool, cut, lo, hi, depth)
        area = engaged_axial_step_mean(tool, cut, lo, hi, depth)[:, 0]
        assert np.array_equal(flag & (depth > 0), area > 1e-12 * depth)
        assert flag.any() and not flag.all()
