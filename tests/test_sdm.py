"""Semi-discretization (stability/sdm.py) and the SDM path of stability/lobes.py.

Ground truth: the straightforward dense-matrix construction of the same monodromy; the free
vibration multiplier ``exp(-zeta w T)``; the 1-DOF milling benchmark of Insperger & Stepan (2004)
and Ding et al. (2010) (fn 922 Hz, zeta 0.011, m 0.03993 kg, Kt 6e8, Kn 2e8 N/m^2, 2 straight
teeth, down milling); and a helix whose pitch equals the depth, which makes the cut
time-invariant so that the zero-order approximation is exact there (an independent method).
"""

import json

import numpy as np
import pytest
import scipy.linalg

from oma.cutting import Cut, CuttingCoefficients, Tool
from oma.frf_table import FRFTable
from oma.modal import ModalModel
from stability import zoa
from stability.lobes import lobe_diagram, predict_point
from stability.oriented import helix_lag_per_m
from stability.sdm import SDMProblem, _expm_batch, choose_resolution, dense_monodromy, steps_per_period

FN, ZETA, MASS = 922.0, 0.011, 0.03993
STIFF = MASS * (2 * np.pi * FN) ** 2
TOOL = Tool(2, 0.01)
# Insperger's "Kn" is the radial coefficient: F_x = -(Kt cos + Kn sin) h, the formats.md
# F_f = -Ft cos - Fr sin with Fr = Krc h, so Kn = Krc.
COEF = CuttingCoefficients(Ktc_N_m2=6e8, Krc_N_m2=2e8)
# flexible along x = the feed direction, as in the benchmark
BENCH = ModalModel([FN], [ZETA], [STIFF], [[1, 0, 0]])


def bench_cut(ratio):
    return Cut(1e-4, ratio * TOOL.diameter_m, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])


def oblique_model():
    return ModalModel([700.0, 1100.0], [0.02, 0.03], [2e6, 3e6], [[1, 0.4, 0], [0.3, 1, 0.5]])


def test_expm_batch_matches_scipy():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((20, 6, 6)) * np.geomspace(1e-3, 30, 20)[:, None, None]
    ref = np.array([scipy.linalg.expm(x) for x in a])
    assert np.allclose(_expm_batch(a), ref, rtol=1e-11, atol=1e-11 * np.abs(ref).max())


@pytest.mark.parametrize("ratio,helix_deg,damping", [(1.0, 0.0, 0.0), (0.05, 30.0, 5e4), (0.3, 45.0, 0.0)])
def test_structured_monodromy_equals_the_dense_product(ratio, helix_deg, damping):
    tool = Tool(3, 0.012, np.radians(helix_deg))
    cut = Cut(1e-4, ratio * 0.012, "down", [1, 0, 0], [0, 1, 0])
    coef = CuttingCoefficients(6e8, 2e8, 1e8)
    problem = SDMProblem(oblique_model(), tool, cut, coef, process_damping_N_m=damping)
    full = problem.monodromy(7000, 2e-3, 30, reduce=False)
    dense = dense_monodromy(problem, 7000, 2e-3, 30)
    assert np.allclose(full, dense, rtol=1e-12, atol=1e-12 * np.abs(dense).max())
    # dropping never-read history keeps every non-zero multiplier
    reduced = problem.monodromy(7000, 2e-3, 30)
    if ratio < 1:
        assert reduced.shape[0] < full.shape[0]
    rho_dense = np.abs(np.linalg.eigvals(dense)).max()
    assert problem.spectral_radius(7000, 2e-3, 30) == pytest.approx(rho_dense, rel=1e-10)


def test_zero_depth_gives_free_vibration_multipliers():
    problem = SDMProblem(oblique_model(), Tool(3, 0.012), bench_cut(0.5), COEF)
    rpm, steps = 9000.0, 40
    period = problem.tooth_period_s(rpm)
    m = problem.model
    expected = np.max(np.exp(-m.damping_ratio * m.omega_rad_s * period))  # |mu| of a damped mode
    assert problem.spectral_radius(rpm, 0.0, steps) == pytest.approx(expected, rel=1e-12)


