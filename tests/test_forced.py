"""Forced vibration, surface location error, force, torque, power (stability/forced.py).

Ground truth: Altintas's closed-form mean milling forces; a two-tooth slot whose force is exactly
a mean plus one harmonic (closed-form response); quasi-static response of a stiff fast mode;
cutting power = Ktc x removal rate; and an independent time integration (python-control) of
the modal model driven by the rigid-tool force until steady state.
"""

import json

import control
import numpy as np
import pytest

from oma.cutting import Cut, CuttingCoefficients, Tool, engagement_angles
from oma.frf_table import FRFTable
from oma.modal import ModalModel
from stability.forced import forced_response, forced_sweep

COEF = CuttingCoefficients(Ktc_N_m2=7.0e8, Krc_N_m2=2.6e8, Kac_N_m2=1.1e8, Kte_N_m=2e3, Kre_N_m=3e3, Kae_N_m=4e2)
NO_EDGE = CuttingCoefficients(Ktc_N_m2=7.0e8, Krc_N_m2=2.6e8)
FZ = 1e-4
# closed forms evaluated in double precision
EXACT = 1e-10


def make_cut(ratio, milling, diameter=0.02, f=(1, 0, 0), n=(0, 1, 0)):
    return Cut(FZ, ratio * diameter, milling, feed_direction=f, normal_direction=n)


def robot_model():
    return ModalModel([150.0, 400.0], [0.05, 0.04], [2e6, 6e6], [[1, 0.3, 0.1], [-0.2, 1, 0.4]])


@pytest.mark.parametrize("ratio,milling,helix_deg", [(1.0, "down", 0.0), (0.3, "down", 30.0), (0.6, "up", 45.0)])
def test_mean_force_is_altintas_closed_form(ratio, milling, helix_deg):
    """Altintas, Manufacturing Automation, eq. 2.x: average forces per tooth period (f = x, n = y)."""
    tool = Tool(3, 0.02, np.radians(helix_deg))
    cut = make_cut(ratio, milling, f=(0, 1, 0), n=(-1, 0, 0))
    a, n_t = 0.004, tool.teeth
    st, ex = engagement_angles(tool, cut)
    k = COEF

    def fx(p):
        return n_t * a * FZ / (8 * np.pi) * (k.Ktc_N_m2 * np.cos(2 * p) - k.Krc_N_m2 * (2 * p - np.sin(2 * p))) \
            + n_t * a / (2 * np.pi) * (-k.Kte_N_m * np.sin(p) + k.Kre_N_m * np.cos(p))

    def fy(p):
        return n_t * a * FZ / (8 * np.pi) * (k.Ktc_N_m2 * (2 * p - np.sin(2 * p)) + k.Krc_N_m2 * np.cos(2 * p)) \
            - n_t * a / (2 * np.pi) * (k.Kte_N_m * np.cos(p) + k.Kre_N_m * np.sin(p))

    def fz(p):
        return n_t * a / (2 * np.pi) * (-k.Kac_N_m2 * FZ * np.cos(p) + k.Kae_N_m * p)

    ref = np.array([fx(ex) - fx(st), fy(ex) - fy(st), fz(ex) - fz(st)])
    r = forced_response(robot_model(), tool, cut, COEF, spindle_rpm=3000, axial_depth_m=a)
    mean_cut = cut.frame @ r.mean_force_N
    assert np.allclose(mean_cut, ref, rtol=EXACT, atol=EXACT * np.abs(ref).max())
    # and the static deflection is that force through G(0)
    assert np.allclose(r.static_displacement_m, robot_model().static_compliance_m_N @ r.mean_force_N, rtol=EXACT)


