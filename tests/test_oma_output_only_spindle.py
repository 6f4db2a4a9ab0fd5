"""Output-only identification when the spindle speed or the cut is not steady (audit of session 15).

Own generator, independent of :func:`oma.synthetic.synthetic_record`: three modes of an "oblique"
structure (12 Hz / 4 % / 1.2e6 N/m and 26 Hz / 3 % / 2.5e6 N/m at 30 deg in XY, 17 Hz / 5 % /
2.0e6 N/m along Z), displacement by an FFT-domain modal filter of the static-chip milling force
(:func:`oma.synthetic.milling_force`) evaluated at a time-warped spindle angle (the true speed
varies; the record states the nominal one), plus a white background force of the paper's level.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from oma.modal import ModalModel
from oma.output_only.harmonics import remove_response_harmonics
from oma.output_only.identify import identify_output_only
from oma.record import Channel, Record
from oma.synthetic import milling_force, paper_like_cut, paper_like_material, paper_like_tool

C30, S30 = np.cos(np.pi / 6), np.sin(np.pi / 6)
OBLIQUE = ModalModel([12.0, 26.0, 17.0], [0.04, 0.03, 0.05], [1.2e6, 2.5e6, 2.0e6],
                     [[C30, S30, 0], [-S30, C30, 0], [0, 0, 1]])
#: A well-scaled mode's stiffness on these records is within 5-15 % of the truth at constant speed
#: (benchmark ``oblique``: max 5.9 / 0.9 / 15.8 %); before the fixes a 0.5 % ramp gave +100 %.
K_TOL = 0.30


def _record(seed, *, rpm=2700.0, nominal_rpm=None, speed=None, envelope=None, tone=None, fs=1000.0, duration_s=20.0,
            oversample=2, preroll_s=5.0, with_force=False):
    """Displacement record of :data:`OBLIQUE`; ``speed(t)``: true rpm over nominal; ``envelope(t)``:
    multiplier of the cutting force; ``tone``: (Hz, N, direction) a chatter-like limit cycle;
    ``with_force``: the force (cutting and background) recorded too, as a dynamometer would."""
    rng = np.random.default_rng(seed)
    fsim = fs * oversample
    n_pre, n = int(preroll_s * fsim), int(duration_s * fsim)
    t = (np.arange(n_pre + n) - n_pre) / fsim
    ratio = np.ones_like(t) if speed is None else speed(np.clip(t, 0.0, None))
    tau = np.cumsum(ratio) / fsim  # spindle angle / (2 pi rpm / 60): the warped time
    tool, material = paper_like_tool(), paper_like_material()
    force = milling_force(tool, paper_like_cut(rpm), material.cutting_coefficients, tau)
    if envelope is not None:
        force = force * envelope(t)[None, :]
    force = force + np.sqrt(np.array([232.0, 278.0, 251.0]) / 1000.0 * fsim)[:, None] * rng.standard_normal(force.shape)
    if tone is not None:
        f_t, amp, direction = tone
        force = force + amp * np.outer(np.asarray(direction) / np.linalg.norm(direction), np.cos(2 * np.pi * f_t * t))
    spec = np.fft.rfft(force, axis=-1)
    w = 2 * np.pi * np.fft.rfftfreq(t.size, 1 / fsim)
    x = np.zeros_like(spec)
    for f, z, k, u in zip(OBLIQUE.natural_frequency_hz, OBLIQUE.damping_ratio, OBLIQUE.stiffness_N_m,
                          OBLIQUE.directions):
        wr = 2 * np.pi * f
        x += np.outer(u, wr ** 2 / (wr ** 2 - w ** 2 + 2j * z * wr * w) / k) * (u @ spec)[None, :]
    y = np.fft.irfft(x, n=t.size, axis=-1)[:, n_pre::oversample]  # 1 kHz, modes far below Nyquist
    cut = paper_like_cut(rpm if nominal_rpm is None else nominal_rpm)
    channels = [Channel(a.lower(), "displacement", a, "m") for a in "XYZ"]
    if with_force:
        channels += [Channel(f"f{a.lower()}", "force", a, "N") for a in "XYZ"]
        y = np.vstack([y, force[:, n_pre::oversample]])
    return Record(sample_rate_hz=fs, channels=channels, data=y, tool=tool, cut=cut, material=material,
                  name=f"spindle-{seed}")


def _stiffness_errors(result):
    """Relative stiffness error and whether the interval holds the truth, per true mode."""
    out = []
    for f, k in zip(OBLIQUE.natural_frequency_hz, OBLIQUE.stiffness_N_m):
        j = int(np.argmin(np.abs(result.model.natural_frequency_hz / f - 1)))
        assert abs(result.model.natural_frequency_hz[j] / f - 1) < 0.03
        lo, hi = result.stiffness.interval_N_m[j]
        out.append((result.model.stiffness_N_m[j] / k - 1, lo <= k <= hi))
    return out


def test_constant_speed_is_not_tracked_and_is_steady():
    rec = _record(0)
    h = remove_response_harmonics(rec.vector("displacement"), rec.sample_rate_hz, 2700.0, 2)
    assert not h.tracked and h.steady


@pytest.mark.parametrize("speed", [lambda t: 1.0025 - 0.005 * t / 20.0,  # 0.5 % ramp over the record
                                   lambda t: 1.0 + 0.003 * np.sin(2 * np.pi * t / 20.0)],  # +-0.3 % wander
                         ids=["ramp", "wander"])
def test_slowly_varying_speed_is_tracked_and_scales_right(speed):
    result = identify_output_only([_record(1, speed=speed)])
    assert result.modes.harmonics[0].tracked
    for err, covered in _stiffness_errors(result):
        assert abs(err) < K_TOL and covered, (err, covered)
    assert any("tracked spindle angle" in w for w in result.warnings)


def test_a_measured_force_is_fitted_as_orders_of_the_tracked_angle():
    """Scaled by a force channel, the force's lines are fitted in the basis the response's were
    (orders of the tracked angle): a fixed-frequency fit of a line that moves by 0.45 Hz captured
    a fraction of the force only (stiffness 2-4x too soft)."""
    result = identify_output_only([_record(1, speed=lambda t: 1.0025 - 0.005 * t / 20.0, with_force=True)],
                                  scaling="measured_force")
    assert result.modes.harmonics[0].tracked
    for err, covered in _stiffness_errors(result):
        assert abs(err) < K_TOL and covered, (err, covered)


def test_the_lines_of_another_signal_are_those_of_the_dense_basis():
    # ResponseHarmonics.line_amplitudes (power sums of the tracked angle) against the dense design
    # of harmonic_basis with each line's phase, solved by lstsq_normal: the same amplitudes
    from oma._linalg import lstsq_normal
    from oma.harmonics import harmonic_basis

    rec = _record(1, speed=lambda t: 1.0025 - 0.005 * t / 20.0, with_force=True)
    h = identify_output_only([rec], scaling="measured_force").modes.harmonics[0]
    assert h.tracked and h.angle_deviation_rad is not None and h.orders.size == h.freq_hz.size
    force = np.array(rec.force[:, : h.angle_deviation_rad.size])
    t = np.arange(force.shape[1]) / rec.sample_rate_hz
    dense = lstsq_normal(harmonic_basis(t, h.freq_hz, trend=True,
                                        phase_rad=np.outer(h.signs * h.orders, h.angle_deviation_rad)), force.T)
    expect = (dense[2::2] - 1j * dense[3::2]).T
    got = h.line_amplitudes(force, rec.sample_rate_hz)
    assert np.max(np.abs(got - expect)) < 1e-9 * np.max(np.abs(expect))


def test_cut_over_part_of_the_record_is_windowed():
    env = lambda t: np.clip((t - 3.0) / 0.5, 0, 1) * np.clip((17.0 - t) / 0.5, 0, 1)  # noqa: E731
    result = identify_output_only([_record(2, envelope=env)])
    msg = [w for w in result.warnings if "tooth-passing line is present only" in w]
    assert msg
    start, stop = (float(v) for v in re.search(r"from ([0-9.]+) to ([0-9.]+) s", msg[0]).groups())
    assert 3.0 <= start <= 4.5 and 15.5 <= stop <= 17.0  # the cut: 3-17 s with 0.5 s ramps
    for err, covered in _stiffness_errors(result):
        assert abs(err) < K_TOL and covered, (err, covered)


def test_unsteady_line_is_flagged_and_not_trusted():
    # the force grows 60 % over the record (tool wear): no window, no tracking repairs it
    result = identify_output_only([_record(3, envelope=lambda t: 0.7 + 0.6 * np.clip(t / 20.0, 0, 1) ** 3)])
    # the line's amplitude grows 1.9x: the steadiness check sees it (stiffness 12-35 % high, seeds 3-5)
    assert not result.modes.harmonics[0].steady
    assert not result.trusted
    assert any("not steady" in w for w in result.warnings)


def test_chatter_tone_makes_the_model_untrusted():
    result = identify_output_only([_record(1, tone=(26.8, 40.0, [-S30, C30, 0]))])
    assert np.any(result.modes.damping_ratio < 0.005)
    assert not result.trusted
    assert any("chatter" in w for w in result.warnings)


def test_wrong_nominal_speed_message_names_the_line():
    result = identify_output_only([_record(0, nominal_rpm=2700.0 * 1.06)])
    assert result.stiffness is None
    msg = next(w for w in result.warnings if w.startswith("modes not scaled"))
    assert "spindle_rpm" in msg
    assert abs(float(re.search(r"lies at ([0-9.]+) Hz", msg).group(1)) - 90.0) <= 0.25  # the true tooth line
