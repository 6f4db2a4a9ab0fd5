"""Tests of the time-domain milling simulator (stability/simulate.py).

Ground truth comes from closed forms (receptance of the modal model, the exact stability boundary of
a 4-tooth slot, the mean cutting force of the force model), from the known behaviour of the
first-order-hold discretisation, and from cross-checks between equivalent systems. Every
simulation here is short (at most 15 s of a 1-DOF model at a few kHz); the whole file runs in a few
seconds once the kernel is compiled (numba caches it on disk).
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.signal
from scipy.optimize import brentq, minimize_scalar

from oma.cutting import Cut, CuttingCoefficients, Material, Tool
from oma.errors import InputError
from oma.modal import ModalModel
from stability.simulate import (
    BackgroundForce,
    Effects,
    ForceSensorDynamics,
    NonlinearCutting,
    PoseDrift,
    ProcessDamping,
    Runout,
    SensorModel,
    SimulationDiverged,
    SimulationResult,
    default_axial_slices,
    default_steps_per_tooth,
    simulate,
)

FEED = [1.0, 0.0, 0.0]
NORMAL = [0.0, 1.0, 0.0]  # a = f x n = +Z
COEFFS = CuttingCoefficients(Ktc_N_m2=6e8, Krc_N_m2=2e8, Kac_N_m2=1e8, Kte_N_m=1e4, Kre_N_m=1e4, Kae_N_m=2e3)
CHIP_ONLY = CuttingCoefficients(Ktc_N_m2=6e8, Krc_N_m2=2e8)


def _slot(teeth: int, diameter_m: float = 0.02, helix_deg: float = 0.0, fz: float = 1e-4, **cut_kw):
    tool = Tool(teeth, diameter_m, math.radians(helix_deg))
    cut = Cut(fz, diameter_m, "down", FEED, NORMAL, **cut_kw)
    return tool, cut


def _harmonics(signals: np.ndarray, steps_per_tooth: int, periods: int) -> np.ndarray:
    """DFT of the last ``periods`` whole tooth periods, normalised; bin ``m * periods`` is the
    m-th tooth harmonic. Shape (3, n_bins)."""
    n = signals.shape[1]
    window = signals[:, n - 1 - periods * steps_per_tooth: n - 1]
    return np.fft.rfft(window, axis=1) / window.shape[1]


# ------------------------------------------------------------------------- 1. forced response
@pytest.fixture(scope="module")
def forced():
    """Regeneration off, two modes (an oblique robot mode and a 700 Hz spindle mode), residual
    compliance, helix, edge forces: a periodic force with rich harmonics."""
    model = ModalModel(
        natural_frequency_hz=[40.0, 700.0],
        damping_ratio=[0.05, 0.02],
        stiffness_N_m=[2e6, 3e7],
        directions=[[1.0, 0.5, 0.2], [0.0, 1.0, 0.0]],
        residual_compliance_m_N=np.diag([1e-8, 2e-8, 5e-9]),
    )
    tool = Tool(2, 0.02, math.radians(30.0))
    cut = Cut(1e-4, 0.005, "down", FEED, [0.0, -1.0, 0.0], spindle_rpm=3000.0, axial_depth_m=0.003)
    result = simulate(model, tool, cut, COEFFS, duration_s=1.2, regeneration=False)
    return model, result


def test_step_rule_resolves_the_fastest_mode(forced):
    model, r = forced
    # 700 Hz mode, 100 Hz teeth: 20 steps per mode period -> 140 steps per tooth
    assert r.steps_per_tooth == 140
    assert r.internal_rate_hz == pytest.approx(14000.0)
    assert r.axial_slices == 12


def test_forced_response_matches_receptance(forced):
    """Displacement harmonics = G(w) @ force harmonics, 1 % and 1 degree (harmonics 1..6).

    The structure sees the force linearly interpolated between steps; for harmonic w that scales
    the response by sinc^2(w h / 2) ~ 1 - (w h)^2 / 12 with zero phase: 0.6 % at 600 Hz here.
    """
    model, r = forced
    periods = 40  # 0.4 s at the end; the 40 Hz transient has decayed by exp(-0.05 * 2 pi 40 * 0.8) ~ 4e-5
    fh = _harmonics(r.force_N, r.steps_per_tooth, periods)
    xh = _harmonics(r.displacement_m, r.steps_per_tooth, periods)
    for m in range(1, 7):
        f_hz = m / r.tooth_period_s
        predicted = model.receptance([f_hz])[:, :, 0] @ fh[:, m * periods]
        measured = xh[:, m * periods]
        assert np.linalg.norm(fh[:, m * periods]) > 0.1  # a real harmonic, not round-off
        rel = np.linalg.norm(measured - predicted) / np.linalg.norm(predicted)
        assert rel < 0.01, (m, rel)
        i = int(np.argmax(np.abs(predicted)))
        assert abs(np.degrees(np.angle(measured[i] / predicted[i]))) < 1.0, m


def test_forced_response_is_exact_first_order_hold(forced):
    """What is left is exactly the first-order hold: the sampled response of the continuous modes
    to the piecewise-linear force, ``sum_m G(w + m ws) sinc^2((w + m ws) h / 2)`` plus the
    residual compliance (which sees the samples themselves), matches to 1e-4 up to 800 Hz where
    the bare receptance is off by > 1 %. The 1e-4 covers the decayed transient (4e-5) and the
    images beyond |m| = 20 (< 1e-7)."""
    model, r = forced
    h = 1.0 / r.internal_rate_hz
    fs = r.internal_rate_hz
    periods = 40
    fh = _harmonics(r.force_N, r.steps_per_tooth, periods)
    xh = _harmonics(r.displacement_m, r.steps_per_tooth, periods)
    resid = model.residual_compliance_m_N
    images = np.arange(-20, 21)
    worst_bare = 0.0
    for m in range(1, 9):
        f_hz = m / r.tooth_period_s
        nu = f_hz + images * fs
        g_modal = model.receptance(nu) - resid[:, :, None]
        hold = np.sinc(nu * h) ** 2  # numpy sinc(x) = sin(pi x) / (pi x)
        g_sampled = np.einsum("ijk,k->ij", g_modal, hold) + resid
        predicted = g_sampled @ fh[:, m * periods]
        bare = model.receptance([f_hz])[:, :, 0] @ fh[:, m * periods]
        measured = xh[:, m * periods]
        assert np.linalg.norm(measured - predicted) / np.linalg.norm(predicted) < 1e-4, m
        worst_bare = max(worst_bare, np.linalg.norm(measured - bare) / np.linalg.norm(bare))
    assert worst_bare > 0.01  # the check above is sharper than the hold effect it accounts for


def test_mode_at_high_frequency_is_not_damped_numerically():
    """A 2 kHz mode integrated with only 5 steps per period follows the closed-form step response
    (no numerical damping, no frequency error): the transition matrix is the exact exponential.

    Four teeth in a slot with chip forces and no helix give a constant force ``F_f = -Krc fz a``
    from t = 0 (sum of sin^2 over the engaged teeth is 1), a step input that the first-order hold
    represents exactly."""
    fn, zeta, k = 2000.0, 0.01, 1e7
    model = ModalModel([fn], [zeta], [k], [FEED])
    tool, cut = _slot(4)
    # 6000 rpm, 4 teeth: T = 2.5 ms; 25 steps per tooth -> h = 0.1 ms = 1/5 of the mode's period
    r = simulate(model, tool, cut, CHIP_ONLY, duration_s=0.05, spindle_rpm=6000.0, axial_depth_m=1e-3,
                 regeneration=False, steps_per_tooth=25)
    assert r.time_s[1] == pytest.approx(1e-4)
    f_const = -CHIP_ONLY.Krc_N_m2 * 1e-4 * 1e-3
    np.testing.assert_allclose(r.force_N[0], f_const, rtol=1e-12)
    t = r.time_s
    wn = 2 * np.pi * fn
    wd = wn * math.sqrt(1 - zeta**2)
    static = f_const / k
    exact = static * (1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t)))
    np.testing.assert_allclose(r.displacement_m[0], exact, rtol=0, atol=1e-9 * abs(static))
    assert np.max(np.abs(r.displacement_m[0] - static)) > 0.5 * abs(static)  # it does ring


# ------------------------------------------------------------------------ 2. chatter onset
def _slot4_exact_boundary(model: ModalModel, krc: float, chatter_hz: float):
    """Stability boundary of a 4-tooth slot on a 1-DOF mode along the feed, closed form.

    With the mode along ``f`` the dynamic chip of tooth j is ``sin(phi_j) (x - x_T)`` and its force
    along ``f`` is ``-(Ktc sin phi cos phi + Krc sin^2 phi) (x - x_T) a``. Summed over 4 teeth
    in a slot (engaged on 0..pi) this is exactly ``-Krc a (x - x_T)``: a constant directional
    factor, so the zero-order solution (Altintas & Budak 1995) is the exact boundary, lobes
    included: ``1 = -Krc a (1 - exp(-i w T)) G(w)`` gives ``a = -1 / (2 Krc Re G(w_c))`` and
    ``w_c T = 3 pi + 2 arg G(w_c) + 2 pi k``.

    Returns depth (m) and spindle speed (rpm) of the point of lobe k = 0 with chatter frequency
    ``chatter_hz``.
    """
    g = model.receptance([chatter_hz])[0, 0, 0]
    depth = -1.0 / (2.0 * krc * g.real)
    tooth_period = (3.0 * np.pi + 2.0 * np.angle(g)) / (2.0 * np.pi * chatter_hz)
    return depth, 60.0 / (4 * tooth_period)


def _onset_by_bisection(model, tool, cut, rpm, lo, hi, *, iterations=6, duration_s=2.5):
    def growth(depth):
        r = simulate(model, tool, cut, CHIP_ONLY, duration_s=duration_s, spindle_rpm=rpm, axial_depth_m=depth)
        return r.chatter_growth(start_fraction=0.3)

    assert growth(lo) < 0.0 < growth(hi)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if growth(mid) < 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("where", ["envelope_minimum", "lobe_flank"])
def test_chatter_onset_matches_closed_form(where):
    """Regenerative chatter starts at the exact boundary (within 3 %).

    Bisection on depth between 0.7 and 1.3 times the closed form, 6 halvings: bracket 0.9 %;
    the rest of the 3 % is for the integration (50 steps per tooth, 66 per mode period), which
    measured 0.1-0.3 %. At the envelope minimum the chatter frequency minimises Re G; on the flank
    Re G is half its minimum (depth twice as large) and the boundary depends steeply on speed.
    """
    model = ModalModel([100.0], [0.02], [1e6], [FEED])
    tool, cut = _slot(4)
    f_min = minimize_scalar(lambda f: model.receptance([f])[0, 0, 0].real, bounds=(100.0, 150.0),
                            method="bounded", options={"xatol": 1e-8}).x
    if where == "envelope_minimum":
        chatter_hz = f_min
    else:
        re_min = model.receptance([f_min])[0, 0, 0].real
        chatter_hz = brentq(lambda f: model.receptance([f])[0, 0, 0].real - re_min / 2, f_min, 3 * f_min)
    depth, rpm = _slot4_exact_boundary(model, CHIP_ONLY.Krc_N_m2, chatter_hz)
    onset = _onset_by_bisection(model, tool, cut, rpm, 0.7 * depth, 1.3 * depth)
    assert onset == pytest.approx(depth, rel=0.03)


def test_chatter_growth_rate_is_zero_at_the_boundary_and_signs_around_it():
    model = ModalModel([100.0], [0.02], [1e6], [FEED])
    tool, cut = _slot(4)
    f_min = minimize_scalar(lambda f: model.receptance([f])[0, 0, 0].real, bounds=(100.0, 150.0),
                            method="bounded", options={"xatol": 1e-8}).x
    depth, rpm = _slot4_exact_boundary(model, CHIP_ONLY.Krc_N_m2, f_min)
    rates = [simulate(model, tool, cut, CHIP_ONLY, duration_s=2.5, spindle_rpm=rpm, axial_depth_m=s * depth)
             .chatter_growth(start_fraction=0.3) for s in (0.9, 1.0, 1.1)]
    # near the boundary the growth rate of the dominant root is ~ zeta w_n (a / a_lim - 1) = +-1.26 /s
    assert rates[0] < -0.5 and rates[2] > 0.5
    assert abs(rates[1]) < 0.1 * min(-rates[0], rates[2])


def test_a_cut_far_beyond_the_limit_is_an_error_not_a_record_of_infinities():
    """At 30 times the limit the vibration grows past the tool's diameter within the record (the
    tool leaving the cut does not bound it): an error saying when, not a scipy traceback from
    resampling infinities; the same moment with the progress bar, which stops there."""
    model = ModalModel([100.0], [0.02], [1e6], [FEED])
    tool, cut = _slot(4)
    f_min = minimize_scalar(lambda f: model.receptance([f])[0, 0, 0].real, bounds=(100.0, 150.0),
                            method="bounded", options={"xatol": 1e-8}).x
    depth, rpm = _slot4_exact_boundary(model, CHIP_ONLY.Krc_N_m2, f_min)
    times = []
    for progress in (False, True):
        with pytest.raises(SimulationDiverged, match="axial_depth_m.*diverged") as info:
            simulate(model, tool, cut, CHIP_ONLY, duration_s=2.0, spindle_rpm=rpm, axial_depth_m=30 * depth,
                     progress=progress)
        times.append(info.value.time_s)
    assert 0.0 < times[0] < 2.0 and times[1] == times[0]
    assert info.value.bound_m == tool.diameter_m
    assert isinstance(info.value, InputError)


# ------------------------------------------------------------------- 3. static deflection
def _mean_force_closed_form(tool: Tool, cut: Cut, coef: CuttingCoefficients, depth: float) -> np.ndarray:
    """Mean force over a revolution, machine frame, from the antiderivatives of the force model
    with ``h = fz sin(phi)`` (formats.md): per tooth and unit depth, (1/2pi) times
    F_f: [-Ktc fz sin^2/2 - Kte sin - Krc fz (phi/2 - sin 2phi/4) + Kre cos]
    F_n: [Ktc fz (phi/2 - sin 2phi/4) - Kte cos - Krc fz sin^2/2 - Kre sin]
    F_a: [-Kac fz cos + Kae phi]   between entry and exit. The helix only shifts the phase."""
    from oma.cutting import engagement_angles

    st, ex = engagement_angles(tool, cut)
    fz = cut.feed_per_tooth_m

    def prim(p):
        return np.array([
            -coef.Ktc_N_m2 * fz * np.sin(p) ** 2 / 2 - coef.Kte_N_m * np.sin(p)
            - coef.Krc_N_m2 * fz * (p / 2 - np.sin(2 * p) / 4) + coef.Kre_N_m * np.cos(p),
            coef.Ktc_N_m2 * fz * (p / 2 - np.sin(2 * p) / 4) - coef.Kte_N_m * np.cos(p)
            - coef.Krc_N_m2 * fz * np.sin(p) ** 2 / 2 - coef.Kre_N_m * np.sin(p),
            -coef.Kac_N_m2 * fz * np.cos(p) + coef.Kae_N_m * p,
        ])

    per_rev = tool.teeth * depth * (prim(ex) - prim(st)) / (2 * np.pi)
    return cut.frame.T @ per_rev


@pytest.mark.parametrize("milling,radial", [("down", 0.02), ("up", 0.006)])
def test_static_deflection_is_mean_force_over_stiffness(milling, radial):
    model = ModalModel([30.0, 45.0, 60.0], [0.05, 0.05, 0.05], [2e6, 5e6, 8e6],
                       [[1, 0, 0], [0.3, 1, 0], [0, 0.2, 1]], residual_compliance_m_N=np.diag([1e-8, 0, 2e-8]))
    tool = Tool(2, 0.02, math.radians(30.0))
    # cutting frame rotated against the machine axes: f = (X+Y)/sqrt2, n = (X-Y)/sqrt2, a = -Z
    s = 1 / math.sqrt(2)
    cut = Cut(1e-4, radial, milling, [s, s, 0.0], [s, -s, 0.0], spindle_rpm=3000.0, axial_depth_m=0.002)
    spt = 400
    r = simulate(model, tool, cut, COEFFS, duration_s=1.0, steps_per_tooth=spt)
    mean_f, mean_x = r.steady_state_mean(start_fraction=0.6)
    # the mean of a periodic response over whole periods is G(0) @ mean force exactly; what is left
    # is the decayed entry transient, exp(-0.05 * 2 pi 30 * 0.6) = 4e-3 of it, asserted < 0.5 %
    static = model.static_compliance_m_N @ mean_f
    assert np.linalg.norm(mean_x - static) < 0.005 * np.linalg.norm(static)
    # the mean force is the closed form (regeneration on, but q(t) - q(t - T) = 0 in periodic
    # steady state). Sampling a force with jumps errs by at most |jump| h per jump; every slice
    # of every tooth jumps twice a revolution by at most (sum Kc fz + sum Ke) dz, so over a tooth
    # period the mean errs by at most 2 a (sum Kc fz + sum Ke) / steps_per_tooth.
    expected = _mean_force_closed_form(tool, cut, COEFFS, 0.002)
    kc = COEFFS.Ktc_N_m2 + COEFFS.Krc_N_m2 + COEFFS.Kac_N_m2
    ke = COEFFS.Kte_N_m + COEFFS.Kre_N_m + COEFFS.Kae_N_m
    bound = 2 * 0.002 * (kc * 1e-4 + ke) / spt
    assert np.linalg.norm(mean_f - expected) < bound
    assert np.linalg.norm(expected) > 20 * bound  # the bound is tight enough to mean something


# ------------------------------------------------------------------------------ 4. effects
@pytest.fixture(scope="module")
def base_case():
    model = ModalModel([25.0, 300.0], [0.05, 0.03], [2e6, 2e7], [[1, 0, 0], [0, 1, 0]])
    tool = Tool(2, 0.02, 0.0)
    cut = Cut(1e-4, 0.02, "down", FEED, NORMAL, spindle_rpm=3000.0, axial_depth_m=0.002)
    kw = dict(duration_s=1.0, background=BackgroundForce((50.0, 50.0, 50.0), 150.0), seed=7)
    return model, tool, cut, kw


@pytest.mark.parametrize("neutral", [
    Effects(),
    Effects(runout=Runout(0.0, 1.0)),
    Effects(process_damping=ProcessDamping(0.0)),
    Effects(pose_drift=PoseDrift(0.0)),
    Effects(nonlinear_cutting=NonlinearCutting(0.0)),
    Effects(channel_delay_s=0.0),
])
def test_effects_off_by_default_and_neutral_at_zero(base_case, neutral):
    model, tool, cut, kw = base_case
    off = simulate(model, tool, cut, COEFFS, **kw)
    on = simulate(model, tool, cut, COEFFS, effects=neutral, **kw)
    for name in ("force_N", "displacement_m", "measured_force_N", "measured_displacement_m"):
        assert np.array_equal(getattr(off, name), getattr(on, name)), name


def test_runout_unequal_teeth_and_spindle_frequency():
    """A tooth on radius R + rho_j cuts the surface left by the tooth that passed the same angle
    one tooth period earlier: chip fz sin(phi) + rho_now - rho_before. With 3 teeth (slot, no
    helix, chip forces, no regeneration) one tooth is engaged at a time and at phi = 90 deg the
    force magnitude is proportional to the chip, so consecutive passes are in the ratio of
    (fz + rho_now - rho_before). Tooth j sits at 2 pi (k / spt + j) / 3 at step k: tooth 0 is at
    90 deg at k = 75 (spt = 100), tooth 2 one period later, tooth 1 after that."""
    model = ModalModel([25.0], [0.05], [2e6], [FEED])
    tool, cut = _slot(3, spindle_rpm=3000.0, axial_depth_m=0.002)
    runout = Runout(1e-5, 0.3)
    kw = dict(duration_s=0.2, regeneration=False, steps_per_tooth=100)
    plain = simulate(model, tool, cut, CHIP_ONLY, **kw)
    with_runout = simulate(model, tool, cut, CHIP_ONLY, effects=Effects(runout=runout), **kw)
    rho = runout.radii_offsets(3)
    fz = cut.feed_per_tooth_m
    k0 = 300 + 75  # one revolution in, so the tooth before has cut too
    order = [0, 2, 1, 0]  # tooth at 90 deg at k0, k0 + spt, k0 + 2 spt, k0 + 3 spt
    for m in range(1, 4):
        now, before = order[m], order[m - 1]
        expected = (fz + rho[now] - rho[before]) / fz
        got = np.linalg.norm(with_runout.force_N[:, k0 + 100 * m]) / np.linalg.norm(plain.force_N[:, k0 + 100 * m])
        assert got == pytest.approx(expected, rel=1e-12), m
    assert np.ptp(rho) > 0.1 * fz  # the teeth really differ
    # spectrum over the last 10 revolutions: bin 10 is the spindle frequency (1x), 30 the teeth
    rev = 300
    spec_plain = np.abs(np.fft.rfft(plain.force_N[0, -1 - 10 * rev:-1]))
    spec_runout = np.abs(np.fft.rfft(with_runout.force_N[0, -1 - 10 * rev:-1]))
    assert spec_plain[10] < 1e-9 * spec_plain[30]
    assert spec_runout[10] > 0.05 * spec_runout[30]


def test_force_sensor_dynamics_only_in_the_measured_force(base_case):
    """The measured force is the true force through H(s) = w^2/(s^2 + 2 zeta w s + w^2): at the
    tooth harmonics the ratio of measured forces with and without the sensor resonance is H(w),
    up to the first-order-hold factor sinc^2(w h / 2) (0.8 % at 300 Hz here). The structure is
    untouched."""
    model, tool, cut, _ = base_case
    sensor = ForceSensorDynamics(300.0, 0.05)
    kw = dict(duration_s=1.0, regeneration=False)
    plain = simulate(model, tool, cut, COEFFS, **kw)
    seen = simulate(model, tool, cut, COEFFS, effects=Effects(force_sensor=sensor), **kw)
    assert np.array_equal(plain.force_N, seen.force_N)
    assert np.array_equal(plain.displacement_m, seen.displacement_m)
    assert np.array_equal(plain.measured_displacement_m, seen.measured_displacement_m)
    # record at 1 kHz, teeth at 100 Hz: 10 samples per tooth period; last 0.5 s (sensor transient
    # decayed by exp(-0.05 * 2 pi 300 * 0.5) ~ 3e-21)
    n = 500
    a = np.fft.rfft(plain.measured_force_N[:, -n:], axis=1)
    b = np.fft.rfft(seen.measured_force_N[:, -n:], axis=1)
    h = 1.0 / seen.internal_rate_hz
    for m in (1, 2, 3, 4):
        f_hz = 100.0 * m
        i = int(np.argmax(np.abs(a[:, 50 * m])))
        ratio = b[i, 50 * m] / a[i, 50 * m]
        expected = sensor.response(f_hz)
        hold = (math.pi * f_hz * h) ** 2 / 3
        assert abs(abs(ratio) / abs(expected) - 1) < hold + 2e-3, m
        assert abs(np.degrees(np.angle(ratio / expected))) < 1.0, m
    assert abs(sensor.response(300.0)) == pytest.approx(10.0)  # amplified 1/(2 zeta) at resonance


def test_channel_delay_is_a_linear_phase(base_case):
    """Displacement read tau later: the force-displacement cross-spectrum gains -2 pi f tau."""
    model, tool, cut, kw = base_case
    tau = 2.3e-3  # not a multiple of the 1 ms record step
    kw = dict(kw, duration_s=4.0)
    plain = simulate(model, tool, cut, COEFFS, **kw)
    late = simulate(model, tool, cut, COEFFS, effects=Effects(channel_delay_s=tau), **kw)
    assert np.array_equal(plain.displacement_m, late.displacement_m)
    assert np.array_equal(plain.measured_force_N, late.measured_force_N)
    f, s0 = scipy.signal.csd(plain.measured_force_N[0], plain.measured_displacement_m[0], fs=1000.0, nperseg=1000)
    _, s1 = scipy.signal.csd(late.measured_force_N[0], late.measured_displacement_m[0], fs=1000.0, nperseg=1000)
    band = (f >= 2.0) & (f <= 300.0)
    phase = np.unwrap(np.angle(s1[band] / s0[band]))
    slope, intercept = np.polyfit(f[band], phase, 1)
    assert slope == pytest.approx(-2 * np.pi * tau, rel=0.01)
    assert abs(intercept) < 0.01
    # the magnitude is unchanged (a delay, not a filter): Welch segment edges cost < 1 %
    assert np.max(np.abs(np.abs(s1[band] / s0[band]) - 1)) < 0.01


def test_process_damping_is_added_damping_and_stabilises():
    """In a 4-tooth slot on a mode along the feed, sum_j sin^2(phi_j) = 1, so the process-damping
    force is exactly ``-(C a / V) x'``: a viscous damper. The cut at 1.2 times the undamped
    boundary chatters without it and is stable with it, and its growth rate equals that of the
    same model with damping ratio raised by ``C a / (V 2 m w_n)``."""
    fn, zeta, k = 100.0, 0.02, 1e6
    model = ModalModel([fn], [zeta], [k], [FEED])
    tool, cut = _slot(4)
    f_min = minimize_scalar(lambda f: model.receptance([f])[0, 0, 0].real, bounds=(100.0, 150.0),
                            method="bounded", options={"xatol": 1e-8}).x
    depth, rpm = _slot4_exact_boundary(model, CHIP_ONLY.Krc_N_m2, f_min)
    depth *= 1.2
    speed = math.pi * 0.02 * rpm / 60.0
    extra_zeta = 0.01
    coefficient = extra_zeta * 2 * model.modal_mass_kg[0] * model.omega_rad_s[0] * speed / depth
    kw = dict(duration_s=1.5, spindle_rpm=rpm, axial_depth_m=depth)
    without = simulate(model, tool, cut, CHIP_ONLY, **kw)
    with_pd = simulate(model, tool, cut, CHIP_ONLY, effects=Effects(process_damping=ProcessDamping(coefficient)), **kw)
    damped_model = simulate(ModalModel([fn], [zeta + extra_zeta], [k], [FEED]), tool, cut, CHIP_ONLY, **kw)
    g_without = without.chatter_growth(start_fraction=0.3)
    g_with = with_pd.chatter_growth(start_fraction=0.3)
    assert g_without > 0.5
    assert g_with < -0.5
    assert g_with == pytest.approx(damped_model.chatter_growth(start_fraction=0.3), abs=0.02)
    # trajectories agree to the predictor's velocity error, O(h dp / m): measured 2e-4
    scale = np.max(np.abs(damped_model.displacement_m))
    assert np.max(np.abs(with_pd.displacement_m - damped_model.displacement_m)) < 1e-3 * scale


def _fitted_frequency(force: np.ndarray, disp: np.ndarray, fs: float) -> float:
    """1-DOF fit of an H1 estimate: Re(1/H) = k (1 - f^2 / fn^2) is linear in f^2."""
    f, sfx = scipy.signal.csd(force, disp, fs=fs, nperseg=2000)
    _, sff = scipy.signal.welch(force, fs=fs, nperseg=2000)
    band = (f > 10.0) & (f < 40.0)
    inv = (sff[band] / sfx[band]).real
    c0, c2 = np.linalg.lstsq(np.c_[np.ones(band.sum()), -f[band] ** 2], inv, rcond=None)[0]
    return math.sqrt(c0 / c2)


@pytest.mark.parametrize("relative_change", [0.0, 0.2])
def test_pose_drift_moves_the_peak(relative_change):
    """Frequencies scale by 1 + r t / T: the mean over the first third is 1 + r/6, over the last
    1 + 5r/6. Background excitation only; the 1-DOF fit of each third's H1 found the frozen model's
    frequency within 0.3 % in trials, so the ratio is asserted within 1 %."""
    model = ModalModel([20.0], [0.05], [1e6], [FEED])
    tool, cut = _slot(2, spindle_rpm=3000.0, axial_depth_m=0.0)
    r = simulate(model, tool, cut, CHIP_ONLY, duration_s=15.0, seed=3,
                 background=BackgroundForce((200.0, 0.0, 0.0), 100.0),
                 effects=Effects(pose_drift=PoseDrift(relative_change)))
    third = r.record_time_s.size // 3
    first = _fitted_frequency(r.measured_force_N[0, :third], r.measured_displacement_m[0, :third], 1000.0)
    last = _fitted_frequency(r.measured_force_N[0, -third:], r.measured_displacement_m[0, -third:], 1000.0)
    expected = (1 + 5 * relative_change / 6) / (1 + relative_change / 6)
    assert last / first == pytest.approx(expected, rel=0.01)
    assert first == pytest.approx(20.0 * (1 + relative_change / 6), rel=0.01)


def test_nonlinear_cutting_mean_force_scales_with_fz_power():
    """With K ~ (h / h_ref)^-p and no edge forces every chip force scales as fz^(1-p): doubling
    the feed multiplies the mean force by 2^(1-p) (exactly, regeneration off), not by 2."""
    model = ModalModel([25.0], [0.05], [2e6], [FEED])
    p = 0.3
    effects = Effects(nonlinear_cutting=NonlinearCutting(p, reference_chip_m=1e-4))
    means = {}
    for name, eff in (("linear", Effects()), ("size", effects)):
        for fz in (1e-4, 2e-4):
            tool, cut = _slot(2, helix_deg=30.0, fz=fz, spindle_rpm=3000.0, axial_depth_m=0.002)
            r = simulate(model, tool, cut, CHIP_ONLY, duration_s=0.3, regeneration=False, effects=eff)
            means[name, fz] = r.steady_state_mean(start_fraction=0.5)[0]
    np.testing.assert_allclose(means["linear", 2e-4], 2.0 * means["linear", 1e-4], rtol=1e-9)
    np.testing.assert_allclose(means["size", 2e-4], 2.0 ** (1 - p) * means["size", 1e-4], rtol=1e-9)
    # at h = h_ref the model is the linear one; at smaller chips the coefficients are larger
    assert np.linalg.norm(means["size", 1e-4]) > np.linalg.norm(means["linear", 1e-4])


def test_nonlinear_cutting_default_reference_is_the_feed():
    model = ModalModel([25.0], [0.05], [2e6], [FEED])
    tool, cut = _slot(2, spindle_rpm=3000.0, axial_depth_m=0.002)
    a = simulate(model, tool, cut, CHIP_ONLY, duration_s=0.1, effects=Effects(nonlinear_cutting=NonlinearCutting(0.3)))
    b = simulate(model, tool, cut, CHIP_ONLY, duration_s=0.1,
                 effects=Effects(nonlinear_cutting=NonlinearCutting(0.3, reference_chip_m=cut.feed_per_tooth_m)))
    assert np.array_equal(a.force_N, b.force_N)


# ---------------------------------------------------------------- background and sensors
def test_background_force_variance_and_frf():
    """Background only (no cutting): the measured force has the given variance per axis, and
    the H1 estimate of the measured signals is the model's receptance.

    Variance: band-limited noise of bandwidth B over T seconds gives a relative standard error
    1 / sqrt(B T) = 1.6 % (Bendat & Piersol); asserted within 4 of those.
    H1 from 20 s of data has ~4 % random error per bin near the 20 Hz peak (the response outlives
    the Welch segment edges: coherence 0.95-0.99 with 9 averages), so per-bin agreement is
    statistical; asserted: the median over 5-100 Hz within 1 %, every bin within 15 %, and the
    record-rate H1 equal to the H1 of the internal-rate truth within 0.5 % (the sensor path --
    zero-phase anti-alias filter, cubic resampling -- does not bias the FRF).
    """
    model = ModalModel([20.0, 35.0], [0.05, 0.05], [1e6, 2e6], [[1, 0, 0], [0, 1, 1]])
    tool, cut = _slot(2, spindle_rpm=2700.0, axial_depth_m=0.0)
    variance = (232.0, 278.0, 251.0)  # Nguyen & Melkote 2020
    r = simulate(model, tool, cut, CHIP_ONLY, duration_s=20.0, seed=11,
                 background=BackgroundForce(variance, 200.0))
    measured = np.var(r.measured_force_N, axis=1)
    np.testing.assert_allclose(measured, variance, rtol=4 / math.sqrt(200.0 * 20.0))
    assert np.all(np.abs(np.mean(r.measured_force_N, axis=1)) < 4 * np.sqrt(np.array(variance) / (200.0 * 20.0)))

    def h1(force, disp, fs, seconds):
        n = int(round(seconds * fs))
        f, sff = scipy.signal.welch(force, fs=fs, nperseg=n)
        _, sfx = scipy.signal.csd(force, disp, fs=fs, nperseg=n)
        return f, sfx / sff

    f, h_rec = h1(r.measured_force_N[0], r.measured_displacement_m[0], r.sample_rate_hz, 4.096)
    f_int, h_int = h1(r.force_N[0], r.displacement_m[0], r.internal_rate_hz, 4.096)
    band = (f >= 5.0) & (f <= 100.0)
    err = np.abs(h_rec[band] / model.receptance(f[band])[0, 0] - 1)
    assert np.median(err) < 0.01
    assert np.max(err) < 0.15
    h_int_on_rec = np.interp(f[band], f_int, h_int.real) + 1j * np.interp(f[band], f_int, h_int.imag)
    assert np.max(np.abs(h_rec[band] / h_int_on_rec - 1)) < 0.005


def test_sensor_noise_and_resolution():
    """No force and no motion: the record is the sensors' noise after quantisation.

    Force: white noise of variance 0.56 N^2 quantised in 0.75 N steps has variance
    0.56 + 0.75^2 / 12 (Sheppard's correction); 30000 samples give a 0.8 % standard error,
    asserted within 4 %. Displacement: 5 um noise on a 15 um grid reads +-15 um where |noise| >
    7.5 um, a fraction 2 (1 - Phi(1.5)) = 0.1336 (standard error 0.002), asserted within 0.01.
    """
    from scipy.stats import norm

    model = ModalModel([20.0], [0.05], [1e6], [FEED])
    tool, cut = _slot(2, spindle_rpm=2700.0, axial_depth_m=0.0)
    sensors = SensorModel(force_noise_variance_N2=0.56, displacement_noise_m=5e-6, displacement_resolution_m=1.5e-5,
                          force_resolution_N=0.75)
    r = simulate(model, tool, cut, CHIP_ONLY, duration_s=10.0, seed=2, sensors=sensors)
    assert np.all(r.force_N == 0.0) and np.all(r.displacement_m == 0.0)
    assert np.var(r.measured_force_N) == pytest.approx(0.56 + 0.75**2 / 12, rel=0.04)
    f_steps = r.measured_force_N / 0.75
    assert np.allclose(f_steps, np.round(f_steps), atol=1e-9)
    x_steps = r.measured_displacement_m / 1.5e-5
    assert np.allclose(x_steps, np.round(x_steps), atol=1e-9)
    assert set(np.unique(np.round(x_steps)).tolist()) <= {-2.0, -1.0, 0.0, 1.0, 2.0}
    assert np.mean(x_steps != 0) == pytest.approx(2 * norm.sf(1.5), abs=0.01)


# -------------------------------------------------------------------- 5. determinism
def test_same_seed_same_output_different_seed_differs(base_case):
    model, tool, cut, kw = base_case
    sensors = SensorModel(force_noise_variance_N2=0.56, displacement_noise_m=1e-6)
    kw = dict(kw, duration_s=0.3, sensors=sensors)
    a = simulate(model, tool, cut, COEFFS, **dict(kw, seed=1))
    b = simulate(model, tool, cut, COEFFS, **dict(kw, seed=1))
    c = simulate(model, tool, cut, COEFFS, **dict(kw, seed=2))
    for name in ("force_N", "displacement_m", "measured_force_N", "measured_displacement_m"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert not np.allclose(getattr(a, name), getattr(c, name)), name


def test_progress_bar_gives_the_same_result(base_case, capsys):
    model, tool, cut, kw = base_case
    kw = dict(kw, duration_s=0.3)
    quiet = simulate(model, tool, cut, COEFFS, **kw)
    shown = simulate(model, tool, cut, COEFFS, progress=True, **kw)
    assert np.array_equal(quiet.displacement_m, shown.displacement_m)
    assert np.array_equal(quiet.force_N, shown.force_N)
    captured = capsys.readouterr()
    assert "simulate" in captured.err and captured.out == ""


# --------------------------------------------------------------------- 6. to_record
def test_to_record_round_trip(base_case):
    model, tool, cut, kw = base_case
    sensors = SensorModel(force_noise_variance_N2=0.56, displacement_resolution_m=1.5e-5, force_resolution_N=0.75)
    r = simulate(model, tool, cut, COEFFS, sensors=sensors, **dict(kw, duration_s=0.5))
    rec = r.to_record(name="sim", joints_deg=[88.44, -13.62, 72.42, 180.90, 59.55, -0.67])
    assert rec.sample_rate_hz == 1000.0 and rec.n_samples == 500
    np.testing.assert_array_equal(rec.force, r.measured_force_N)
    np.testing.assert_array_equal(rec.displacement, r.measured_displacement_m)
    np.testing.assert_array_equal(rec.time, r.record_time_s)
    assert [c.unit for c in rec.channels] == ["N", "N", "N", "um", "um", "um"]
    assert [(c.quantity, c.axis) for c in rec.channels[3:]] == [("displacement", a) for a in "XYZ"]
    steps = rec.displacement / 1.5e-5
    assert np.allclose(steps, np.round(steps), atol=1e-9)
    assert np.unique(rec.displacement[0]).size > 2  # the quantisation is visible, not all zero
    assert rec.sensors.displacement_resolution_m == 1.5e-5
    assert rec.sensors.force_noise_variance_N2 == 0.56
    assert rec.cut.spindle_rpm == 3000.0 and rec.cut.axial_depth_m == 0.002
    assert rec.material.cutting_coefficients == COEFFS
    # a given cut gets the simulated speed and depth
    rec2 = r.to_record(tool, Cut(1e-4, 0.02, "down", FEED, NORMAL), material=Material("acetal"))
    assert rec2.cut.spindle_rpm == 3000.0 and rec2.material.name == "acetal"


# ------------------------------------------------------------------ rules and errors
def test_default_rules():
    model = ModalModel([10.0, 25.0, 700.0], [0.05, 0.05, 0.03], [1e6, 1e6, 2e7], np.eye(3))
    t = 60.0 / (2 * 2700.0)
    assert default_steps_per_tooth(model, t, sample_rate_hz=1000.0) == math.ceil(20 * 700.0 * t)
    slow = ModalModel([10.0], [0.05], [1e6], [FEED])
    assert default_steps_per_tooth(slow, t, sample_rate_hz=1000.0) == 50
    assert default_steps_per_tooth(slow, t, sample_rate_hz=20000.0) == math.ceil(4 * 20000.0 * t)
    assert default_steps_per_tooth(slow, t, sample_rate_hz=1000.0,
                                   effects=Effects(force_sensor=ForceSensorDynamics(1000.0))) == math.ceil(20 * 1000 * t)
    assert default_axial_slices(Tool(2, 0.0254, 0.0), 0.006) == 1
    assert default_axial_slices(Tool(2, 0.0254, math.radians(30)), 0.006) == 12
    assert default_axial_slices(Tool(2, 0.0254, math.radians(45)), 0.02) == math.ceil(
        2 * 0.02 / 0.0254 / math.radians(2.0))


@pytest.mark.parametrize("kwargs,match", [
    (dict(duration_s=0.0), "duration_s"),
    (dict(duration_s=1.0, spindle_rpm=-5.0), "spindle_rpm"),
    (dict(duration_s=1.0, axial_depth_m=float("nan")), "axial_depth_m"),
    (dict(duration_s=1.0, sample_rate_hz=0.0), "sample_rate_hz"),
    (dict(duration_s=1.0, steps_per_tooth=1), "steps_per_tooth"),
    (dict(duration_s=1.0, steps_per_tooth=10), "twice the record rate"),
    (dict(duration_s=1.0, axial_slices=0), "axial_slices"),
    (dict(duration_s=0.001), "two record samples"),
    (dict(duration_s=1.0, steps_per_tooth=50, background=BackgroundForce((1.0, 1.0, 1.0), 4000.0)), "bandwidth_hz"),
])
def test_bad_parameters_raise_input_error(kwargs, match):
    model = ModalModel([20.0], [0.05], [1e6], [FEED])
    tool, cut = _slot(2, spindle_rpm=3000.0, axial_depth_m=0.001)
    with pytest.raises(InputError, match=match):
        simulate(model, tool, cut, COEFFS, **kwargs)


def test_missing_speed_and_bad_effects():
    model = ModalModel([20.0], [0.05], [1e6], [FEED])
    tool, cut = _slot(2)
    with pytest.raises(InputError, match="spindle_rpm: expected a finite number > 0, found None"):
        simulate(model, tool, cut, COEFFS, duration_s=1.0, axial_depth_m=1e-3)
    with pytest.raises(InputError, match="normal_direction"):
        simulate(model, tool, Cut(1e-4, 0.02, "down", FEED, [1.0, 1.0, 0.0]), COEFFS, duration_s=1.0,
                 spindle_rpm=3000.0, axial_depth_m=1e-3)
    with pytest.raises(InputError, match="cutting_coefficients"):
        simulate(model, tool, cut, Material("x"), duration_s=1.0, spindle_rpm=3000.0, axial_depth_m=1e-3)
    with pytest.raises(InputError, match="amplitude_m"):
        Runout(-1e-6)
    with pytest.raises(InputError, match="exponent_p"):
        NonlinearCutting(1.0)
    with pytest.raises(InputError, match="relative_change"):
        PoseDrift(-1.0)
    with pytest.raises(InputError, match="variance_N2"):
        BackgroundForce((1.0, 2.0), 100.0)
    with pytest.raises(InputError, match="frequency_hz"):
        ForceSensorDynamics(0.0)
    with pytest.raises(InputError, match="channel_delay_s"):
        Effects(channel_delay_s=float("inf"))
    with pytest.raises(InputError, match="displacement_resolution_m"):
        SensorModel(displacement_resolution_m=-1.0)


def test_chatter_growth_needs_enough_periods():
    model = ModalModel([20.0], [0.05], [1e6], [FEED])
    tool, cut = _slot(2, spindle_rpm=3000.0, axial_depth_m=1e-3)
    r = simulate(model, tool, cut, COEFFS, duration_s=0.03)
    with pytest.raises(InputError, match="tooth periods"):
        r.chatter_growth()
    with pytest.raises(InputError, match="start_fraction"):
        r.chatter_growth(start_fraction=1.0)


def test_result_is_read_only_and_summarised(base_case):
    model, tool, cut, kw = base_case
    r = simulate(model, tool, cut, COEFFS, **dict(kw, duration_s=0.2))
    assert isinstance(r, SimulationResult)
    with pytest.raises(ValueError):
        r.displacement_m[0, 0] = 1.0
    d = r.to_dict()
    assert d["steps_per_tooth"] == r.steps_per_tooth and d["n_samples"] == 200


def test_plot_on_agg(base_case):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model, tool, cut, kw = base_case
    r = simulate(model, tool, cut, COEFFS, **dict(kw, duration_s=0.2))
    fig, axes = r.plot()
    assert len(axes[0].lines) == 3 and len(axes[1].lines) == 3
    np.testing.assert_allclose(axes[1].lines[0].get_ydata(), r.measured_displacement_m[0] * 1e6)
    plt.close(fig)


def test_import_does_not_pull_matplotlib():
    code = "import sys, stability.simulate; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