def test_two_tooth_slot_is_one_harmonic_and_its_response_is_closed_form():
    """Two straight teeth in a slot, no edge forces: exactly one tooth cuts at a time and the
    forces are ``a fz [-(Kt sin2p + Kr (1 - cos2p)) / 2, (Kt (1 - cos2p) - Kr sin2p) / 2]``: a mean
    and the first tooth harmonic only. The response is then G(0) F0 + 2 Re(G(w_T) F1 e^{i w_T t})."""
    tool = Tool(2, 0.02)
    cut = make_cut(1.0, "down")
    a, rpm = 0.003, 6000.0
    model = ModalModel([80.0, 230.0], [0.05, 0.03], [4e6, 9e6], [[1, 0.5, 0], [0.2, 1, 0.3]])
    kt, kr = NO_EDGE.Ktc_N_m2, NO_EDGE.Krc_N_m2
    f0 = a * FZ * np.array([-kr / 2, kt / 2, 0.0])
    # e^{i 2p} coefficient of the force: sin2p = (e - e*)/2i, cos2p = (e + e*)/2
    f1 = a * FZ * np.array([-(kt / 2j - kr / 2) / 2, (-kt / 2 - kr / 2j) / 2, 0.0])
    f_tp = 2 * rpm / 60
    x_ref = lambda t: (model.static_compliance_m_N @ f0)[:, None] + 2 * np.real(
        (model.receptance([f_tp])[:, :, 0] @ f1)[:, None] * np.exp(2j * np.pi * f_tp * t)[None, :])
    r = forced_response(model, tool, cut, NO_EDGE, spindle_rpm=rpm, axial_depth_m=a, harmonics=8)
    scale = np.abs(r.displacement_m).max()
    assert np.allclose(r.displacement_m, x_ref(r.time_s), atol=1e-9 * scale)
    # the higher harmonics vanish (up to the cell-average correction's aliasing, < 1e-6)
    assert np.abs(r.displacement_harmonics_m[:, 2:]).max() < 1e-6 * scale
    # finished wall at phi = pi (down milling), wall on the -n side: SLE = +x_n there
    t_fin = np.pi / (2 * np.pi * rpm / 60)
    assert r.surface_location_error_m == pytest.approx(x_ref(np.array([t_fin]))[1, 0], rel=1e-7)
    # peak force: |F| = a fz sin(p) sqrt(Kt^2 + Kr^2), largest at p = pi/2; torque R Kt a fz sin p
    assert r.peak_force_N == pytest.approx(a * FZ * np.hypot(kt, kr), rel=1e-9)
    assert r.peak_torque_N_m == pytest.approx(0.01 * kt * a * FZ, rel=1e-9)


@pytest.mark.parametrize("milling,sign", [("down", 1.0), ("up", -1.0)])
def test_quasi_static_sle_of_a_stiff_fast_mode(milling, sign):
    """A mode 200x the tooth frequency responds quasi-statically, x(t) = F(t)/k along it. Three
    teeth in a slot: when one tooth generates the wall (phi = pi down, 0 up) another sits at
    pi/3 (down) or 2 pi/3 (up), so F_n = a fz sin(p) (Kt sin p - Kr cos p) there.
    Down milling, wall on the -n side: F_n > 0 pushes the tool away, material is left (SLE > 0);
    up milling, wall on the +n side: the same push cuts into the wall (SLE < 0)."""
    tool = Tool(3, 0.02)
    cut = make_cut(1.0, milling)
    a, rpm, k = 0.002, 3000.0, 5e7
    f_tp = 3 * rpm / 60
    zeta = 0.05
    model = ModalModel([200 * f_tp], [zeta], [k], [[0, 1, 0]])
    r = forced_response(model, tool, cut, NO_EDGE, spindle_rpm=rpm, axial_depth_m=a, harmonics=1000)
    p = np.pi / 3 if milling == "down" else 2 * np.pi / 3
    f_n = a * FZ * np.sin(p) * (NO_EDGE.Ktc_N_m2 * np.sin(p) - NO_EDGE.Krc_N_m2 * np.cos(p))
    # quasi-static error: k G(f) - 1 ~ -2 i zeta f / fn per harmonic, 2 zeta / 200 = 5e-4 on the
    # first; the kinks at entry and exit ring the mode by less: 1e-3
    assert r.surface_location_error_m == pytest.approx(sign * f_n / k, rel=1e-3)
    assert np.sign(r.surface_location_error_m) == sign
    x_qs = (model.static_compliance_m_N @ r.force_N)
    assert np.allclose(r.displacement_m, x_qs, atol=1e-3 * np.abs(x_qs).max())


