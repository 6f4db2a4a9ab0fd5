"""Synthetic cutting records with known dynamics, for tests, benchmarks and detectability.

Two layers:

* :func:`simulate_response` -- the exact discrete-time response of a :class:`~oma.modal.ModalModel`
  to a sampled force history, the force being taken piecewise linear between samples (first-order
  hold). Each mode is discretised exactly; no time-stepping error.
* :func:`band_limited_response` -- the response to the band-limited force whose samples are given
  (what an anti-aliased acquisition of a continuous force records), in the frequency domain: the
  continuous frequency response at every frequency below Nyquist. The first-order hold's is
  ``sinc^2(f / fs)`` times it (-0.7 % at 0.045 fs, -2.6 % at 0.09 fs, -5.9 % at 0.135 fs), which
  a method that scales modes by lines far above them (output-only scaling) reads as stiffness.
* :func:`synthetic_record` -- a paper-like record (Nguyen & Melkote 2020): periodic milling forces at
  the spindle and tooth-passing frequencies from the linear-plus-edge force model of formats.md
  (static chip, no regeneration), Gaussian white background force of a given variance per axis,
  force-sensor noise, and tool-tip displacement quantised to the tracker resolution.

The regenerative milling simulator lives in ``stability`` and is deliberately not used here
(``oma`` imports nothing from ``stability``).

References
----------
V. Nguyen, S. N. Melkote, "Identification of industrial robot frequency response function for
robotic milling using operational modal analysis", Procedia Manufacturing 48 (2020),
doi:10.1016/j.promfg.2020.05.032.
G. F. Franklin, J. D. Powell, M. Workman, Digital Control of Dynamic Systems, 3rd ed. (1998),
(the triangle-hold equivalent).
"""

from __future__ import annotations

import functools
import math
from typing import Literal, Sequence

import numpy as np
from scipy import signal as sps

from .cutting import CuttingCoefficients, Cut, Material, Sensors, Tool, engagement_angles
from .modal import ModalModel
from .record import AXES, Channel, Record

__all__ = [
    "mode_filter",
    "hold_equalised",
    "simulate_response",
    "band_limited_response",
    "paper_like_model",
    "paper_like_tool",
    "paper_like_cut",
    "paper_like_material",
    "paper_like_sensors",
    "milling_force",
    "band_limited_milling_force",
    "synthetic_record",
    "PAPER_BACKGROUND_VARIANCE_N2",
]

#: Background force variances of the paper's experiment, X, Y, Z, N^2.
PAPER_BACKGROUND_VARIANCE_N2 = (232.0, 278.0, 251.0)
#: Force simulated after a synthetic record's end, s (:func:`synthetic_record`): the band-limited
#: response's ringing before an abrupt stop decays as ``1 / (pi k)`` over ``k`` samples, here to
#: 3e-4 of the broadband level at 1 kHz.
POSTROLL_S = 1.0


# --------------------------------------------------------------------------- linear response
def mode_filter(natural_frequency_hz: float, damping_ratio: float, sample_rate_hz: float, *, derivative: int = 0):
    """Discrete filter of one unit-mass mode, ``q'' + 2 zeta w q' + w^2 q = p(t)``.

    The input ``p`` is taken piecewise linear between samples (first-order hold), which makes the
    discretisation exact for such inputs and free of the half-sample delay of a zero-order hold.
    Closed form of the triangle-hold equivalent ``H(z) = (z - 1)^2 / (T z) Z{G(s) / s^2}``
    (Franklin, Powell & Workman) for an underdamped mode; ``zeta >= 1`` falls back to
    :func:`scipy.signal.cont2discrete`.

    Parameters
    ----------
    natural_frequency_hz : float
        Undamped natural frequency, Hz.
    damping_ratio : float
        Viscous damping ratio.
    sample_rate_hz : float
        Sampling rate, Hz.
    derivative : {0, 1}
        Output ``q`` (0) or ``q'`` (1).

    Returns
    -------
    b, a : ndarray
        Numerator and denominator for :func:`scipy.signal.lfilter` (displacement, or velocity,
        per unit force per unit mass).
    """
    w = 2.0 * math.pi * float(natural_frequency_hz)
    z = float(damping_ratio)
    t = 1.0 / float(sample_rate_hz)
    if not 0.0 <= z < 1.0:
        return _mode_filter_c2d(w, z, t, derivative)
    sig = z * w
    wd = w * math.sqrt(1.0 - z * z)
    r = math.exp(-sig * t)
    c, s = math.cos(wd * t), math.sin(wd * t)
    # G(s)/s^2 = A/s + B/s^2 + (C s + D)/(s^2 + 2 zeta w s + w^2)
    if derivative == 0:
        a_, b_, c_, d_ = -2 * z / w**3, 1 / w**2, 2 * z / w**3, (4 * z * z - 1) / w**2
    else:
        a_, b_, c_, d_ = 1 / w**2, 0.0, -1 / w**2, -2 * z / w
    e_ = (d_ - c_ * sig) / wd
    d1, d2 = -2.0 * r * c, r * r
    dd = -c_ * r * c + e_ * r * s
    k0 = b_ * t - a_
    # (A z + B T - A)(z^2 + d1 z + d2) + (z^2 - 2 z + 1)(C z + dd); the z^3 coefficient A + C is 0
    num = np.array([
        a_ * d1 + k0 + dd - 2.0 * c_,
        a_ * d2 + k0 * d1 + c_ - 2.0 * dd,
        k0 * d2 + dd,
    ]) / t
    return num, np.array([1.0, d1, d2])


