"""Output-only identification (robomill issue 14): modes without a force channel, harmonics kept out,
scaling by the cutting-force model, jackknife intervals, the CLI.

Ground truth: the paper-like cell of :mod:`oma.synthetic` (X 10.5 Hz / 5 % / 1.5e6 N/m, Y 24.8 Hz /
4 % / 3.0e6 N/m, Z 10.0 Hz / 5 % / 2.0e6 N/m), accelerations of 20 s records at 1 kHz.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from robot_helpers import shared_dir

from oma.errors import RecordError
from oma.modal import ModalModel
from oma.output_only.harmonics import remove_response_harmonics
from oma.output_only.identify import compare_models, identify_output_only
from oma.output_only.modes import output_only_modes, real_direction
from oma.output_only.scaling import scale_modes, tooth_force_harmonics
from oma.output_only.ssi import output_correlations, segment_correlations, select_modes, ssi_poles
from oma.output_only.uncertainty import jackknife, t_interval, whittle_bound
from oma.record import Channel, Record
from oma.synthetic import (milling_force, paper_like_cut, paper_like_material, paper_like_model, paper_like_tool,
                           synthetic_record)

TRUTH = paper_like_model()
#: Frequency tolerance of one 20 s record: 3 times the Whittle (Cramer-Rao) bound 0.63 % of a
#: 10 Hz / 5 % mode in 20 s (computed in notes/oo.md), so that a correct estimator fails < 0.3 %.
FREQ_TOL = 0.02
#: The benchmark's extra case: the paper-like cell and a 70 Hz mode along (1, 1, 0).
EXTRA_TRUTH = ModalModel([10.5, 24.8, 10.0, 70.0], [0.05, 0.04, 0.05, 0.03], [1.5e6, 3.0e6, 2.0e6, 4.0e6],
                         [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]])


def _record(seed, rpm=2700.0, harmonics=True, duration_s=20.0):
    return synthetic_record(duration_s=duration_s, rng=seed, spindle_rpm=rpm, harmonics=harmonics,
                            output="acceleration", runout_m=None)


def _match(found: np.ndarray, directions: np.ndarray, k: int) -> int:
    """Index of the identified mode nearest truth mode k in frequency and direction."""
    d = np.abs(found / TRUTH.natural_frequency_hz[k] - 1) + (1 - np.abs(directions @ TRUTH.directions[k]))
    return int(np.argmin(d))


def test_correlations_closed_form_and_segments_add_up():
    rng = np.random.default_rng(0)
    y = rng.standard_normal((2, 4000))
    r = output_correlations(y, 5)
    # lag 0 is the (biased-by-nothing) second moment; lag 3 of channel 0 with itself by direct sum
    assert np.allclose(r[0], y @ y.T / y.shape[1])
    assert np.isclose(r[3, 0, 0], np.dot(y[0, 3:], y[0, :-3]) / (y.shape[1] - 3))
    # segment correlations reach past the segment end: weighted by their counts they sum to the whole
    parts = [segment_correlations(y, a, b, 5) for a, b in ((0, 1000), (1000, 2500), (2500, 4000))]
    counts = [np.minimum(b - a, np.minimum(b + 5, 4000) - a - np.arange(6)) for a, b in ((0, 1000), (1000, 2500),
                                                                                        (2500, 4000))]
    total = sum(p * c[:, None, None] for p, c in zip(parts, counts)) / (4000 - np.arange(6))[:, None, None]
    assert np.allclose(total, r)


def test_ssi_recovers_two_modes_of_a_noise_driven_system():
    # two orthogonal modes, white force, 60 s of displacement at 200 Hz: frequencies to 1 %
    model = ModalModel([6.0, 15.0], [0.03, 0.02], [1e6, 2e6], [[1, 0, 0], [0, 1, 0]])
    from oma.synthetic import simulate_response

    rng = np.random.default_rng(3)
    y = simulate_response(model, 100.0 * rng.standard_normal((3, 12000)), 200.0)[:2]
    r = output_correlations(y / y.std(axis=1, keepdims=True), 60)
    sel = select_modes(ssi_poles(r, 200.0, block_rows=30, max_order=30, band_hz=(1.0, 80.0)))
    assert sel.n_modes == 2
    assert np.allclose(sel.freq_hz, [6.0, 15.0], rtol=0.01)
    assert np.allclose(sel.damping_ratio, [0.03, 0.02], rtol=0.35)  # 60 s: ~10 % sd of a 3 % mode


def test_ssi_stops_at_the_correlations_rank():
    """SSI's orders stop at the block Toeplitz matrix's numerical rank: a silent band (zero
    correlations) has no pole rather than a singular system, and one mode's noiseless correlations
    give it at order 2 whatever the orders asked."""
    assert ssi_poles(np.zeros((50, 2, 2)), 100.0, block_rows=10, max_order=10, band_hz=(1, 40)).freq_hz.size == 0
    fs, f, z = 100.0, 12.0, 0.03
    lam = np.exp((-z + 1j * np.sqrt(1 - z * z)) * 2 * np.pi * f / fs)
    r = np.real(lam ** np.arange(60))[:, None, None] * np.array([[1.0, 0.5], [0.5, 0.25]])[None]
    p = ssi_poles(r, fs, block_rows=20, max_order=20, band_hz=(1, 40))
    assert p.orders.tolist() == [2]
    np.testing.assert_allclose([p.freq_hz[0], p.damping_ratio[0]], [f, z], rtol=1e-6)


def test_real_direction_removes_phase_and_sign():
    u = np.array([0.6, -0.8, 0.0])
    assert np.allclose(real_direction(-u * np.exp(0.7j)), [-0.6, 0.8, 0.0])


def test_harmonic_regression_removes_a_line_inside_a_mode_band_and_keeps_the_mode():
    # a 24.0 Hz tooth line on the 24.8 Hz / 4 % mode: SSI without removal takes a pole at the line
    rec = _record(0, rpm=720.0)
    y = rec.vector("acceleration")
    rh = remove_response_harmonics(y, 1000.0, 720.0, 2)
    assert abs(rh.spindle_hz - 12.0) < 1e-3
    assert rh.significant[rh.freq_hz.size and 1]  # the 24 Hz tooth line stands out
    # what is left has no line at 24 Hz: its share of the power there is that of the background
    spec = lambda x: np.abs(np.fft.rfft(x[1])) ** 2  # noqa: E731
    f = np.fft.rfftfreq(y.shape[1], 1e-3)
    at = np.argmin(np.abs(f - 24.0))
    ring = (np.abs(f - 24.0) > 0.1) & (np.abs(f - 24.0) < 0.5)
    assert spec(y)[at] > 100 * np.median(spec(y)[ring])
    assert spec(rh.residual)[at] < 10 * np.median(spec(rh.residual)[ring])


@pytest.mark.parametrize("seed,rpm", [(0, 720.0), (1, 2700.0)])
def test_exactly_the_true_modes_with_harmonics_on_and_away_from_a_mode(seed, rpm):
    rec = _record(seed, rpm=rpm)
    m = output_only_modes([rec.vector("acceleration")], 1000.0, [rpm], [2])
    assert m.n_modes == 3
    assert not np.any(np.abs(m.freq_hz - 24.0) < 0.2)  # the harmonic is not reported as a mode
    for k in range(3):
        j = _match(m.freq_hz, m.directions, k)
        assert abs(m.freq_hz[j] / TRUTH.natural_frequency_hz[k] - 1) < FREQ_TOL
        assert abs(m.directions[j] @ TRUTH.directions[k]) > 0.9
        lo, hi = m.freq_interval_hz[j]
        assert lo < m.freq_hz[j] < hi and np.isfinite(m.damping_se[j])


def test_jackknife_of_a_mean_is_the_standard_error_and_t_interval():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(10)
    reps = np.array([(x.sum() - v) / 9 for v in x])[:, None]  # delete-one means
    mean, se = jackknife(reps)
    assert np.isclose(se[0], x.std(ddof=1) / np.sqrt(10))
    assert np.isclose(mean[0], x.mean())
    iv = t_interval([1.0], [0.1], 10, 0.95)
    assert np.allclose(iv, [[1 - 2.2622 * 0.1, 1 + 2.2622 * 0.1]], atol=1e-4)
    assert np.isnan(jackknife(np.array([[1.0], [np.nan], [np.nan]]))[1][0])


def test_force_harmonics_match_the_dft_of_the_force_model_and_scale_with_coefficients():
    tool, cut, mat = paper_like_tool(), paper_like_cut(2700.0), paper_like_material()
    a = tooth_force_harmonics(tool, cut, mat.cutting_coefficients, [1, 2, 4])
    # the DFT of the force sampled over 10 revolutions at an unrelated rate gives the same lines
    t = np.arange(20000) / (45.0 * 2000)
    f = milling_force(tool, cut, mat.cutting_coefficients, t)
    for h, col in zip([2, 4], a.T[1:]):
        direct = 2 * np.mean(f * np.exp(-2j * np.pi * h * 45.0 * t)[None, :], axis=1)
        assert np.allclose(col, direct, rtol=1e-3, atol=1e-6 * np.abs(direct).max())
    assert np.allclose(a[:, 0], 0, atol=1e-6 * np.abs(a).max())  # no runout: no spindle line
    from dataclasses import replace

    double = replace(mat.cutting_coefficients, **{k: 2 * v for k, v in vars(mat.cutting_coefficients).items()})
    assert np.allclose(tooth_force_harmonics(tool, cut, double, [2]), 2 * a[:, 1:2])


def test_scale_modes_recovers_stiffness_and_spindle_angle_from_exact_lines():
    tool, mat = paper_like_tool(), paper_like_material()
    cut = paper_like_cut(720.0)
    orders = np.array([2, 4, 6])
    force = tooth_force_harmonics(tool, cut, mat.cutting_coefficients, orders)
    lines = orders * 12.0
    theta = 1.1
    g = TRUTH.receptance(lines)
    x = np.einsum("ijh,jh->ih", g, force) * np.exp(1j * orders * theta)[None, :]
    noise = 1e-3 * np.abs(x).max() * np.ones(x.shape)
    s = scale_modes(TRUTH.natural_frequency_hz, TRUTH.damping_ratio, TRUTH.directions, [x], [noise], [force],
                    [lines], [orders], coefficient_relative_sd=0.1)
    assert np.allclose(s.stiffness_N_m, TRUTH.stiffness_N_m, rtol=1e-6)
    assert np.isclose(np.angle(np.exp(2j * (s.theta_rad[0] - theta))), 0, atol=1e-6)
    assert np.all(s.relative_sd >= 0.1) and np.all(s.interval_N_m[:, 0] < TRUTH.stiffness_N_m)


def test_a_line_inside_a_modes_band_does_not_carry_its_damping_error_into_the_stiffness(monkeypatch):
    """Exact lines at 24, 48, 72, 96 Hz (720 rpm, 2 teeth), the 24 Hz line inside the 24.8 Hz / 4 %
    mode's half-power band, and that mode's damping passed 15 % high with a 15 % standard error.
    Through the in-band line, ``|1 - r^2 + 2 i zeta r|`` grows by 9 %; the lines above the modes
    hardly depend on damping. Weighted by their noise alone the in-band line (the loudest, equal
    noise) sets the mode's scale: stiffness 8 % low. Weighted by their effective variance (noise
    plus the spread the modes' errors give each line's prediction) within 1 %, and both intervals
    hold the truth."""
    import oma.output_only.scaling as scaling

    tool, mat = paper_like_tool(), paper_like_material()
    orders = np.array([2, 4, 6, 8])
    force = tooth_force_harmonics(tool, paper_like_cut(720.0), mat.cutting_coefficients, orders)
    lines = orders * 12.0
    x = np.einsum("ijh,jh->ih", TRUTH.receptance(lines), force) * np.exp(1j * orders * 1.1)[None, :]
    noise = 1e-3 * np.abs(x).max() * np.ones(x.shape)
    zeta = TRUTH.damping_ratio * np.array([1.0, 1.15, 1.0])
    errors = {}
    for iterations in (0, scaling.EFFECTIVE_VARIANCE_ITERATIONS):
        monkeypatch.setattr(scaling, "EFFECTIVE_VARIANCE_ITERATIONS", iterations)
        s = scale_modes(TRUTH.natural_frequency_hz, zeta, TRUTH.directions, [x], [noise], [force], [lines], [orders],
                        freq_se_hz=0.003 * TRUTH.natural_frequency_hz, damping_se=0.15 * zeta,
                        direction_se_rad=np.full(3, 0.01), coefficient_relative_sd=0.0)
        errors[iterations] = s.stiffness_N_m[1] / TRUTH.stiffness_N_m[1] - 1
        assert s.interval_N_m[1, 0] < TRUTH.stiffness_N_m[1] < s.interval_N_m[1, 1]
    assert errors[0] < -0.05 and abs(errors[scaling.EFFECTIVE_VARIANCE_ITERATIONS]) < 0.01, errors


def test_the_z_mode_beside_x_is_not_scalable_and_says_so_with_an_unbounded_sd():
    """Exact lines (720 rpm, 2 teeth), every mode in its true direction: X and Y are scaled to a
    few % even with 0.01 rad direction errors, but Z (10.0 Hz beside X's 10.5 Hz, an axial force a
    sixth of the feed force) is uncertain by more than 20 % from those 0.01 rad alone: X's response
    leaks into the Z channel as much as Z's own. With 0.3 rad on Z, draws leave it unscaled and its
    sd is infinite (the JSON's null), never a finite number standing in for infinity."""
    tool, mat = paper_like_tool(), paper_like_material()
    orders = np.array([2, 4, 6])
    force = tooth_force_harmonics(tool, paper_like_cut(720.0), mat.cutting_coefficients, orders)
    lines = orders * 12.0
    x = np.einsum("ijh,jh->ih", TRUTH.receptance(lines), force) * np.exp(1j * orders * 1.1)[None, :]
    noise = 1e-3 * np.abs(x).max() * np.ones(x.shape)
    for se_z in (0.01, 0.3):
        s = scale_modes(TRUTH.natural_frequency_hz, TRUTH.damping_ratio, TRUTH.directions, [x], [noise], [force],
                        [lines], [orders], freq_se_hz=0.003 * TRUTH.natural_frequency_hz,
                        damping_se=0.1 * TRUTH.damping_ratio, direction_se_rad=np.array([0.01, 0.01, se_z]),
                        coefficient_relative_sd=0.1)
        assert np.all(s.statistical_relative_sd[:2] < 0.05) and not s.too_far[:2].any()
        assert s.statistical_relative_sd[2] > 0.2 and s.too_far[2]
        if se_z > 0.1:
            assert np.isinf(s.statistical_relative_sd[2]) and np.isinf(s.relative_sd[2])
            assert s.to_dict()[2]["relative_sd"] is None and s.to_dict()[2]["harmonics_too_far"]


def test_identify_output_only_scales_x_and_y_and_flags_what_it_cannot():
    rec = _record(4)
    res = identify_output_only([rec])
    assert res.scaling == "force_model" and res.model.n_modes == 3
    for k in (0, 1):  # X and Y: the 90 Hz tooth line scales them to a few %
        j = _match(res.model.natural_frequency_hz, res.model.directions, k)
        assert abs(res.model.stiffness_N_m[j] / TRUTH.stiffness_N_m[k] - 1) < 0.10
    d = res.to_dict()
    assert {"model", "scaling", "stiffness_uncertainty", "modes", "warnings"} <= set(d)
    assert d["undetermined_directions"] == []     # every direction pinned (errors under 30 degrees)
    # the model's directions are those the mass lines turned (the lines solved with them), each
    # mode entry keeps the resonance band's
    assert d["directions_source"] == "mass lines"
    assert not np.allclose(res.model.directions, res.modes.directions)
    assert [m["direction"] for m in d["modes"]] == res.modes.directions.tolist()
    fig, ax = res.plot()  # Agg: one error bar per mode, the 90 Hz line drawn
    assert len(ax.lines) >= 1 and ax.get_xlabel() == "natural frequency (Hz)"
    import matplotlib.pyplot as plt

    plt.close(fig)
    assert all("stiffness_uncertainty" in m for m in d["modes"])
    json.dumps(d)


def test_close_modes_take_the_refined_directions_and_scale_better():
    """The close pair (10.0 / 10.5 Hz) takes the ML refinement's directions, the separate 24.8 Hz
    mode keeps SSI's exactly; over eight records the X stiffness is scaled better with them
    (measured 2026-11-25, seeds 0-7: mean |error| 3.2 % with SSI's directions, 1.8 % with the
    refined ones; the benchmark's worst records 15-18 % -> 9-10 %). Since the lines are solved
    with the directions the mass lines turn (session 19) the start matters little: mean 1.0 % from
    SSI's, 1.1 % from the refined ones, at most 3.1 %; the Z direction 10.5 -> 6.1 degrees off in
    the mean."""
    err = {False: [], True: []}
    angle = {"refined": [], "turned": []}   # the Z mode's direction off the truth, degrees
    for seed in range(8):
        res = {opt: identify_output_only([_record(seed)], ml_directions=opt) for opt in (False, True)}
        # the identified modes' directions (the model's are those the mass lines turned, from either start)
        jy = [_match(r.modes.freq_hz, r.modes.directions, 1) for r in res.values()]
        np.testing.assert_array_equal(res[False].modes.directions[jy[0]], res[True].modes.directions[jy[1]])
        for opt, r in res.items():
            j = _match(r.model.natural_frequency_hz, r.model.directions, 0)
            err[opt].append(r.model.stiffness_N_m[j] / TRUTH.stiffness_N_m[0] - 1)
        r = res[True]
        jz = _match(r.model.natural_frequency_hz, r.model.directions, 2)
        for key, u in (("refined", r.modes.directions[jz]), ("turned", r.model.directions[jz])):
            angle[key].append(np.degrees(np.arccos(min(1.0, abs(u @ TRUTH.directions[2]) / np.linalg.norm(u)))))
    ssi, refined = (np.abs(err[o]) for o in (False, True))
    assert refined.mean() < 0.02 and refined.max() < 0.05 and ssi.max() < 0.05, (ssi, refined)
    # the mass lines turn the Z mode nearer the truth than the resonance band left it
    assert np.mean(angle["turned"]) < 0.7 * np.mean(angle["refined"]), angle


def test_a_mode_whose_direction_the_record_does_not_pin_leaves_the_model_untrusted(monkeypatch):
    """A mode whose direction's standard error exceeds MAX_DIRECTION_SE_DEG (a false mode of an
    independent generator had 44 degrees; the benchmark's true modes at most 24) is named in a
    warning and in the JSON, and the model is not trusted. A structure whose modes the lines all
    scale (in-plane modes at 30 degrees, Z apart at 17 Hz) is trusted as identified, and not with
    one direction's error put over the limit."""
    from dataclasses import replace as dc_replace

    import oma.output_only.identify as ident
    from test_oma_output_only_spindle import OBLIQUE

    rec = synthetic_record(OBLIQUE, duration_s=20.0, rng=10_000, spindle_rpm=2700.0, output="acceleration",
                           runout_m=None)
    base = identify_output_only([rec])
    assert base.trusted and base.to_dict()["undetermined_directions"] == []
    real = ident.output_only_modes

    def loose(*args, **kwargs):   # the 26 Hz mode's direction error put at 35 degrees
        m = real(*args, **kwargs)
        se = np.array(m.direction_se_rad)
        se[np.argmin(np.abs(m.freq_hz - 26.0))] = np.radians(ident.MAX_DIRECTION_SE_DEG + 5.0)
        return dc_replace(m, direction_se_rad=se)

    monkeypatch.setattr(ident, "output_only_modes", loose)
    res = identify_output_only([rec])
    j = int(np.argmin(np.abs(res.modes.freq_hz - 26.0)))
    d = res.to_dict()
    assert [e["freq_hz"] for e in d["undetermined_directions"]] == [pytest.approx(res.modes.freq_hz[j])]
    assert any(f"mode at {res.modes.freq_hz[j]:.2f} Hz: its direction is uncertain by 35 degrees" in w
               for w in res.warnings)
    assert not res.trusted


def test_no_harmonics_no_scale_and_untrusted():
    res = identify_output_only([_record(5, harmonics=False)])
    assert res.scaling == "none" and not res.trusted and not res.scaled
    assert any("no tooth-passing line" in w for w in res.warnings)
    assert res.to_dict()["directions_source"] == "resonance band"
    np.testing.assert_array_equal(res.model.directions, res.modes.directions)


def test_compare_models_pairs_by_frequency_and_direction():
    other = TRUTH.with_modes(stiffness_N_m=TRUTH.stiffness_N_m * 1.1)
    c = compare_models(other, TRUTH)
    assert np.allclose([e["stiffness_ratio"] for e in c], 1.1)
    lone = ModalModel([50.0], [0.02], [1e6], [[1, 0, 0]])
    assert compare_models(lone, TRUTH)[0]["reference"] is None
    assert c[0]["frequency_z"] is None  # no standard errors given
    # with them: the difference over the combined standard error
    shifted = TRUTH.with_modes(natural_frequency_hz=TRUTH.natural_frequency_hz + 0.03)
    se = (np.full(3, 0.03), np.full(3, 0.004))
    c = compare_models(shifted, TRUTH, standard_errors=se, reference_standard_errors=(np.full(3, 0.04), np.full(3, 0.003)))
    assert np.allclose([e["frequency_z"] for e in c], 0.03 / 0.05) and np.allclose([e["damping_z"] for e in c], 0.0)


def test_a_record_without_a_z_channel_gives_its_x_and_y_modes_and_says_what_it_cannot_see():
    """An accelerometer with X and Y only (a two-axis sensor, or a Z channel dropped): the record's
    Z row is absent. Before session 23 finding the cut's window from the tooth line read the NaN Z
    row and raised an internal error; now X and Y are identified as from three channels and a
    warning says that nothing along Z is seen."""
    from dataclasses import replace

    rec = _record(0)
    xy = replace(rec, channels=tuple(Channel(a.lower(), "acceleration", a, "m/s2") for a in "XY"),
                 data=rec.vector("acceleration")[:2])
    res = identify_output_only([xy])
    assert res.modes.n_modes == 2
    for k in (0, 1):   # X 10.5 Hz, Y 24.8 Hz
        j = _match(res.modes.freq_hz, res.modes.directions, k)
        assert abs(res.modes.freq_hz[j] / TRUTH.natural_frequency_hz[k] - 1) < FREQ_TOL
        assert abs(res.model.stiffness_N_m[j] / TRUTH.stiffness_N_m[k] - 1) < 0.15
    assert np.allclose(res.modes.directions[:, 2], 0.0)
    assert sum("no Z channel" in w for w in res.warnings) == 1


def test_the_cut_is_found_from_a_clear_tooth_line_and_not_from_one_in_the_noise():
    """The cut's window from the tooth line's envelope. Accelerations whose tooth lines start 6 s
    into the record (the first 6 s of a record without them): the window starts there. Displacements
    of a record that cuts throughout: the line stands about 2 times over the noise beside it (5
    needed), and before session 23 the noise's dips were read as gaps (this record cut to 7.8-20 s);
    now the whole record is used and a warning says why no window could be told."""
    from dataclasses import replace

    full = _record(0)
    idle = _record(0, harmonics=False)
    n0 = int(6.0 * full.sample_rate_hz)
    data = full.data.copy()
    data[:, :n0] = idle.data[:, :n0]
    res = identify_output_only([replace(full, data=data)])
    win = [w for w in res.warnings if "tooth-passing line is present only from" in w]
    assert len(win) == 1
    start, stop = (float(v) for v in win[0].split("present only from ")[1].split(" s of")[0].split(" to "))
    assert 6.0 <= start < 7.0 and stop == 20.0

    disp = synthetic_record(duration_s=20.0, rng=0, spindle_rpm=2700.0, harmonics=True, output="displacement",
                            runout_m=None)
    res = identify_output_only([disp])
    assert not any("present only from" in w for w in res.warnings)
    assert sum("too weak to tell whether the tool cuts throughout" in w for w in res.warnings) == 1


def test_a_dead_motion_channel_is_taken_as_not_recorded():
    """A Z accelerometer channel that reads 0 throughout (a dead sensor, a cable off) had raised an
    internal error (the channels' unit scaling divided by its zero power); it is named and taken as
    not recorded: the same modes as without the channel."""
    from dataclasses import replace

    rec = _record(0)
    data = rec.data.copy()
    data[[i for i, c in enumerate(rec.channels) if c.quantity == "acceleration" and c.axis == "Z"][0]] = 0.0
    res = identify_output_only([replace(rec, data=data)])
    xy = replace(rec, channels=tuple(Channel(a.lower(), "acceleration", a, "m/s2") for a in "XY"),
                 data=rec.vector("acceleration")[:2])
    ref = identify_output_only([xy])
    np.testing.assert_array_equal(res.modes.freq_hz, ref.modes.freq_hz)
    assert sum("Z motion channel is constant" in w for w in res.warnings) == 1
    # every motion channel constant: a record error (one line, exit 2 from the CLI), no traceback
    data[[i for i, c in enumerate(rec.channels) if c.quantity == "acceleration"]] = 0.0
    with pytest.raises(RecordError, match="only constant ones"):
        identify_output_only([replace(rec, data=data)])


def test_a_one_axis_record_gives_the_mode_along_it():
    """One accelerometer axis (X): SSI's one-channel Toeplitz matrix, decimated with a steep filter,
    has numerical rank 50 of the 60 orders asked, and its shifted system was singular there (an
    internal error before session 23). The orders stop at the rank: the X mode is found, and the
    warning says what is not seen."""
    from dataclasses import replace

    rec = _record(0)
    x = replace(rec, channels=(Channel("x", "acceleration", "X", "m/s2"),), data=rec.vector("acceleration")[:1])
    res = identify_output_only([x])
    assert res.modes.n_modes >= 1
    j = int(np.argmin(np.abs(res.modes.freq_hz - 10.5)))
    assert abs(res.modes.freq_hz[j] / 10.5 - 1) < FREQ_TOL
    assert res.modes.damping_interval[j, 0] <= 0.05 <= res.modes.damping_interval[j, 1]
    assert sum("no Y, Z channel" in w for w in res.warnings) == 1


def test_errors():
    rec = _record(6, duration_s=2.0)
    with pytest.raises(ValueError, match="scaling must be"):
        identify_output_only([rec], scaling="guess")
    with pytest.raises(ValueError, match="at least one record"):
        identify_output_only([])
    force_only = Record(1000.0, (Channel("Fx", "force", "X", "N"),), np.zeros((1, 100)), rec.tool, rec.cut)
    with pytest.raises(RecordError, match="displacement, velocity or acceleration"):
        identify_output_only([force_only])
    other_rate = Record(500.0, rec.channels, rec.data, rec.tool, rec.cut)
    with pytest.raises(RecordError, match="sample_rate_hz"):
        identify_output_only([rec, other_rate])
    with pytest.raises(ValueError, match="too short"):
        output_only_modes([rec.vector("acceleration")[:, :20]], 1000.0, [2700.0], [2])


def test_cli_output_only_json_with_force_comparison(tmp_path, capsys):
    from oma.record_io import write_record
    from planner.cli import main

    rec = synthetic_record(duration_s=20.0, rng=7, spindle_rpm=2700.0, output="acceleration", runout_m=None)
    write_record(rec, tmp_path / "rec")
    code = main(["identify", str(tmp_path / "rec"), "--output-only", "--json", "-o", str(tmp_path / "m.yaml")])
    payload = json.loads(capsys.readouterr().out)
    assert payload["scaling"] == "force_model"
    assert len(payload["stiffness_uncertainty"]) == len(payload["model"]["modes"]) == 3
    comp = payload["force_based"]["comparison"]
    assert all(abs(c["frequency_ratio"] - 1) < 0.03 for c in comp)
    # both ways carry standard errors: the differences in combined sds are finite and modest
    assert all(c["frequency_z"] is not None and abs(c["frequency_z"]) < 5 for c in comp)
    assert code in (0, 1) and ((tmp_path / "m.yaml").exists() == (code == 0))
    # the model file and the "no model written" warning exclude each other (they did not: the warning
    # hung on the --plot branch and was given whenever no plot was asked for)
    assert (tmp_path / "m.yaml").exists() != any("no model written" in w for w in payload["warnings"])
    main(["identify", str(tmp_path / "rec"), "--output-only", "-o", str(tmp_path / "m2.yaml")])
    text = capsys.readouterr().out
    assert ("model written to" in text) == (tmp_path / "m2.yaml").exists() != ("no model written" in text)
    assert main(["identify", str(tmp_path / "rec"), "--output-only", "--coefficient-uncertainty", "2"]) == 2
    assert "coefficient-uncertainty" in capsys.readouterr().err
    assert main(["identify", str(tmp_path / "rec"), "--output-only", "--reference", "x.csv"]) == 2
    assert "--reference" in capsys.readouterr().err
    # the measured force lines scale the modes with no coefficient uncertainty to carry
    main(["identify", str(tmp_path / "rec"), "--output-only", "--scale-with", "measured_force", "--json",
          "--plot", str(tmp_path / "modes.png")])
    assert (tmp_path / "modes.png").stat().st_size > 0
    measured = json.loads(capsys.readouterr().out)
    assert measured["scaling"] == "measured_force"
    assert all(s["coefficient_relative_sd"] == 0 for s in measured["stiffness_uncertainty"])


def test_whittle_bound_tends_to_the_small_damping_closed_form():
    sd_f, sd_z = whittle_bound(10.0, 0.05, 20.0)
    assert np.isclose(sd_f, np.sqrt(0.05 / (2 * np.pi * 10.0 * 20.0)), rtol=0.01)
    assert np.isclose(sd_z, np.sqrt(1 / (2 * np.pi * 0.05 * 10.0 * 20.0)), rtol=0.02)
    # four times the data, half the spread
    assert np.isclose(whittle_bound(10.0, 0.05, 80.0)[0], sd_f / 2, rtol=1e-6)


def _hurco_record(name, window_s=None):
    """A real Hurco file of shared/data as an output-only record (accelerations, no force), its
    spindle speed and flutes from the file: ``window_s`` seconds from a quarter of that into the
    file, or (None) the span where the tool cuts."""
    from oma.cutting import Cut, Tool
    from planner.diagnosis.hurco import cutting_span, read_hurco_csv

    path = shared_dir() / "data" / "milling-vibration-hurco" / name
    h = read_hurco_csv(path)
    if window_s is None:
        span = cutting_span(h.acceleration_m_s2, h.sample_rate_hz)
    else:
        n = int(window_s * h.sample_rate_hz)
        span = slice(n // 4, n // 4 + n)
    cut = Cut(1e-4, 0.006, "down", [1, 0, 0], [0, 1, 0], spindle_rpm=float(h.spindle_rpm[0]))
    return Record(h.sample_rate_hz, tuple(Channel(a.lower(), "acceleration", a, "m/s2") for a in "XYZ"),
                  np.asarray(h.acceleration_m_s2)[:, span], Tool(h.teeth, 0.0127), cut, name=path.name)


def test_real_hurco_accelerations_identified_but_not_trusted_without_coefficients():
    # one real file of shared/data (its README): a 4000 rpm, 4-flute steel cut, 8 s of it
    rec = _hurco_record("EBI_F20IN_T50_D0p05IN_4000RPM.csv", window_s=8.0)
    assert rec.tool.teeth == 4 and rec.cut.spindle_rpm == 4000.0
    res = identify_output_only([rec], band_hz=(20.0, 600.0))
    # the spindle found within 1 % of the name's 4000 rpm, from the response's own comb
    assert abs(res.modes.harmonics[0].spindle_hz / (4000 / 60) - 1) < 0.01
    assert res.scaling == "none" and not res.trusted
    # no reported mode sits on a tooth-passing line with tone-like damping
    lines = res.modes.harmonics[0].freq_hz
    for f, z in zip(res.modes.freq_hz, res.modes.damping_ratio):
        assert not (np.min(np.abs(lines / f - 1)) < 0.005 and z < 0.01)


def test_a_mode_the_refinement_takes_onto_a_milling_line_is_not_reported():
    # a real 12000 rpm file (1650 Hz sampling, no anti-aliasing: the 200 Hz spindle's multiples fold
    # onto the band): two SSI modes refine onto folded lines at 0.90 and 0.13 % damping, where SSI's
    # own rule calls a pole the line's remainder (session 22; both were reported as modes before)
    from oma.output_only.harmonics import HARMONIC_MAX_DAMPING, HARMONIC_TOLERANCE

    res = identify_output_only([_hurco_record("EBI_T50_0p125IN_12000RPM.csv")], band_hz=(20.0, 600.0),
                               alias_up_to=4.0)
    lines = res.modes.harmonics[0].freq_hz
    for f, z in zip(res.modes.freq_hz, res.modes.damping_ratio):
        assert not (np.min(np.abs(lines / f - 1)) < HARMONIC_TOLERANCE and z < HARMONIC_MAX_DAMPING)
    named = [w for w in res.modes.warnings if w.startswith("mode refined to")]
    assert len(named) >= 1 and all("milling line's remainder" in w for w in named)
    assert not res.trusted


def test_a_scoring_fit_stopped_short_is_finished_to_the_optimum():
    """The refinement's finish (:func:`oma.output_only._ml_fit._finish`): a close pair's Whittle fit
    that Fisher scoring left after three steps is carried to within 0.1 of the optimum's ``-log L``
    found by a long BFGS run, and its damping to within a tenth of its standard error of the
    optimum's; an optimum is returned as it is."""
    from scipy.optimize import minimize

    from oma.output_only import whittle as wh
    from oma.output_only._ml_fit import FINISH_MIN_GAIN, _finish, _initial, _scoring
    from oma.output_only._ml_inference import _information_se

    rng = np.random.default_rng(7)
    m, l = 2, 3
    w = 2 * np.pi * np.arange(7.5, 13.5, 0.05)
    gain = (w / w.mean()) ** 4
    f_true, z_true = np.array([10.0, 10.5]), np.array([0.05, 0.05])
    mod = wh._Model(m, l, w, gain / gain.mean(), np.zeros((w.size, l, 0), dtype=complex), True, (f_true, z_true))
    tm, tl = wh._free_c(mod), wh._tril(l)
    p_true = np.concatenate([np.zeros(m), np.log(z_true), [0.0, 0.0, 1.0, 1.0, 0.0, 0.0],
                             np.where(tm[0] == tm[1], 1.0, 0.0), np.where(tl[0] == tl[1], 0.05, 0.0)])
    s = wh._spectrum(p_true, mod)[-1]
    x = (np.linalg.cholesky(s) @ ((rng.normal(size=(w.size, l)) + 1j * rng.normal(size=(w.size, l))) / np.sqrt(2))[
        :, :, None])[..., 0]
    start = _initial(mod, f_true * np.array([1.01, 0.99]), 1.6 * z_true, np.array([[0.3, 1.0], [0.2, 0.1], [1.0, 0.3]]), x)
    short, v_short = _scoring(start, mod, x, max_iter=3)
    best = minimize(lambda q: wh._nll(q, mod, x), short, jac=True, method="BFGS",
                    options={"maxiter": 5000, "gtol": 1e-8})
    assert v_short - best.fun > 2 * FINISH_MIN_GAIN      # the short fit is worth finishing
    done, v_done, iterations = _finish(short, mod, x)
    assert 0 < iterations and v_done - best.fun < 0.1
    u = wh._unpack(best.x, mod).u
    se_log_z = _information_se(best.x, mod, x, u, np.ones(l))[1]
    z_done, z_best = wh._unpack(done, mod).z, wh._unpack(best.x, mod).z
    assert np.all(np.abs(np.log(z_done / z_best)) < 0.1 * se_log_z)
    again = _finish(best.x, mod, x)
    assert again[0] is best.x and again[1] == wh._nll(best.x, mod, x)[0]


@pytest.mark.parametrize("noise,n_residual,slope,coherent,signed", [
    (True, 0, False, True, False), (False, 6, False, True, False), (True, 6, False, True, False),
    (True, 6, True, False, False), (True, 0, True, True, True), (False, 6, True, True, False)])
def test_whittle_likelihood_gradient_and_fisher_match_finite_differences(noise, n_residual, slope, coherent, signed):
    """The ML refinement's analytic gradient (frequency, damping, direction, input and background
    covariances, with and without the residual terms of out-of-band modes, coherent with the modes
    or not, the input's slope, the background's sign free) against central differences of the
    likelihood, and its Fisher information against ``Re sum tr(S^-1 dS_i S^-1 dS_j)`` with ``dS``
    by central differences of the spectrum. The summed likelihood and the information are
    compiled loops (:mod:`oma.output_only._whittle_kernels`); the bins' scores are NumPy's stacked
    products: their sum is the compiled gradient."""
    from oma.output_only import whittle as ml

    rng = np.random.default_rng(3)
    m, l, k = 2, 3, 40
    w = 2 * np.pi * np.linspace(8.0, 12.5, k)
    mod = ml._Model(m, l, w, (w / w.mean()) ** 4, ml._residual_columns(w, l)[:, :, :n_residual], noise,
                    (np.array([10.0, 10.5]), np.array([0.05, 0.05])), coherent=coherent, slope=slope,
                    signed_background=signed)
    x = rng.normal(size=(k, l)) + 1j * rng.normal(size=(k, l))
    tm = ml._free_c(mod)
    nc = tm[0].size
    p = 0.5 * rng.normal(size=2 * m + m * l + nc + (6 if noise else 0) + int(slope))
    p[2 * m + m * l:2 * m + m * l + nc] += (tm[0] == tm[1])
    if noise:
        p[2 * m + m * l + nc:2 * m + m * l + nc + 6] += [1.0, 0.0, 1.0, 0.0, 0.0, 1.0]
    _, grad = ml._nll(p, mod, x)
    h = 1e-6
    steps = np.eye(p.size) * h
    num = np.array([(ml._nll(p + e, mod, x)[0] - ml._nll(p - e, mod, x)[0]) / (2 * h) for e in steps])
    np.testing.assert_allclose(grad, num, rtol=1e-5, atol=1e-6 * np.max(np.abs(num)))

    def spectrum(q):
        pp = ml._unpack(q, mod)
        v = ml._columns(pp, mod)[1]
        return ml._gain(pp, mod)[:, None, None] * (v @ pp.c @ np.conj(np.swapaxes(v, 1, 2))) + pp.n[None]

    sinv = np.linalg.inv(spectrum(p))
    ds = [(spectrum(p + e) - spectrum(p - e)) / (2 * h) for e in steps]
    ref = np.array([[np.real(np.einsum("kab,kbc,kcd,kda->", sinv, a, sinv, b)) for b in ds] for a in ds])
    if slope:
        ref[-1, -1] += 1.0 / ml.SLOPE_PRIOR_SD ** 2     # the slope's prior is in the information
    np.testing.assert_allclose(ml._fisher(p, mod), ref, rtol=1e-6, atol=1e-7 * np.max(np.abs(ref)))
    # the bins' scores (the sandwich's ingredients) add up to the gradient (less the slope's prior)
    val, per_bin = ml._nll(p, mod, x, per_bin=True)
    prior = np.zeros(p.size)
    if slope:
        beta = ml._unpack(p, mod).beta
        prior[-1] = beta / ml.SLOPE_PRIOR_SD ** 2
        val += 0.5 * (beta / ml.SLOPE_PRIOR_SD) ** 2
    assert per_bin.shape == (k, p.size) and val == pytest.approx(ml._nll(p, mod, x)[0], rel=1e-12)
    np.testing.assert_allclose(per_bin.sum(axis=0) + prior, grad, rtol=1e-10, atol=1e-12 * np.max(np.abs(grad)))
    # a model spectrum that is not positive definite (the background of one channel and no
    # residual terms: rank-deficient) is no fit in both paths
    if noise and not n_residual:
        q = p.copy()
        q[2 * m + m * l + nc:2 * m + m * l + nc + 6] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        q[2 * m + m * l:2 * m + m * l + nc] = 0.0
        assert ml._nll(q, mod, x)[0] >= 1e30 and ml._fisher(q, mod) is None


def test_information_errors_match_the_scatter_of_the_ml_estimate():
    """The refinement's standard errors (the larger of the inverse Fisher information and the
    sandwich) against the scatter of its own estimates over periodograms drawn from a known close
    pair (10.0 / 10.5 Hz, 5 %, along Z and X, a constant background; 0.05 Hz bins as in a 20 s
    record, accelerance tilt): the mean error within 30 % of the observed spread for the
    frequency and log damping of both modes, and the 95 % intervals covering >= 80 % of 30 draws.
    The segment jackknife used before covered 75-80 % for this pair on the benchmark records."""
    from oma.output_only import ml, whittle

    rng = np.random.default_rng(7)
    l = 3
    f_true, z_true = np.array([10.0, 10.5]), np.array([0.05, 0.05])
    u_true = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    w = 2 * np.pi * np.arange(7.0, 13.6, 0.05)
    gain = w ** 4 / np.mean(w ** 4)
    v = u_true.T[None, :, :] / whittle._response(f_true, z_true, z_true, w)[:, None, :]
    s = gain[:, None, None] * (v @ np.diag([1.0, 1.3]) @ np.conj(np.swapaxes(v, 1, 2))) + 0.02 * np.eye(l)[None]
    chol = np.linalg.cholesky(s)
    est, se = [], []
    for _ in range(30):
        e = (rng.standard_normal((w.size, l)) + 1j * rng.standard_normal((w.size, l))) / np.sqrt(2)
        x = (chol @ e[:, :, None])[..., 0]
        u0 = u_true + 0.1 * rng.standard_normal(u_true.shape)
        f, z, u, _, px, mod = ml._fit_group(w, x, f_true * (1 + 0.005 * rng.standard_normal(2)),
                                            z_true * np.exp(0.1 * rng.standard_normal(2)),
                                            (u0 / np.linalg.norm(u0, axis=1, keepdims=True)).T, 2, residuals=False)
        est.append(np.r_[f, np.log(z)])
        se.append(ml._information_se(px, mod, x, u, np.ones(l))[:2].ravel())
    err, se = np.array(est) - np.r_[f_true, np.log(z_true)], np.array(se)
    ratio = np.mean(se, axis=0) / np.sqrt(np.mean(err ** 2, axis=0))
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio
    assert np.all(np.mean(np.abs(err) < 1.96 * se, axis=0) >= 0.8)


def test_view_choice_keeps_per_band_the_view_resolving_more_modes():
    from oma.output_only.modes import _choose_views

    # view 0 sees one mode of a close pair and the 70 Hz mode; view 1 both of the pair, the 70 Hz
    # mode with less support and a lone 40 Hz mode
    f = np.array([10.0, 10.1, 10.5, 40.0, 70.0, 70.2])
    z = np.array([0.05, 0.05, 0.05, 0.03, 0.03, 0.03])
    support = np.array([0.9, 0.6, 0.5, 0.4, 0.8, 0.5])
    view = np.array([0, 1, 1, 1, 0, 1])
    keep = _choose_views(f, z, support, view, np.ones(6, dtype=bool))
    assert keep.tolist() == [False, True, True, True, True, False]


def test_extra_mode_case_finds_all_four_modes_and_drops_unsupported_candidates():
    """A 70 Hz mode along (1, 1, 0) 23 dB over the 10.5 Hz X mode in the X acceleration (the
    benchmark's `extra` case): the displacement view of SSI finds the X mode, and a fictitious
    candidate handed to the refinement is dropped by the likelihood check; its group refined
    alone (``fit_only``, the flat input's retry of a group) gives the same fit."""
    from oma.output_only.ml import refine_modes_ml

    model = EXTRA_TRUTH
    # the benchmark's second record (its first, rng 10_000, is its worst: X at -2.04 %, reported)
    rec = synthetic_record(model, duration_s=20.0, rng=10_001, spindle_rpm=1350.0, output="acceleration",
                           runout_m=None)
    y = rec.vector("acceleration")
    m = output_only_modes([y], 1000.0, [1350.0], [2])
    assert m.n_modes == 4
    for k in range(4):
        d = np.abs(m.freq_hz / model.natural_frequency_hz[k] - 1) + (1 - np.abs(m.directions @ model.directions[k]))
        j = int(np.argmin(d))
        assert abs(m.freq_hz[j] / model.natural_frequency_hz[k] - 1) < FREQ_TOL
        assert abs(m.directions[j] @ model.directions[k]) > 0.9
    # the modes found plus a fictitious one at 82 Hz along the 70 Hz mode (like the displacement
    # view's noise clusters of the benchmark): only that one is dropped
    r = m.harmonics[0].residual
    ch = r.std(axis=1)
    u = np.hstack([m.directions.T / ch[:, None], np.array([[1.0, 1.0, 0.0]]).T / ch[:, None]])
    ev = {}
    args = ([r / ch[:, None]], 1000.0, np.append(m.freq_hz, 82.0), np.append(m.damping_ratio, 0.024),
            u / np.linalg.norm(u, axis=0))
    full = refine_modes_ml(*args, lines_hz=m.harmonics[0].freq_hz, evidence=ev)
    assert ev["dropped"].tolist() == [False] * 4 + [True]
    k70 = int(np.argmin(np.abs(m.freq_hz - 70.0)))
    assert abs(full.freq_hz[k70] / 70.0 - 1) < FREQ_TOL
    # the 70 Hz mode's group (it and the candidate beside it) refined alone: the same fit to the
    # last bit (a group's fit sees the others through their starting values only), the other
    # groups left at their starting values, unfitted
    assert full.group.size == 5 and full.group[4] == full.group[k70]
    alone = full.group == full.group[k70]
    part = refine_modes_ml(*args, lines_hz=m.harmonics[0].freq_hz, evidence={}, fit_only=alone)
    assert np.array_equal(part.fitted, full.fitted & alone) and part.fitted[k70]
    assert np.array_equal(part.freq_hz[alone], full.freq_hz[alone])
    assert np.array_equal(part.damping[alone], full.damping[alone])
    assert np.array_equal(part.freq_hz[~alone], args[2][~alone])



def test_weak_poles_a_group_fit_takes_out_of_their_bands_are_dropped_and_the_group_refined():
    """The extra case's record 98 (rng 10_098): SSI forms weak clusters at 64.1 and 84.4 Hz (support
    0.30 and 0.33) in the 70 Hz mode's group, and the group's fit turns them into humps out of their
    bands (56.5 Hz, and 36 % damping). Before session 23 the group went unrefined and both were
    reported as modes; now they are dropped by the likelihood and the 70 Hz mode is refined: exactly
    the four true modes."""
    model = EXTRA_TRUTH
    rec = synthetic_record(model, duration_s=20.0, rng=10_098, spindle_rpm=1350.0, output="acceleration",
                           runout_m=None)
    m = output_only_modes([rec.vector("acceleration")], 1000.0, [1350.0], [2])
    assert m.n_modes == 4
    for k in range(4):
        d = np.abs(m.freq_hz / model.natural_frequency_hz[k] - 1) + (1 - np.abs(m.directions @ model.directions[k]))
        j = int(np.argmin(d))
        assert abs(m.freq_hz[j] / model.natural_frequency_hz[k] - 1) < FREQ_TOL
    k70 = int(np.argmin(np.abs(m.freq_hz - 70.0)))
    # refined (an input level from the likelihood; NaN where left at SSI's values), its interval
    # covering the true damping
    assert np.isfinite(m.input_level[k70])
    assert abs(m.damping_ratio[k70] - 0.03) < 2.0 * m.damping_se[k70]


def test_a_dropped_candidate_is_no_tail_of_the_group_refitted_without_it():
    """The extra case's record 73 (rng 10_073): SSI gives two candidates for the 70 Hz peak, 66.7 Hz
    (support 0.30) and 70.2 Hz. Each looks redundant while the other is there, and the likelihood
    check drops the second. Before session 23 the group refitted without it took it back as a known
    tail of the other modes (fixed at SSI's 70.2 Hz) and fitted the first as a hump beside it:
    68.2 Hz at 4.5 % damping, a 2.6 % frequency error, and X and Y stiffness 26 % off through the
    lines. A dropped mode is no tail: the peak's mode is refitted at 70.0 Hz / 3.0 %."""
    model = EXTRA_TRUTH
    rec = synthetic_record(model, duration_s=20.0, rng=10_073, spindle_rpm=1350.0, output="acceleration",
                           runout_m=None)
    m = output_only_modes([rec.vector("acceleration")], 1000.0, [1350.0], [2])
    assert m.n_modes == 4
    k70 = int(np.argmin(np.abs(m.freq_hz - 70.0)))
    assert abs(m.freq_hz[k70] / 70.0 - 1) < 0.01
    assert np.isfinite(m.input_level[k70])
    assert m.damping_interval[k70, 0] <= 0.03 <= m.damping_interval[k70, 1]


def test_every_unsupported_candidate_of_a_group_goes_not_only_the_weakest():
    """Three lightly damped modes far apart (50 / 120 / 200 Hz at 1.0 / 0.8 / 1.0 %, one per
    axis; frequency-domain records, 2 % sensor noise; the independent audit's structure). Record 2:
    SSI proposes candidates at 111.8, 115.6 and 131.1 Hz in the 120 Hz mode's group; before session
    25 the evidence gate dropped one per group (131.1 Hz, gaining 3.6) and kept the other two, which
    gained 6.5 and 7.0 against a penalty of 16.8. Each candidate is now judged again once another
    has gone: exactly the three true modes, and every mode the refinement kept is supported (its
    gain over its penalty) or alone in its group."""
    import sys
    from pathlib import Path

    from oma.output_only.ml import refine_modes_ml
    import oma.output_only.modes as modes_module

    sys.path.insert(0, str(Path(__file__).parent))
    from frequency_domain_records import modal_superposition

    truth = [(50.0, 0.01, [1, 0, 0]), (120.0, 0.008, [0, 1, 0]), (200.0, 0.01, [0, 0, 1])]
    y = modal_superposition(truth, 1000.0, 20.0, 2)
    seen = []

    def spy(*args, **kwargs):
        out = refine_modes_ml(*args, **kwargs)
        seen.append((out, kwargs.get("evidence")))
        return out

    from oma.record import Channel, Record
    from oma.synthetic import paper_like_cut, paper_like_tool

    rec = Record(1000.0, tuple(Channel(a.lower(), "acceleration", a, "m/s2") for a in "XYZ"), y,
                 paper_like_tool(), paper_like_cut())
    mp = pytest.MonkeyPatch()
    mp.setattr(modes_module, "refine_modes_ml", spy)
    try:
        m = identify_output_only([rec], band_hz=(20.0, 400.0)).modes
    finally:
        mp.undo()
    assert m.n_modes == 3
    assert np.all(np.abs(m.freq_hz / np.array([50.0, 120.0, 200.0]) - 1) < 0.005)
    out, ev = seen[0]
    assert ev["dropped"].sum() >= 3   # the 111.8, 115.6 and 131.1 Hz candidates at least
    for k in np.flatnonzero(out.fitted & ~ev["dropped"]):
        alone = np.sum((out.group == out.group[k]) & ~ev["dropped"]) == 1
        assert alone or (k in ev and ev[k][0] > ev[k][1]), (out.freq_hz[k], ev.get(k))


def test_a_modes_gain_near_its_penalty_is_read_from_the_refit_at_its_optimum(monkeypatch):
    """Three close modes (350 / 357 / 365 Hz at 0.8-2 %) under a sharp 530 Hz mode (0.2 %), 15 s
    of velocity at 2 kHz (frequency-domain records; the independent audit's Hurco kind, whose
    velocity records kept a broad hump at 372-384 Hz beside the 365 Hz mode). From the true modes
    and a candidate at 372 Hz / 3 %, the refit without the candidate stopped by the scoring's
    steps leaves it a gain of 104 against a penalty of 19 (it ends at 385.6 Hz); carried on to its
    optimum the group is better without it (-89), and it is dropped. With the finish turned off
    the candidate stays: the gain was the scoring's shortfall, not the spectrum's."""
    import sys
    from pathlib import Path

    import oma.output_only._ml_inference as inference
    from oma.output_only.ml import refine_modes_ml

    sys.path.insert(0, str(Path(__file__).parent))
    from frequency_domain_records import modal_superposition

    truth = [(350.0, 0.008, [1, 0.3, 0.1]), (357.0, 0.010, [0.2, 1, 0.3]), (365.0, 0.02, [0.3, 0.2, 1]),
             (530.0, 0.002, [1, 1, 0.2])]
    fs = 2000.0
    y = modal_superposition(truth, fs, 15.0, 1, derivative=1)
    y = y - y.mean(axis=1, keepdims=True)
    ch = y.std(axis=1)
    f0 = np.array([m[0] for m in truth] + [372.0])
    z0 = np.array([m[1] for m in truth] + [0.03])
    u0 = np.column_stack([np.asarray(m[2], float) / np.linalg.norm(m[2]) for m in truth] + [np.array([0.3, 0.3, 0.9])])
    u0 = u0 / ch[:, None]
    u0 = u0 / np.linalg.norm(u0, axis=0)

    def refine():
        ev = {}
        refine_modes_ml([y / ch[:, None]], fs, f0, z0, u0, derivative=1, evidence=ev, add_missing=None)
        return ev

    ev = refine()
    assert ev["dropped"].tolist() == [False] * 4 + [True]
    assert ev[4][0] < ev[4][1]
    monkeypatch.setattr(inference, "EVIDENCE_FINISH", False)
    ev = refine()
    assert not ev["dropped"][4] and ev[4][0] > ev[4][1]


def test_a_retried_groups_results_replace_only_that_groups():
    """:func:`oma.output_only.modes._merged`: three starting modes in groups 0 (modes 0, 1) and 2
    (mode 2), the first refinement's scan adding a mode to each group; group 0 retried, its scan
    adding another. The merge keeps the starting modes in their order (0 and 1 from the retry,
    2 from the first), then the first's added mode of group 2, then the retry's; the mode added to
    group 0 by the first refinement is gone, and the evidence follows each mode."""
    from oma.output_only.modes import _merged, _Refined

    def refinement(f, group, tag):
        n = len(f)
        f = np.asarray(f, dtype=float)
        shapes = np.vstack([f, -f]).astype(complex)
        ses = tuple(f * s for s in (0.01, 0.02, 0.03))
        return _Refined(f, f / 100, shapes, np.ones(n, dtype=bool), ses, (f * 10, f * 20), np.asarray(group)), \
            {**{k: (tag, k) for k in range(n)}, "dropped": np.arange(n) == 1, "duplicate": np.zeros(n, dtype=bool),
             "left_band": np.arange(n) == (1 if tag == "retry" else 2), "added": np.arange(n) >= 3}

    first, ev = refinement([10.0, 11.0, 30.0, 31.0, 12.0], [0, 0, 2, 2, 0], "first")
    retry, ev_retry = refinement([10.5, 11.5, 30.0, 13.0], [0, 0, 2, 0], "retry")
    out, new_ev = _merged(first, ev, retry, ev_retry, np.array([True, True, False]))
    assert out.freq_hz.tolist() == [10.5, 11.5, 30.0, 31.0, 13.0]
    assert out.group.tolist() == [0, 0, 2, 2, 0]
    assert np.array_equal(out.shapes[0].real, out.freq_hz) and np.array_equal(out.levels[1], out.freq_hz * 20)
    assert np.array_equal(out.se[2], np.array([10.5, 11.5, 30.0, 31.0, 13.0]) * 0.03)
    assert [new_ev[j] for j in range(5)] == [("retry", 0), ("retry", 1), ("first", 2), ("first", 3), ("retry", 3)]
    assert new_ev["dropped"].tolist() == [False, True, False, False, False]
    assert new_ev["left_band"].tolist() == [False, True, True, False, False]
    assert new_ev["added"].tolist() == [False, False, False, True, True]

@pytest.mark.parametrize("seed", [1, 3])
def test_modes_off_the_machine_axes_are_found_and_scaled(seed):
    """Not the paper's cell: the two in-plane modes at 30 degrees to the axes (12 Hz / 4 %, 26 Hz /
    3 %) and a Z mode apart from them (17 Hz / 5 %). Every mode is found (seed 1 lost the 17 Hz mode
    before session 11: the refit without it reached a spectrum so nearly singular that ``inv``
    gave a quadratic form of -1.9e12, a "gain" that dropped it), directions within 3 degrees, the
    in-plane stiffnesses within 10 % and every stiffness inside its stated 95 % interval."""
    c, s = np.cos(np.deg2rad(30.0)), np.sin(np.deg2rad(30.0))
    dirs = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    truth = ModalModel(natural_frequency_hz=[12.0, 26.0, 17.0], damping_ratio=[0.04, 0.03, 0.05],
                       stiffness_N_m=[1.2e6, 2.5e6, 2.0e6], directions=dirs)
    rec = synthetic_record(truth, duration_s=20.0, rng=seed, spindle_rpm=2700.0, output="acceleration", runout_m=None)
    res = identify_output_only([rec])
    m, st = res.model, res.stiffness
    assert m.n_modes == 3 and not any("not kept" in w for w in res.warnings)
    for k in range(3):
        j = int(np.argmin(np.abs(m.natural_frequency_hz / truth.natural_frequency_hz[k] - 1)))
        assert abs(m.natural_frequency_hz[j] / truth.natural_frequency_hz[k] - 1) < FREQ_TOL
        assert np.degrees(np.arccos(min(1.0, abs(m.directions[j] @ dirs[k])))) < 3.0
        lo, hi = st.interval_N_m[j]
        assert lo <= truth.stiffness_N_m[k] <= hi
        if k < 2:
            assert abs(m.stiffness_N_m[j] / truth.stiffness_N_m[k] - 1) < 0.10


def test_a_pole_at_the_band_edge_is_not_reported_as_a_mode(monkeypatch):
    """The structure above, the benchmark's record 5 of its ``oblique`` case: SSI and the
    likelihood check kept a pole at 4.3 Hz with 22 % damping (the background's slope at the
    analysed band's lower edge, 4 Hz) as a fourth mode. Its half-power band crosses the edge, so
    since session 12 it is a warning, not a mode, and the modes are exactly the true three. Since
    session 23 the refinement drops it first: its group's fit takes it out of its band (and then
    refines the 12 and 17 Hz modes, which it had left at SSI's values); the edge's rule is checked
    with that drop switched off."""
    import oma.output_only.ml as ml

    c, s = np.cos(np.deg2rad(30.0)), np.sin(np.deg2rad(30.0))
    truth = ModalModel(natural_frequency_hz=[12.0, 26.0, 17.0], damping_ratio=[0.04, 0.03, 0.05],
                       stiffness_N_m=[1.2e6, 2.5e6, 2.0e6], directions=[[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    rec = synthetic_record(truth, duration_s=20.0, rng=10_005, spindle_rpm=2700.0, output="acceleration",
                           runout_m=None)
    res = identify_output_only([rec])
    f = np.sort(res.model.natural_frequency_hz)
    np.testing.assert_allclose(f, np.sort(truth.natural_frequency_hz), rtol=FREQ_TOL)
    left = [w for w in res.warnings if "took it out of its band" in w]
    assert len(left) == 1 and float(left[0].split()[4]) < 5.0  # 'stable SSI cluster at 4.30 Hz not kept: ...'
    assert np.all(np.isfinite(res.modes.input_level))   # every mode refined (NaN where left at SSI's values)

    monkeypatch.setattr(ml, "_left_band", lambda fit, g, f0, hw: np.ones(len(g), dtype=bool))
    res = identify_output_only([rec])
    np.testing.assert_allclose(np.sort(res.model.natural_frequency_hz), np.sort(truth.natural_frequency_hz),
                               rtol=FREQ_TOL)
    edge = [w for w in res.warnings if "not reported as a mode" in w]
    assert len(edge) == 1 and "crosses the edge of the analysed band 4-100 Hz" in edge[0]
    assert float(edge[0].split()[2]) < 5.0  # 'pole at 4.30 Hz ...'


def test_a_mode_missing_from_the_record_leaves_lines_the_model_cannot_explain_and_no_trust():
    """The structure above measured as displacement (tracker rounding 15 um): in this record the
    17 Hz Z mode is under the rounding and SSI does not find it. Without the seeding of residual
    peaks (session 16) the tooth lines carry the missing mode's response (reduced chi-square 8):
    warned and, since session 11, not trusted (before: trusted with a mode missing). With it (the
    default) the Z channel's peak is tried as a mode and the refinement finds it: frequency,
    damping and stiffness intervals hold the truth and the lines agree with the model again (the
    model stays untrusted: Z is scaled by the background's level)."""
    from oma.output_only.identify import MAX_LINE_MISFIT

    c, s = np.cos(np.deg2rad(30.0)), np.sin(np.deg2rad(30.0))
    truth = ModalModel(natural_frequency_hz=[12.0, 26.0, 17.0], damping_ratio=[0.04, 0.03, 0.05],
                       stiffness_N_m=[1.2e6, 2.5e6, 2.0e6], directions=[[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    rec = synthetic_record(truth, duration_s=20.0, rng=1, spindle_rpm=2700.0, output="displacement", runout_m=None)
    res = identify_output_only([rec], seed_peaks=False)
    assert res.model.n_modes == 2 and np.all(np.abs(res.model.natural_frequency_hz - 17.0) > 2.0)
    assert any("disagree with the force model" in w for w in res.warnings)
    assert not res.trusted and res.stiffness.misfit > 4.0
    seeded = identify_output_only([rec])
    assert seeded.model.n_modes == 3 and any("tried as a mode" in w for w in seeded.warnings)
    j = int(np.argmin(np.abs(seeded.model.natural_frequency_hz - 17.0)))
    assert abs(seeded.model.natural_frequency_hz[j] / 17.0 - 1) < FREQ_TOL
    m = seeded.modes
    assert m.freq_interval_hz[j, 0] <= 17.0 <= m.freq_interval_hz[j, 1]
    assert m.damping_interval[j, 0] <= 0.05 <= m.damping_interval[j, 1]
    lo, hi = seeded.stiffness.interval_N_m[j]
    assert lo <= 2.0e6 <= hi and seeded.scaled_by[j] == "background"
    assert seeded.stiffness.misfit < MAX_LINE_MISFIT and not seeded.trusted


def _scan(rng, missing: bool):
    """The residual scan on periodograms drawn from a known spectrum: a 10 Hz mode along Z (the
    group's fitted model, exactly the truth) and, with ``missing``, a 14 Hz mode along (0.8, 0.6,
    0) that the model lacks; constant background, 0.05 Hz bins as in a 20 s record."""
    from oma.output_only import ml, whittle

    l = 3
    w = 2 * np.pi * np.arange(6.0, 18.0, 0.05)
    gain = w ** 4 / np.mean(w ** 4)
    f, z = np.array([10.0, 14.0]), np.array([0.04, 0.04])
    u = np.array([[0.0, 0.0, 1.0], [0.8, 0.6, 0.0]])
    noise = 0.02 * np.eye(l)
    v = u.T[None, :, :] / whittle._response(f, z, z, w)[:, None, :]
    s = gain[:, None, None] * (v @ np.diag([1.0, 0.5 if missing else 0.0]) @ np.conj(np.swapaxes(v, 1, 2))) + noise
    e = (rng.standard_normal((w.size, l)) + 1j * rng.standard_normal((w.size, l))) / np.sqrt(2)
    x = (np.linalg.cholesky(s) @ e[:, :, None])[..., 0]
    mod = whittle._Model(1, l, w, gain, np.zeros((w.size, l, 0), complex), True, (f[:1], z[:1]))
    p = np.concatenate([[0.0], np.log(z[:1]), u[0], [1.0], np.linalg.cholesky(noise)[np.tril_indices(l)]])
    r, n_eff, fc, zc, uc = ml._missing_mode(w, x, p, mod, (6.0, 18.0))
    return (r - 1.0) * np.sqrt(n_eff), fc, uc


def test_the_residual_scan_is_quiet_under_its_model_and_finds_a_missing_mode():
    """The score test behind the refinement's scan for modes SSI missed: when the group's model is
    the truth, its largest excess over 240 bins stays under the threshold that proposes a mode
    (:data:`oma.output_only.ml.ADD_SIGMAS`, in units of its own noise, 1/sqrt(n_eff)) in 30 of 30
    draws; when a mode is missing from the model, the excess is many times the threshold, at that
    mode (within its half-power band) and along its direction."""
    from oma.output_only.ml import ADD_SIGMAS

    rng = np.random.default_rng(11)
    null = [_scan(rng, False)[0] for _ in range(30)]
    assert max(null) < ADD_SIGMAS and np.median(null) < 4.0
    for _ in range(3):
        sigma, fc, uc = _scan(rng, True)
        assert sigma > 5 * ADD_SIGMAS
        assert abs(fc - 14.0) < 2 * 0.04 * 14.0
        assert abs(uc @ np.array([0.8, 0.6, 0.0])) > 0.99


def test_a_mode_ssi_misses_is_found_by_the_refinements_scan():
    """A benchmark record of the extra case where no SSI cluster forms for the 10.5 Hz X mode
    beside Z (record 8, session 12; record 16 is another, its Z direction 31 degrees off). The
    scan of what the refined groups leave unexplained proposes it, the group refitted with it (on
    a band widened to hold it) gains far more than the mode's BIC penalty: exactly the true modes,
    each within 2 % in frequency and 0.9 in direction, and the warning says which mode came from
    the scan."""
    truth = EXTRA_TRUTH
    rec = synthetic_record(truth, duration_s=20.0, rng=10_008, spindle_rpm=1350.0, output="acceleration", runout_m=None)
    m = identify_output_only([rec]).modes
    assert m.n_modes == truth.n_modes and np.all(np.diff(m.freq_hz) > 0)
    for k in range(truth.n_modes):
        cost = np.abs(m.freq_hz / truth.natural_frequency_hz[k] - 1) + (1 - np.abs(m.directions @ truth.directions[k]))
        j = int(np.argmin(cost))
        assert abs(m.freq_hz[j] / truth.natural_frequency_hz[k] - 1) < FREQ_TOL
        assert abs(m.directions[j] @ truth.directions[k]) > 0.9
    scanned = [w for w in m.warnings if "not by SSI" in w]
    assert len(scanned) == 1
    assert abs(float(scanned[0].split()[2]) / 10.5 - 1) < FREQ_TOL   # 'mode at 10.38 Hz found ...'


def test_a_mode_neither_ssi_nor_the_scan_finds_leaves_the_model_untrusted_and_named(monkeypatch):
    """The damped structure's record 8 (9 / 21 / 33 Hz at 8 / 6 / 5 %, 45 degrees in XY): no SSI
    cluster forms for the 21 Hz mode, between the groups of the 9 and 33 Hz modes. Until session 24
    the scan's candidate did not gain its penalty there either; with the other modes' tails always
    in the groups' model (``ml.KNOWN_TAILS_ALWAYS``) it does and the mode is found, so the scan is
    turned off here to keep the case this test is about: a mode neither finds. The model must not
    be trusted, and a warning must name the peak at 21 Hz."""
    import functools

    import oma.output_only.modes as modes_module
    from oma.output_only.ml import refine_modes_ml

    s45 = np.sqrt(0.5)
    truth = ModalModel([9.0, 21.0, 33.0], [0.08, 0.06, 0.05], [1.0e6, 2.0e6, 4.0e6],
                       [[s45, s45, 0], [-s45, s45, 0], [0, 0, 1]])
    rec = synthetic_record(truth, duration_s=20.0, rng=10_008, spindle_rpm=2700.0, output="acceleration", runout_m=None)
    found = identify_output_only([rec])
    assert np.any(np.abs(found.modes.freq_hz / 21.0 - 1) < FREQ_TOL)   # the scan finds it (session 24)
    monkeypatch.setattr(modes_module, "refine_modes_ml", functools.partial(refine_modes_ml, add_missing=None))
    res = identify_output_only([rec])
    assert not np.any(np.abs(res.modes.freq_hz / 21.0 - 1) < FREQ_TOL)   # the case this test is about
    assert not res.trusted
    assert any(p.freq_hz == pytest.approx(21.0, rel=FREQ_TOL) for p in res.unexplained_peaks)


def test_the_scans_candidates_solved_at_once_match_one_at_a_time():
    """The scan for a missing mode (:func:`oma.output_only._ml_inference._missing_mode`) solves
    every candidate's generalised eigenproblem ``A u = r B u`` at once; on random positive
    definite pairs (the candidates' weights summing to 1) it picks the same candidate as SciPy's
    ``eigh(A, B)`` one at a time, with its eigenvalue to 1e-12 and its direction to 1e-10 (up to
    sign); with one ``B`` indefinite it falls back to that loop, skipping it."""
    from oma.output_only._ml_inference import _strongest_candidate, _strongest_candidate_each

    rng = np.random.default_rng(7)
    n, l, k = 40, 3, 50
    g = rng.standard_normal((n, l, 2 * l))
    amat = g @ np.swapaxes(g, 1, 2) / (2 * l)
    h = rng.standard_normal((n, l, 2 * l))
    bmat = h @ np.swapaxes(h, 1, 2) / (2 * l) + 0.1 * np.eye(l)
    a = rng.random((k, n))
    a /= a.sum(axis=0)
    fcs = np.linspace(10.0, 20.0, n)
    at_once = _strongest_candidate(fcs, a, amat, bmat, 0.03)
    each = _strongest_candidate_each(fcs, a, amat, bmat, 0.03)
    assert at_once[2] == each[2] and at_once[1] == pytest.approx(each[1], rel=1e-14)
    assert at_once[0] == pytest.approx(each[0], rel=1e-12)
    assert abs(abs(at_once[4] @ each[4]) - 1.0) < 1e-10
    j = int(np.flatnonzero(fcs == at_once[2])[0])
    bmat[j] = -bmat[j]
    skipped = _strongest_candidate(fcs, a, amat, bmat, 0.03)
    again = _strongest_candidate_each(fcs, a, amat, bmat, 0.03)
    assert skipped[2] != at_once[2] and skipped[:4] == again[:4] and np.array_equal(skipped[4], again[4])