def test_converges_with_the_number_of_harmonics():
    tool = Tool(2, 0.0254, np.radians(30))
    cut = make_cut(0.25, "down", diameter=0.0254, f=(0, 1, 0), n=(-1, 0, 0))
    kw = dict(spindle_rpm=2700.0, axial_depth_m=0.006)
    sle = {h: forced_response(robot_model(), tool, cut, COEF, harmonics=h, **kw).surface_location_error_m
           for h in (2, 8, 32, 128, 512)}
    err = [abs(sle[h] - sle[512]) for h in (2, 8, 32, 128)]
    assert all(e2 < e1 for e1, e2 in zip(err, err[1:]))
    default = forced_response(robot_model(), tool, cut, COEF, **kw)
    # default: harmonics up to 4x the highest mode; beyond, |G| falls as (fn/f)^2
    assert default.surface_location_error_m == pytest.approx(sle[512], rel=1e-3)


def test_matches_an_independent_time_integration():
    """python-control's forced_response of the modal state space driven by the rigid-tool force
    sampled finely, run until transients have died (e^{-zeta w t} < 1e-9): the last tooth period
    equals the harmonic solution."""
    tool = Tool(2, 0.0254, np.radians(30))
    cut = make_cut(0.3, "down", diameter=0.0254, f=(0, 1, 0), n=(-1, 0, 0))
    model = robot_model()
    rpm, a = 4000.0, 0.004
    r = forced_response(model, tool, cut, COEF, spindle_rpm=rpm, axial_depth_m=a, n_time=512, harmonics=400)
    period = 1 / r.tooth_frequency_hz
    decay = 1 / np.min(model.damping_ratio * model.omega_rad_s)
    n_periods = int(np.ceil(21 * decay / period))
    n_per = 512
    t = np.arange(n_periods * n_per + 1) * period / n_per
    force = np.tile(r.force_N, n_periods)
    force = np.concatenate([force, force[:, :1]], axis=1)
    sim = control.forced_response(model.to_statespace(), T=t, U=force).outputs
    last = sim[:, -n_per - 1:-1]
    # first-order hold of a force sampled 512 times per period with jumps at entry/exit: 2e-3
    assert np.allclose(last, r.displacement_m, atol=2e-3 * np.abs(r.displacement_m).max())


@pytest.mark.parametrize("ratio,milling,helix_deg", [(1.0, "down", 0.0), (0.2, "up", 30.0), (0.45, "down", 50.0)])
def test_power_is_cutting_coefficient_times_removal_rate(ratio, milling, helix_deg):
    """Mean of sum Ft R Omega: the chip term integrates to Ktc * MRR for any immersion
    (cos(phi_st) - cos(phi_ex) = 2 ae / D); the edge term adds Kte a R Omega N (phi_ex - phi_st) / 2 pi."""
    tool = Tool(4, 0.016, np.radians(helix_deg))
    cut = make_cut(ratio, milling, diameter=0.016)
    a, rpm = 0.005, 5000.0
    r = forced_response(robot_model(), tool, cut, COEF, spindle_rpm=rpm, axial_depth_m=a)
    st, ex = engagement_angles(tool, cut)
    omega = 2 * np.pi * rpm / 60
    mrr = a * cut.radial_depth_m * FZ * tool.teeth * rpm / 60
    edge = COEF.Kte_N_m * a * 0.008 * omega * tool.teeth * (ex - st) / (2 * np.pi)
    assert r.mrr_m3_s == pytest.approx(mrr, rel=EXACT)
    assert r.power_W == pytest.approx(COEF.Ktc_N_m2 * mrr + edge, rel=1e-9)
    assert r.power_W == pytest.approx(r.mean_torque_N_m * omega, rel=EXACT)