#: Taps on each side of :func:`hold_equalised`'s filter: its response times the hold's
#: ``sinc^2(f / fs)`` is 1 within 2.3e-5 up to 0.2 fs, 3.9e-5 up to 0.4 fs (8 taps: 8e-4; 32: 5e-8).
HOLD_EQUALISER_HALF_TAPS = 16


@functools.lru_cache(maxsize=4)
def _hold_equaliser(half: int) -> np.ndarray:
    """The symmetric FIR (``2 half + 1`` taps) whose response is ``1 / sinc^2(f / fs)``, least
    squares over 0-0.45 fs (above, an acquisition's anti-alias filter leaves nothing)."""
    nu = np.linspace(0.0, 0.45, 40 * half + 1)
    basis = np.column_stack([np.ones_like(nu)] + [2.0 * np.cos(2.0 * np.pi * k * nu) for k in range(1, half + 1)])
    c = np.linalg.lstsq(basis, 1.0 / np.sinc(nu) ** 2, rcond=None)[0]
    taps = np.concatenate([c[:0:-1], c])
    taps.setflags(write=False)
    return taps


def hold_equalised(force, *, axis: int = -1) -> np.ndarray:
    """The samples whose first-order-hold interpolant drives a filter like the band-limited signal
    through ``force`` does.

    A mode discretised with a hold (:func:`mode_filter`) responds to a sampled force as the
    continuous mode to its piecewise-linear interpolant, whose spectrum is the band-limited
    signal's times ``sinc^2(f / fs)`` (-2.6 % at 0.09 fs, -6.6 % at 0.15 fs); a measured force is the
    band-limited one (an anti-aliased acquisition's). Filtering the samples by the inverse
    (:data:`HOLD_EQUALISER_HALF_TAPS`, symmetric, so no delay) removes that: the held mode's line
    is then the continuous one's within 4e-3 (complex) from 0.8 to 1.1 times modes up to 0.2 fs,
    and 6e-3 at the resonance of a mode at 0.3 fs (the hold alone: 26 % short there); what is left
    is the hold's aliases, off resonance near Nyquist (tested in ``tests/test_oma_timefit.py``). The
    record's ends are continued by reflection (the first and last 16 samples approximate).
    """
    from scipy.ndimage import convolve1d

    return convolve1d(np.asarray(force, dtype=float), _hold_equaliser(HOLD_EQUALISER_HALF_TAPS), axis=axis,
                      mode="reflect")


def _mode_filter_c2d(w, z, t, derivative):
    a_c = np.array([[0.0, 1.0], [-w * w, -2.0 * z * w]])
    b_c = np.array([[0.0], [1.0]])
    c_c = np.array([[1.0, 0.0]]) if derivative == 0 else np.array([[0.0, 1.0]])
    ad, bd, cd, dd, _ = sps.cont2discrete((a_c, b_c, c_c, np.zeros((1, 1))), t, method="foh")
    b, a = sps.ss2tf(ad, bd, cd, dd)
    return np.ravel(b), np.ravel(a)