def test_benchmark_slotting_5000_rpm_converges_to_the_published_value():
    """Slotting at 5000 rpm: converged limit about 0.41 mm (DOMAIN.md), and the step rule meets
    its stated accuracy against a Richardson-extrapolated reference."""
    problem = SDMProblem(BENCH, TOOL, bench_cut(1.0), COEF)
    res = choose_resolution(problem, (5000, 5000), rtol=0.01)
    assert res.converged and res.history[-1][2] < 0.01
    steps = int(steps_per_period(problem, 5000, steps_per_mode_period=res.steps_per_mode_period,
                                 min_steps=res.min_steps))
    chosen = problem.limit(5000, steps, guess_m=4e-4, depth_rtol=1e-4)
    # first-order SDM converges as dt^2: Richardson extrapolation from m and 2m
    a1 = problem.limit(5000, 300, guess_m=4e-4, depth_rtol=1e-5).depth_limit_m
    a2 = problem.limit(5000, 600, guess_m=4e-4, depth_rtol=1e-5).depth_limit_m
    converged = a2 + (a2 - a1) / 3
    assert chosen.depth_limit_m == pytest.approx(converged, rel=0.01)
    # "about 0.41 mm": the quoted value's two significant digits, +-0.005 mm
    assert abs(converged - 0.41e-3) <= 0.005e-3
    assert chosen.kind == "hopf"
    # Hopf chatter just above the natural frequency (ZOA gives 942.7 Hz here)
    assert 922 < chosen.chatter_frequency_hz < 960
    # 40 steps per period (the literature scripts' choice) is noticeably high. DOMAIN.md's 18 % is
    # for the zeroth-order script; this first-order SDM with exact step means is 8 % high.
    coarse = problem.limit(5000, 40, guess_m=4e-4, depth_rtol=1e-4).depth_limit_m
    assert coarse > 1.05 * converged


def test_low_immersion_has_flip_lobes_the_zoa_misses():
    """a/D = 0.05 down milling: between Hopf lobes the SDM finds period-doubling lobes well below
    the ZOA (Insperger & Stepan 2004, Fig. 6 style); on Hopf lobes the two agree."""
    cut = bench_cut(0.05)
    rpm = np.array([16000.0, 17000.0, 21000.0, 22000.0])
    sdm = lobe_diagram(BENCH, TOOL, cut, COEF, rpm_range=(rpm[0], rpm[-1]), rpm=rpm, method="sdm",
                       steps_per_mode_period=40, min_steps=80)
    z = zoa.envelope(BENCH, TOOL, cut, COEF, rpm).depth_limit_m
    flip = sdm.kind == "flip"
    assert list(sdm.kind) == ["flip", "flip", "hopf", "hopf"]
    assert np.all(sdm.depth_limit_m[flip] < 0.6 * z[:2])
    # flip chatter is at an odd multiple of half the tooth-passing frequency
    f_tp = TOOL.teeth * rpm[flip] / 60
    half_orders = 2 * sdm.chatter_frequency_hz[flip] / f_tp
    assert np.allclose(half_orders, np.round(half_orders), atol=1e-6) and np.all(np.round(half_orders) % 2 == 1)
    assert np.allclose(sdm.depth_limit_m[~flip], z[~flip], rtol=0.10)


def test_slotting_zoa_and_sdm_agree_at_the_lobe_bottoms():
    cut = bench_cut(1.0)
    rpm = np.linspace(14500, 17500, 13)
    sdm = lobe_diagram(BENCH, TOOL, cut, COEF, rpm_range=(rpm[0], rpm[-1]), rpm=rpm, method="sdm",
                       steps_per_mode_period=40, min_steps=80)
    z = lobe_diagram(BENCH, TOOL, cut, COEF, rpm_range=(rpm[0], rpm[-1]), n_rpm=301)
    assert sdm.min_depth_limit_m == pytest.approx(z.min_depth_limit_m, rel=0.10)


def test_helix_pitch_depth_sdm_equals_the_exact_zoa():
    """At a depth of one helical pitch the directional matrix is constant, the delay equation is
    autonomous and the ZOA is exact. Scale the structure so the ZOA limit is that depth: the SDM
    must find it, with its O(dt^2) discretization error (2.5e-4 at 160 steps, measured)."""
    tool = Tool(3, 0.012, np.radians(40))
    cut = Cut(1e-4, 0.012, "down", [1, 0, 0], [0, 1, 0])
    coef = CuttingCoefficients(6e8, 2e8, 1e8)
    pitch_depth = 2 * np.pi / tool.teeth / helix_lag_per_m(tool)
    base = oblique_model()
    rpm = 9000.0
    scale = pitch_depth / zoa.envelope(base, tool, cut, coef, [rpm]).depth_limit_m[0]
    model = base.with_modes(stiffness_N_m=base.stiffness_N_m * scale)
    ref = zoa.envelope(model, tool, cut, coef, [rpm])
    assert ref.depth_limit_m[0] == pytest.approx(pitch_depth, rel=1e-9)
    lim = SDMProblem(model, tool, cut, coef).limit(rpm, 160, guess_m=0.8 * pitch_depth, depth_rtol=1e-5)
    assert lim.depth_limit_m == pytest.approx(pitch_depth, rel=1e-3)
    assert lim.kind == "hopf"
    assert lim.chatter_frequency_hz == pytest.approx(ref.chatter_frequency_hz[0], abs=0.1)