def test_frf_table_gives_the_modal_result_and_sweep_matches_points():
    tool = Tool(2, 0.0254, np.radians(30))
    cut = make_cut(0.25, "down", diameter=0.0254, f=(0, 1, 0), n=(-1, 0, 0))
    model = robot_model()
    f = np.linspace(0, 2000, 200_001)
    g = model.receptance(f)
    table = FRFTable.from_entries(f, {x + y: g["XYZ".index(x), "XYZ".index(y)] for x in "XYZ" for y in "XYZ"})
    kw = dict(spindle_rpm=2700.0, axial_depth_m=0.006, harmonics=20)
    a = forced_response(model, tool, cut, COEF, **kw)
    b = forced_response(table, tool, cut, COEF, **kw)
    # linear interpolation of a 0.01 Hz table: (0.01 / 15 Hz bandwidth)^2 ~ 5e-7
    assert b.surface_location_error_m == pytest.approx(a.surface_location_error_m, rel=1e-5)
    rpm = np.array([1500.0, 2700.0, 6000.0])
    sweep = forced_sweep(model, tool, cut, COEF, rpm=rpm, axial_depth_m=0.006, harmonics=20)
    pts = [forced_response(model, tool, cut, COEF, spindle_rpm=x, axial_depth_m=0.006, harmonics=20) for x in rpm]
    assert np.allclose(sweep.surface_location_error_m, [p.surface_location_error_m for p in pts], rtol=1e-10)
    assert np.allclose(sweep.peak_force_N, [p.peak_force_N for p in pts], rtol=1e-12)
    assert np.allclose(sweep.power_W, [p.power_W for p in pts], rtol=1e-12)
    assert json.loads(json.dumps(sweep.to_dict(), allow_nan=False))["axial_depth_m"] == 0.006
    assert "surface_location_error_m" in json.loads(json.dumps(a.to_dict(), allow_nan=False))


def test_sle_profile_follows_the_helix():
    """The wall at height z is cut kappa z / Omega later; the profile is the displacement then."""
    tool = Tool(2, 0.0254, np.radians(30))
    cut = make_cut(0.25, "up", diameter=0.0254, f=(0, 1, 0), n=(-1, 0, 0))
    r = forced_response(robot_model(), tool, cut, COEF, spindle_rpm=2700, axial_depth_m=0.006, n_profile=5)
    kappa = 2 * np.tan(tool.helix_rad) / tool.diameter_m
    t = kappa * r.sle_profile_z_m / (2 * np.pi * 2700 / 60)  # up milling: phi = 0 at t = 0
    expected = -(cut.normal_direction @ r.displacement_at(t))
    assert np.allclose(r.sle_profile_m, expected, rtol=1e-12)
    assert r.sle_profile_m[0] == r.surface_location_error_m


def test_bad_input_is_rejected():
    tool, cut = Tool(2, 0.02), make_cut(0.5, "down")
    with pytest.raises(ValueError, match="must be > 0"):
        forced_response(robot_model(), tool, cut, COEF, spindle_rpm=3000, axial_depth_m=-1e-3)
    with pytest.raises(ValueError, match="harmonics must be >= 0"):
        forced_response(robot_model(), tool, cut, COEF, spindle_rpm=3000, axial_depth_m=1e-3, harmonics=-1)
    with pytest.raises(ValueError, match="must be > 0"):
        forced_sweep(robot_model(), tool, cut, COEF, rpm=[0.0, 100.0], axial_depth_m=1e-3)