def simulate_response(model: ModalModel, force_N, sample_rate_hz: float) -> np.ndarray:
    """Tool-tip displacement of a modal model driven by a sampled force, from rest.

    Parameters
    ----------
    model : ModalModel
        The tool-tip dynamics.
    force_N : array_like, shape (3, n_samples)
        Force on the tool along X, Y, Z, N, sampled at ``sample_rate_hz`` and taken piecewise
        linear between samples.
    sample_rate_hz : float
        Sampling rate, Hz.

    Returns
    -------
    ndarray, shape (3, n_samples)
        Displacement, m: ``sum_r u_r q_r + residual_compliance @ force``, with
        ``m_r q_r'' + c_r q_r' + k_r q_r = u_r . F`` started at rest at the first sample.
    """
    f = np.asarray(force_N, dtype=float)
    if f.ndim != 2 or f.shape[0] != 3:
        raise ValueError(f"force_N has the wrong shape; expected (3, n_samples) instead of {f.shape}")
    x = np.asarray(model.residual_compliance_m_N) @ f
    for fn, zeta, m, u in zip(
        model.natural_frequency_hz, model.damping_ratio, model.modal_mass_kg, model.directions
    ):
        b, a = mode_filter(fn, zeta, sample_rate_hz)
        x += np.outer(u, sps.lfilter(b, a, u @ f / m))
    return x


def band_limited_response(model: ModalModel, force_N, sample_rate_hz: float, *, derivative: int = 0) -> np.ndarray:
    """Tool-tip motion of a modal model driven by the band-limited force whose samples are given.

    The force is the continuous signal with no content at or above the Nyquist frequency that
    passes through the samples (zero before the first): what an anti-aliased acquisition of a
    continuous force records, and what :func:`band_limited_milling_force` and white sampled noise
    are. Its response at each frequency below Nyquist is the continuous frequency response's,
    exactly; a filter discretised with a hold (:func:`simulate_response`) carries the hold's
    ``sinc^2(f / fs)`` instead. Computed in the frequency domain over the record padded with zero
    force until the slowest mode has decayed to ``1e-10`` (so the periodic transform does not wrap
    the end's response onto the start).

    Parameters
    ----------
    model : ModalModel
        The tool-tip dynamics; every mode damped.
    force_N : array_like, shape (3, n_samples)
        Force on the tool along X, Y, Z, N, sampled at ``sample_rate_hz``.
    sample_rate_hz : float
        Sampling rate, Hz.
    derivative : {0, 1, 2}
        Displacement (m), velocity (m/s) or acceleration (m/s^2); the residual compliance's
        contribution is differentiated alike.

    Returns
    -------
    ndarray, shape (3, n_samples)
        ``sum_r u_r q_r + residual_compliance @ force`` (or its derivative), started at rest.
    """
    from scipy import fft as spfft

    f = np.asarray(force_N, dtype=float)
    if f.ndim != 2 or f.shape[0] != 3:
        raise ValueError(f"force_N has the wrong shape; expected (3, n_samples) instead of {f.shape}")
    if derivative not in (0, 1, 2):
        raise ValueError(f"derivative must be 0, 1 or 2, not {derivative!r}")
    fs = float(sample_rate_hz)
    w_n = 2.0 * np.pi * np.asarray(model.natural_frequency_hz, dtype=float)
    zeta = np.asarray(model.damping_ratio, dtype=float)
    if np.any(zeta <= 0.0):
        raise ValueError("band_limited_response needs every mode damped (damping_ratio > 0)")
    decay_s = np.log(1e10) / np.min(zeta * w_n) if w_n.size else 0.0
    n = f.shape[1]
    n_fft = spfft.next_fast_len(n + int(np.ceil(decay_s * fs)) + 1, real=True)
    force_hat = spfft.rfft(f, n=n_fft, axis=1)
    s = 2j * np.pi * spfft.rfftfreq(n_fft, 1.0 / fs)
    x_hat = np.asarray(model.residual_compliance_m_N, dtype=float) @ force_hat
    for wr, zr, m, u in zip(w_n, zeta, model.modal_mass_kg, model.directions):
        x_hat += np.outer(u, (u @ force_hat) / (m * (s * s + 2.0 * zr * wr * s + wr * wr)))
    return spfft.irfft(x_hat * s ** derivative, n=n_fft, axis=1)[:, :n]