def test_process_damping_is_extra_damping_on_a_time_invariant_cut():
    """At the pitch depth of a slot, sum_j int r r^T g dz = a N / 4 I: process damping C adds the
    viscous damping C a N / (4 V) to a mode along n, and nothing else."""
    tool = Tool(3, 0.012, np.radians(40))
    cut = Cut(1e-4, 0.012, "down", [1, 0, 0], [0, 1, 0])
    depth = 2 * np.pi / tool.teeth / helix_lag_per_m(tool)
    rpm, c_pd = 3000.0, 2e5
    speed = np.pi * tool.diameter_m * rpm / 60
    base = ModalModel([700.0], [0.02], [5e7], [[0, 1, 0]])
    c_extra = c_pd * depth * tool.teeth / 4 / speed
    zeta2 = base.damping_ratio + c_extra / (2 * base.modal_mass_kg * base.omega_rad_s)
    damped = SDMProblem(base, tool, cut, COEF, process_damping_N_m=c_pd)
    viscous = SDMProblem(base.with_modes(damping_ratio=zeta2), tool, cut, COEF)
    assert damped.spectral_radius(rpm, depth, 60) == pytest.approx(viscous.spectral_radius(rpm, depth, 60), rel=1e-10)
    assert zeta2[0] > base.damping_ratio[0] * 1.5  # a real effect at this speed


def test_process_damping_raises_the_limit_most_at_low_speed():
    cut = bench_cut(0.5)
    gains = []
    for rpm in (2000.0, 8000.0):
        plain = SDMProblem(BENCH, TOOL, cut, COEF).limit(rpm, 200, guess_m=5e-4, chatter_frequency=False)
        pd = SDMProblem(BENCH, TOOL, cut, COEF, process_damping_N_m=3e4).limit(
            rpm, 200, guess_m=5e-4, chatter_frequency=False)
        gains.append(pd.depth_limit_m / plain.depth_limit_m)
    assert gains[0] > 1.2 and gains[0] > gains[1] > 1.0  # C / V: four times the speed, less damping


def test_sdm_lobe_diagram_records_the_step_count_and_serialises():
    d = lobe_diagram(BENCH, TOOL, bench_cut(0.05), COEF, rpm_range=(20000, 24000), n_rpm=5, method="sdm")
    res = d.resolution
    assert res.converged and res.history[-1][2] < res.rtol
    problem = SDMProblem(BENCH, TOOL, bench_cut(0.05), COEF)
    assert np.array_equal(d.steps, steps_per_period(problem, d.rpm, steps_per_mode_period=res.steps_per_mode_period,
                                                     min_steps=res.min_steps))
    out = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    assert out["method"] == "sdm" and out["resolution"]["converged"] and len(out["steps"]) == 5


def test_predict_point_sdm():
    cut = bench_cut(1.0)
    limit = SDMProblem(BENCH, TOOL, cut, COEF).limit(5000, 222, guess_m=4e-4).depth_limit_m
    p = predict_point(BENCH, TOOL, cut, COEF, spindle_rpm=5000, axial_depth_m=0.9 * limit, method="sdm")
    assert p.stable and p.spectral_radius < 1 and p.depth_limit_m == pytest.approx(limit, rel=0.01)
    q = predict_point(BENCH, TOOL, cut, COEF, spindle_rpm=5000, axial_depth_m=1.1 * limit, method="sdm")
    assert not q.stable and q.spectral_radius > 1


def test_sdm_needs_a_modal_model():
    f = np.linspace(0, 2000, 2001)
    table = FRFTable.from_entries(f, {"XX": BENCH.receptance(f)[0, 0]})
    with pytest.raises(ValueError, match="method 'sdm' needs a modal model"):
        lobe_diagram(table, TOOL, bench_cut(1.0), COEF, rpm_range=(5000, 6000), method="sdm")
    with pytest.raises(ValueError, match="method 'sdm' needs a modal model"):
        predict_point(table, TOOL, bench_cut(1.0), COEF, spindle_rpm=5000, axial_depth_m=1e-4, method="sdm")
    with pytest.raises(ValueError, match="process_damping_N_m must be >= 0"):
        SDMProblem(BENCH, TOOL, bench_cut(1.0), COEF, process_damping_N_m=-1.0)


def test_a_state_space_model_is_accepted():
    """python-control boundary: the same modes as a StateSpace give the same multipliers."""
    problem = SDMProblem(oblique_model(), TOOL, bench_cut(0.5), COEF)
    from_ss = SDMProblem(oblique_model().to_statespace(), TOOL, bench_cut(0.5), COEF)
    assert from_ss.spectral_radius(8000, 1e-3, 40) == pytest.approx(problem.spectral_radius(8000, 1e-3, 40), rel=1e-9)


def test_residual_compliance_is_ignored_with_a_warning():
    model = BENCH.with_modes(residual_compliance_m_N=np.eye(3) * 1e-9)
    with pytest.warns(UserWarning, match="ignores the residual compliance"):
        SDMProblem(model, TOOL, bench_cut(1.0), COEF)


@pytest.mark.parametrize("ratio, rpm", [(0.05, 10829.145728643216), (0.05, 18266.331658291456),
                                        (0.1, 18065.32663316583)])
def test_the_limit_is_below_a_flip_lens_under_a_stable_gap(ratio, rpm):
    # 1-DOF benchmark at low immersion: at these speeds (lens edges of a 200-speed diagram over
    # 5000-25000 rpm) a flip lens lies under a stable gap below the Hopf boundary, e.g. unstable at
    # 1.45-3.93 mm, stable again to 4.95 mm at 10 829 rpm. A search bracketing from the ZOA guess
    # found the Hopf boundary, 2-5x too high; the limit must be below every unstable depth of a
    # fine scan (60 depths up to the reported limit) and the cut unstable just above it.
    cut = bench_cut(ratio)
    point = predict_point(BENCH, TOOL, cut, COEF, spindle_rpm=rpm, axial_depth_m=1e-4, method="sdm")
    limit, steps = point.depth_limit_m, point.steps
    prob = SDMProblem(BENCH, TOOL, cut, COEF)
    depths = np.linspace(0.02, 0.995, 60) * limit
    rho, _ = prob._radii(np.full(depths.size, rpm), depths, steps)
    assert np.all(rho < 1.0), depths[rho >= 1.0]
    assert prob.spectral_radius(rpm, 1.01 * limit, steps) > 1.0
    assert point.kind == "flip"


def test_arnoldi_breakdown_keeps_a_complex_dominant_multiplier():
    """A monodromy whose Krylov space from the fixed start vector breaks down at once (the start is
    an eigenvector, 0.5) and whose dominant multipliers are a complex pair of modulus 0.95 elsewhere,
    batched with one whose Ritz values are all real: the redone row keeps its imaginary part (LAPACK
    returns a real array for the real batch, which once dropped it: modulus 0.73, a stable verdict)."""
    from stability._sdm_kernels import _arnoldi, _dominant, _start_vector

    n = 40
    v0 = _start_vector(n)
    q, _ = np.linalg.qr(np.column_stack([v0, np.random.default_rng(1).standard_normal((n, n - 1))]))
    d = np.zeros((n, n))
    d[0, 0] = 0.5
    d[1:3, 1:3] = 0.95 * np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    broken = q @ d @ q.T
    real = np.diag(np.linspace(0.1, 0.9, n))
    mu, _, _ = _arnoldi(np.stack([real, broken]), 10, False)
    assert abs(mu[1]) == pytest.approx(0.95, rel=1e-9)
    dom, _ = _dominant(np.stack([real, broken]))
    np.testing.assert_allclose(np.abs(dom), np.abs([np.linalg.eigvals(m)[np.argmax(np.abs(np.linalg.eigvals(m)))]
                                                    for m in (real, broken)]), rtol=1e-8)