# --------------------------------------------------------------------------- paper-like cell
def paper_like_model() -> ModalModel:
    """The truth of the paper-like example cell (KR500 at the paper's pose, machine frame).

    X: 10.5 Hz, 5 %, 1.5e6 N/m; Y: 24.8 Hz, 4 %, 3.0e6 N/m; Z: 10.0 Hz, 5 %, 2.0e6 N/m; modes along
    the machine axes, no residual compliance.
    """
    return ModalModel(
        natural_frequency_hz=[10.5, 24.8, 10.0],
        damping_ratio=[0.05, 0.04, 0.05],
        stiffness_N_m=[1.5e6, 3.0e6, 2.0e6],
        directions=np.eye(3),
        source={"method": "synthetic truth"},
    )


def paper_like_tool() -> Tool:
    """25.4 mm two-flute end mill with a 30 degree helix (the paper's tool)."""
    return Tool(teeth=2, diameter_m=0.0254, helix_rad=np.deg2rad(30.0))


def paper_like_cut(spindle_rpm: float = 2700.0, window_s=None) -> Cut:
    """The paper's cut: fz 0.5 mm, ae 6 mm, ap 6 mm, down milling, feed along +Y, normal -X."""
    return Cut(
        feed_per_tooth_m=0.0005,
        radial_depth_m=0.006,
        milling="down",
        feed_direction=[0.0, 1.0, 0.0],
        normal_direction=[-1.0, 0.0, 0.0],
        spindle_rpm=spindle_rpm,
        axial_depth_m=0.006,
        window_s=window_s,
    )


def paper_like_material() -> Material:
    """Acetal with the cutting coefficients of the formats.md example."""
    return Material(
        name="acetal",
        cutting_coefficients=CuttingCoefficients(
            Ktc_N_m2=1.2e8, Krc_N_m2=4.5e7, Kac_N_m2=2.0e7, Kte_N_m=2.0e3, Kre_N_m=3.0e3, Kae_N_m=5.0e2
        ),
    )


def paper_like_sensors() -> Sensors:
    """ATI Omega 160 (0.56 N^2 noise, 0.75 N resolution) and Leica AT960 (15 um)."""
    return Sensors(force_noise_variance_N2=0.56, force_resolution_N=0.75, displacement_resolution_m=1.5e-5)


# --------------------------------------------------------------------------- milling force
def milling_force(
    tool: Tool,
    cut: Cut,
    coefficients: CuttingCoefficients,
    time_s,
    *,
    runout_m: Sequence[float] | None = None,
    n_slices: int = 24,
) -> np.ndarray:
    """Periodic milling force on the tool from the static chip (no regeneration), machine frame.

    Implements the linear-plus-edge model of formats.md with the static chip
    ``h_j = fz sin(phi) + rho_j - rho_{j-1}`` (``rho_j`` the radial runout of tooth ``j``), summed over
    ``n_slices`` axial slices with the helix lag ``2 z tan(helix) / D``.

    Parameters
    ----------
    tool : Tool
    cut : Cut
        Must have ``spindle_rpm`` and ``axial_depth_m``.
    coefficients : CuttingCoefficients
    time_s : array_like, shape (n_samples,)
        Sample times, s.
    runout_m : sequence of float, optional
        Radial offset of each tooth, m (length ``tool.teeth``); none by default.
    n_slices : int
        Axial slices of the helix integration.

    Returns
    -------
    ndarray, shape (3, n_samples)
        Force on the tool, N.
    """
    t = np.asarray(time_s, dtype=float)
    teeth = int(tool.teeth)
    rho = np.zeros(teeth) if runout_m is None else np.asarray(runout_m, dtype=float).reshape(teeth)
    omega = 2.0 * np.pi * cut.spindle_rpm / 60.0
    ap = cut.axial_depth_m
    dz = ap / n_slices
    z = (np.arange(n_slices) + 0.5) * dz
    lag = 2.0 * z * np.tan(tool.helix_rad) / tool.diameter_m  # (n_slices,)
    phi_st, phi_ex = engagement_angles(tool, cut)
    k = coefficients
    f_f = np.zeros(t.size)
    f_n = np.zeros(t.size)
    f_a = np.zeros(t.size)
    for j in range(teeth):
        phi = omega * t[:, None] + 2.0 * np.pi * j / teeth - lag[None, :]
        phi = np.mod(phi, 2.0 * np.pi)
        engaged = (phi >= phi_st) & (phi <= phi_ex)
        h = cut.feed_per_tooth_m * np.sin(phi) + rho[j] - rho[j - 1]
        cutting = engaged & (h > 0.0)
        h = np.where(cutting, h, 0.0)
        on = cutting.astype(float)
        d_ft = (k.Ktc_N_m2 * h + k.Kte_N_m * on) * dz
        d_fr = (k.Krc_N_m2 * h + k.Kre_N_m * on) * dz
        d_fa = (k.Kac_N_m2 * h + k.Kae_N_m * on) * dz
        f_f += np.sum(-d_ft * np.cos(phi) - d_fr * np.sin(phi), axis=1)
        f_n += np.sum(d_ft * np.sin(phi) - d_fr * np.cos(phi), axis=1)
        f_a += np.sum(d_fa, axis=1)
    return np.outer(cut.feed_direction, f_f) + np.outer(cut.normal_direction, f_n) + np.outer(cut.tool_axis, f_a)