def _tool_mode_problem(damping_ratio):
    """Two tool modes (720 / 735 Hz, the kr500 example's), 2-flute 30 deg helix, 6 of 25.4 mm
    down milling: at 500-1 000 rpm a tooth period holds 20-45 mode periods, reduced monodromies
    of ~500-1 500 rows, where the multiplier is found without forming the matrix."""
    model = ModalModel([720.0, 735.0], [damping_ratio] * 2, [4.0e6, 4.4e6], [[1, 0, 0], [0, 1, 0]])
    cut = Cut(5e-4, 0.006, "down", feed_direction=[0, 1, 0], normal_direction=[-1, 0, 0])
    return SDMProblem(model, Tool(2, 0.0254, np.radians(30.0)), cut, CuttingCoefficients(1.2e8, 4.5e7, 2e7))


def _lapack_dominant(problem, rpm, depth, steps):
    vals = np.linalg.eigvals(problem.monodromy(rpm, depth, steps))
    return vals[np.argmax(np.abs(vals))]


@pytest.mark.parametrize("rpm", [480.0, 900.0, 2500.0, 12000.0])
def test_the_multiplier_found_without_the_matrix_is_lapacks(rpm):
    """Matrix-free (large monodromies: ``MATRIX_FREE_MIN_SIZE``) or formed (small), the dominant
    multiplier of depths on both sides of the limit is LAPACK's on the formed matrix, to the
    Arnoldi residual test (1e-9 relative; 1e-8 leaves room for the eigenvalue's conditioning)."""
    from stability import sdm

    problem = _tool_mode_problem(0.02)
    steps = int(steps_per_period(problem, [rpm], steps_per_mode_period=20.0, min_steps=40)[0])
    depth = np.array([0.004, 0.008, 0.016])
    rho, mu = problem._radii(np.full(3, rpm), depth, steps)
    ref = np.array([_lapack_dominant(problem, rpm, a, steps) for a in depth])
    np.testing.assert_allclose(np.abs(mu), np.abs(ref), rtol=1e-8)
    np.testing.assert_allclose(rho, np.abs(ref), rtol=1e-8)
    assert np.any(rho > 1) and np.any(rho < 1)  # the depths straddle the limit
    size = problem.monodromy(rpm, depth[0], steps).shape[0]
    assert (size >= sdm.MATRIX_FREE_MIN_SIZE) == (rpm < 3000)  # both paths are exercised


def test_matrix_free_and_formed_multipliers_agree_to_rounding(monkeypatch):
    """Where 20 Arnoldi vectors converge both paths run the same iteration from the same start
    vector, so the multipliers agree to rounding (only the products' summation order differs)."""
    from stability import sdm

    problem = _tool_mode_problem(0.02)
    rpm = np.full(3, 900.0)
    depth = np.array([0.004, 0.008, 0.016])
    steps = int(steps_per_period(problem, rpm[:1], steps_per_mode_period=20.0, min_steps=40)[0])
    _, free = problem._radii(rpm, depth, steps)
    monkeypatch.setattr(sdm, "MATRIX_FREE_MIN_SIZE", np.inf)
    _, formed = problem._radii(rpm, depth, steps)
    np.testing.assert_allclose(free, formed, rtol=1e-12)


def test_a_multiplier_needing_more_krylov_vectors_is_lapacks():
    """Strongly damped (5.4 %) at 800 rpm: two multipliers of nearly equal modulus, 20 Arnoldi
    vectors do not converge; the matrix-free factorization, continued, gives LAPACK's multiplier
    (the formed path falls back to LAPACK itself on a ~1 000-row matrix)."""
    from stability import sdm
    from stability._sdm_kernels import _KRYLOV, _RESIDUAL_RTOL, _arnoldi

    problem = _tool_mode_problem(0.02 * np.e)
    rpm, depth = 800.0, 0.0185
    steps = int(steps_per_period(problem, [rpm], steps_per_mode_period=20.0, min_steps=40)[0])
    mono = problem.monodromy(rpm, depth, steps)
    assert mono.shape[0] >= sdm.MATRIX_FREE_MIN_SIZE
    mu20, _, resid = _arnoldi(mono[None], _KRYLOV, False)
    assert resid[0] > _RESIDUAL_RTOL * abs(mu20[0])  # the case needs the continuation
    _, mu = problem._radii(np.array([rpm]), np.array([depth]), steps)
    lapack = _lapack_dominant(problem, rpm, depth, steps)
    assert min(abs(mu[0] - lapack), abs(mu[0] - np.conj(lapack))) <= 1e-8 * abs(lapack)  # either of a pair