def band_limited_milling_force(
    tool: Tool,
    cut: Cut,
    coefficients: CuttingCoefficients,
    time_s,
    max_hz: float,
    *,
    runout_m: Sequence[float] | None = None,
    n_per_rev: int = 4096,
) -> np.ndarray:
    """The periodic milling force keeping only its harmonics below ``max_hz``.

    What an anti-aliased acquisition records: the spindle-periodic force of :func:`milling_force`
    is expanded in a Fourier series over one revolution (``n_per_rev`` points) and re-synthesised
    at ``time_s`` from the lines below ``max_hz`` only. Sampling the raw force instead would fold
    the sharp tooth-entry harmonics above the Nyquist frequency onto lines that are not spindle
    multiples.

    Returns
    -------
    ndarray, shape (3, n_samples)
        Force on the tool, N.
    """
    f_spindle = cut.spindle_rpm / 60.0
    t_rev = np.arange(n_per_rev) / (n_per_rev * f_spindle)
    one_rev = milling_force(tool, cut, coefficients, t_rev, runout_m=runout_m)
    coef = np.fft.rfft(one_rev, axis=-1) / n_per_rev  # (3, n_per_rev//2+1)
    h = np.arange(coef.shape[1])
    keep = h * f_spindle < max_hz
    t = np.asarray(time_s, dtype=float)
    out = np.repeat(coef[:, :1].real, t.size, axis=1)
    for hh in h[keep][1:]:
        ph = np.exp(2j * np.pi * hh * f_spindle * t)
        out += 2.0 * np.real(coef[:, hh : hh + 1] * ph[None, :])
    return out


# --------------------------------------------------------------------------- records
def _quantise(x, step, offset=0.0):
    if step is None or step <= 0:
        return x
    return step * np.round((x - offset) / step) + offset


def synthetic_record(
    model: ModalModel | None = None,
    *,
    duration_s: float = 1.1,
    sample_rate_hz: float = 1000.0,
    spindle_rpm: float = 2700.0,
    nominal_rpm: float | None = None,
    tool: Tool | None = None,
    cut: Cut | None = None,
    material: Material | None = None,
    sensors: Sensors | None = None,
    background_variance_N2: Sequence[float] = PAPER_BACKGROUND_VARIANCE_N2,
    harmonics: bool = True,
    runout_m: Sequence[float] | None = (5e-6, -5e-6),
    output: Literal["displacement", "velocity", "acceleration"] = "displacement",
    preroll_s: float = 3.0,
    rng: np.random.Generator | int | None = None,
    name: str | None = None,
) -> Record:
    """A paper-like milling record with known dynamics and known background force.

    The true force is the periodic milling force (:func:`milling_force`) plus independent Gaussian
    white noise of variance ``background_variance_N2`` per axis (band-limited to the sampling
    rate). The structure responds to the true force (:func:`band_limited_response`, started
    ``preroll_s`` earlier so that the record is stationary, the force going on for
    :data:`POSTROLL_S` after it). The recorded force adds sensor noise
    of ``sensors.force_noise_variance_N2`` and is rounded to ``sensors.force_resolution_N``; the
    recorded displacement is the response plus a random absolute position, rounded to
    ``sensors.displacement_resolution_m`` (the tracker grid does not line up with the tool).

    Parameters
    ----------
    model : ModalModel, optional
        Truth; :func:`paper_like_model` by default.
    duration_s : float
        Record length, s (1.1 s: the paper's 50 mm cut).
    sample_rate_hz : float
        Sampling rate, Hz.
    spindle_rpm : float
        True spindle speed, rev/min.
    nominal_rpm : float, optional
        Spindle speed written into the record's cut (what the controller claimed); defaults to the
        true speed. Use it to test harmonic refinement.
    tool, cut, material, sensors : optional
        Paper-like by default (:func:`paper_like_tool` ...). ``cut.spindle_rpm`` is overridden.
    background_variance_N2 : sequence of 3 float
        Variance of the white background force along X, Y, Z, N^2.
    harmonics : bool
        Include the periodic milling force.
    runout_m : sequence of float, optional
        Radial runout per tooth (gives the spindle-frequency line).
    output : {'displacement', 'velocity', 'acceleration'}
        What the motion channels carry (velocity and acceleration are exact derivatives of the
        response, not quantised).
    preroll_s : float
        Simulated time before the record starts, s.
    rng : numpy.random.Generator or int, optional
        Random source (seeded generator or seed).
    name : str, optional

    Returns
    -------
    Record
        Channels ``Fx, Fy, Fz`` (force, N) and ``x, y, z`` (displacement in m, or velocity /
        acceleration).
    """
    if output not in ("displacement", "velocity", "acceleration"):
        raise ValueError(f"output must be 'displacement', 'velocity' or 'acceleration', not {output!r}")
    rng = np.random.default_rng(rng)
    model = paper_like_model() if model is None else model
    tool = paper_like_tool() if tool is None else tool
    material = paper_like_material() if material is None else material
    sensors = paper_like_sensors() if sensors is None else sensors
    base_cut = paper_like_cut(spindle_rpm) if cut is None else cut
    from dataclasses import replace

    true_cut = replace(base_cut, spindle_rpm=float(spindle_rpm))
    recorded_cut = replace(base_cut, spindle_rpm=float(spindle_rpm if nominal_rpm is None else nominal_rpm))

    fs = float(sample_rate_hz)
    n = int(round(duration_s * fs))
    n_pre = int(round(preroll_s * fs))
    # the force goes on after the record (a record is a window of a longer cut): the band-limited
    # response to a force that stopped at the record's end would ring before it
    n_post = int(round(POSTROLL_S * fs))
    t = (np.arange(n_pre + n + n_post) - n_pre) / fs
    force = np.zeros((3, t.size))
    if harmonics:
        if material.cutting_coefficients is None:
            raise ValueError("material has no cutting coefficients; cannot make the milling force")
        force += band_limited_milling_force(
            tool, true_cut, material.cutting_coefficients, t, 0.5 * fs, runout_m=runout_m
        )
    sigma = np.sqrt(np.asarray(background_variance_N2, dtype=float).reshape(3))
    noise = rng.standard_normal((3, n_pre + n))
    # the noise after the record from a stream of its own (the generator jumped ahead), so that the
    # record's draws do not depend on it (a bit generator that cannot jump gives a seed instead)
    jumped = getattr(rng.bit_generator, "jumped", None)
    after = np.random.Generator(jumped()) if jumped is not None else np.random.default_rng(rng.integers(2**63))
    force += sigma[:, None] * np.hstack([noise, after.standard_normal((3, n_post))])
    order = ("displacement", "velocity", "acceleration").index(output)
    motion = band_limited_response(model, force, fs, derivative=order)[:, n_pre:n_pre + n]
    force = force[:, n_pre:n_pre + n]

    measured_force = force.copy()
    if sensors.force_noise_variance_N2:
        measured_force += np.sqrt(sensors.force_noise_variance_N2) * rng.standard_normal(force.shape)
    measured_force = _quantise(measured_force, sensors.force_resolution_N)

    if output == "displacement":
        step = sensors.displacement_resolution_m
        absolute = rng.uniform(0.0, step) if step else 0.0
        motion = _quantise(motion + absolute, step)
        unit = "m"
    else:
        unit = "m/s" if output == "velocity" else "m/s2"

    channels = [Channel(f"F{a.lower()}", "force", a, "N") for a in AXES]
    channels += [Channel(a.lower(), output, a, unit) for a in AXES]
    return Record(
        sample_rate_hz=fs,
        channels=tuple(channels),
        data=np.vstack([measured_force, motion]),
        tool=tool,
        cut=recorded_cut,
        material=material,
        sensors=sensors,
        name=name or "synthetic",
    )
