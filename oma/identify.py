"""OMA pipeline: the robot's tool-tip modal model from milling records, and whether to trust it.

Steps (robomill issue 3; Nguyen & Melkote 2020 for steps 1-4):

0. Records: one pose (joint angles within :data:`oma._identify_checks.SAME_POSE_TOLERANCE_DEG`),
   each cut window long enough for its force spectrum to separate the milling harmonics from the
   background force; otherwise a :class:`~oma.errors.RecordError`. Records sampled far above what
   the fits read (accelerometers at 10-51.2 kHz) are decimated first, by the rule of
   :mod:`oma.decimation` (at least 4 kHz, ten times the band's top, 2.5 times the tooth-passing
   frequency); not rounded displacement, whose grid the likelihood of step 5 uses.
1. Harmonics: spindle and tooth-passing lines of each record, the spindle frequency refined from the
   force spectrum (:mod:`oma.harmonics`).
2. Background force variance per axis from the force PSD with the harmonics removed.
3. FRF: multiple-input H1 from pooled Welch spectra of all records, harmonic lines left out, with
   coherence and random-error bands (:mod:`oma.frf_estimate`).
4. Modal fit of the H1 FRF: stabilisation diagram (:mod:`oma.lscf`), nonlinear least squares, BIC
   (:mod:`oma.fit`, :mod:`oma.modal_fit`).
   With ``method='h1'`` this is the answer (the paper's estimator plus a fit).
5. ``method='default'``: time-domain fit of the modal model to the measured force and displacement,
   started from step 4, with the exact likelihood of a quantised (tracker) displacement
   (:mod:`oma.timefit`). No window, no leakage: it is what makes a 1.1 s cut usable. Motion that is
   not rounded (velocity, acceleration, continuous displacement): samples no model explains
   (spikes, the edge ringing of an FFT derivative) are left out and the fit repeated
   (:mod:`oma._timefit_artefacts`), and the result is cross-checked against step 4 where that
   resolves the modes (the H1 fit is reported when the time-domain fit misses the H1 estimate far
   more).
   No mode lies outside the band the records resolve: above 0.3 fs (the anti-alias roll-off) or
   below 4 cycles in the longest record; a model that needed one there is not trusted. The static
   compliance of modes above the analysed band (a tool mode above 0.3 fs), flat in the H1
   estimate beyond the model's modes, is estimated (:mod:`oma._upper_residual`); where it is
   there, it is the model's residual compliance and the model is not trusted.
6. Detectability: the smallest background variance the displacement sensor can resolve through the
   identified model, per axis (:mod:`oma.detectability`); an axis below it is flagged and the model
   is marked untrusted.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal, Sequence

import numpy as np

from ._arrays import readonly as _ro
from .decimation import analysis_factor, decimated, white_power
from .detectability import Detectability, detectability
from .errors import RecordError
from ._identify_checks import (artefact_warnings, check_duration, check_same_pose, h1_disagreement, h1_misfit,
                              keep_in_band)
from ._linalg import single_threaded_blas
from .modal_fit import ModalFit, fit_modal_model
from .frf_estimate import FRFEstimate, estimate_frf, frf_agreement
from .frf_table import FRFTable
from .harmonics import BackgroundEstimate, Harmonics, background_variance, find_harmonics, fit_harmonic_signal
from .modal import ModalModel
from .record import Record
from .signals import PreparedSignals, prepare_record
from .synthetic import simulate_response
from .quantised import MIN_BLOCKS
from .timefit import NoModeFound, TimeFit, fit_time_domain, resolved_band_hz
from ._timefit_artefacts import MAX_TRUSTED_SHARE, fit_without_artefacts
from ._upper_residual import UpperResidual, upper_residual

__all__ = ["Identification", "identify", "modal_mapping", "frf_agreement", "METHODS", "ROBOT_BAND_HZ"]

AXES = ("X", "Y", "Z")
METHODS = ("default", "h1")
#: Upper end of the default fit band, Hz: robot structural modes sit at 8-40 Hz (DOMAIN.md); pass
#: ``band_hz`` to fit spindle or tool modes higher up.
MAX_BAND_HZ = 100.0
#: Band of the robot's structural modes, Hz, where an identified FRF is compared with a hammer test
#: (``robomill identify --reference``, the demo).
ROBOT_BAND_HZ = (5.0, 40.0)
#: The default method starts from the H1 fit only when the Welch lines are at most this far apart,
#: Hz: the half-power band 2 zeta f_n of a 5 %-damped 5 Hz mode. Coarser (short records): the
#: time-domain fit searches for the modes itself.
MIN_RESOLVED_BANDWIDTH_HZ = 0.5
Method = Literal["default", "h1"]


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


def modal_mapping(model: ModalModel) -> dict[str, Any]:
    """A :class:`ModalModel` as a ``robomill-modal/1`` mapping (plain Python types, YAML/JSON-ready)."""
    out: dict[str, Any] = {"format": "robomill-modal/1"}
    if model.joints_deg is not None:
        out["pose"] = {"joints_deg": [float(v) for v in model.joints_deg]}
    out["modes"] = [
        {
            "natural_frequency_hz": float(f),
            "damping_ratio": float(z),
            "stiffness_N_m": float(k),
            "direction": [float(v) for v in u],
        }
        for f, z, k, u in zip(model.natural_frequency_hz, model.damping_ratio, model.stiffness_N_m, model.directions)
    ]
    out["residual_compliance_m_N"] = [[float(v) for v in row] for row in model.residual_compliance_m_N]
    if model.source is not None:
        out["source"] = _plain(model.source)
    return out


def _plain(obj):
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return _num(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


@dataclass(frozen=True)
class Identification:
    """What :func:`identify` found, and how far to trust it.

    Attributes
    ----------
    model : ModalModel
        The identified tool-tip model, with ``source`` provenance.
    frf : FRFTable
        The H1 estimate (receptance, with ordinary coherence), harmonic lines left out.
    frf_fit_error : ndarray, shape (3,)
        Relative misfit per axis (NaN for axes not measured). ``method='h1'``: the model against
        the H1 estimate (direct entries, weighted by the inverse random error, in the fitted
        band). Default method: the time-domain misfit of the displacement beyond the sensor's
        rounding noise (:attr:`oma.timefit.TimeFit.fit_error`), because the H1 estimate of
        quantised displacement is itself biased; it is that of the fit's modes, before a residual
        compliance of modes above the band is added (:attr:`upper_residual`).
    noise_variance_N2 : ndarray, shape (3,)
        Background force variance per axis (harmonics removed, sensor noise subtracted), N^2.
    min_noise_variance_N2 : ndarray, shape (3,)
        Smallest background variance the displacement sensor can resolve through the model, N^2.
    excitation_sufficient : ndarray of bool, shape (3,)
        Per axis, whether the background force moves the tool enough for the displacement sensor
        (False for an axis without recorded motion).
    trusted : bool
        Every measured axis sufficiently excited, the fit converged and its errors are acceptable,
        no mode was needed outside the band the records resolve, the records show no compliance of
        modes above the analysed band (:attr:`upper_residual`), at most 2 % of a record's samples
        were left out of the fit as artefacts, and (unrounded motion) the time-domain fit agrees
        with the H1 fit.
    harmonics : tuple of Harmonics
        One per record.
    warnings : tuple of str
    method : str
    frf_estimate : FRFEstimate
        The estimate with its random-error bands.
    modal_fit : ModalFit or None
        The frequency-domain fit (the answer for ``method='h1'``, the start otherwise; None when
        it found no mode).
    time_fit : TimeFit or None
    background : tuple of BackgroundEstimate
        One per record.
    detectability : Detectability
    upper_residual : UpperResidual
        The flat compliance of the H1 estimate beyond the model's modes in the analysed band: the
        static compliance of modes above it (:func:`oma._upper_residual.upper_residual`). Where it
        is present the model carries it as its residual compliance (the H1 fit's own, for a model
        from the H1 fit).
    analysis_rate_hz : float
        The rate the records were analysed at, Hz: theirs, or lower where they were decimated
        (:mod:`oma.decimation`). ``frf``, ``harmonics`` and the fits are at this rate;
        ``noise_variance_N2`` and ``min_noise_variance_N2`` are at the recorded rate (white levels:
        decimated, the background's variance is divided by the filter's
        :func:`oma.decimation.white_power` and multiplied by the factor).
    """

    model: ModalModel
    frf: FRFTable
    frf_fit_error: np.ndarray
    noise_variance_N2: np.ndarray
    min_noise_variance_N2: np.ndarray
    excitation_sufficient: np.ndarray
    trusted: bool
    harmonics: tuple
    warnings: tuple
    method: str
    frf_estimate: FRFEstimate = field(repr=False)
    modal_fit: ModalFit | None = field(repr=False)
    time_fit: TimeFit | None = field(default=None, repr=False)
    background: tuple = field(default=(), repr=False)
    detectability: Detectability | None = field(default=None, repr=False)
    upper_residual: UpperResidual | None = field(default=None, repr=False)
    analysis_rate_hz: float | None = None

    def __post_init__(self):
        for name in ("frf_fit_error", "noise_variance_N2", "min_noise_variance_N2"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "excitation_sufficient", _ro(self.excitation_sufficient, bool))
        object.__setattr__(self, "harmonics", tuple(self.harmonics))
        object.__setattr__(self, "warnings", tuple(self.warnings))
        object.__setattr__(self, "background", tuple(self.background))

    def to_dict(self) -> dict[str, Any]:
        """The ``robomill identify --json`` object (cli.md): per-axis values keyed ``X``, ``Y``, ``Z``."""

        def per_axis(v):
            return {a: _num(x) for a, x in zip(AXES, v)}

        return {
            "model": modal_mapping(self.model),
            "frf_fit_error": per_axis(self.frf_fit_error),
            "noise_variance_N2": per_axis(self.noise_variance_N2),
            "min_noise_variance_N2": per_axis(self.min_noise_variance_N2),
            "excitation_sufficient": {a: bool(s) for a, s in zip(AXES, self.excitation_sufficient)},
            "trusted": bool(self.trusted),
            "method": self.method,
            "harmonics": [h.to_dict() for h in self.harmonics],
            "warnings": list(self.warnings),
            "uncertainty": self.uncertainty(),
            "upper_residual": None if self.upper_residual is None else self.upper_residual.to_dict(),
            "analysis_rate_hz": _num(self.analysis_rate_hz),
        }

    def standard_errors(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Standard errors of the modes' frequencies (Hz) and damping ratios, in model order, and
        the number of blocks behind them (:class:`oma.timefit.TimeFit`); NaN where there are none
        (see :meth:`uncertainty`)."""
        tf = self.time_fit
        ok = (tf is not None and tf.n_blocks >= MIN_BLOCKS  # the reported model is the time fit's
              and np.array_equal(tf.model.natural_frequency_hz, self.model.natural_frequency_hz)
              and np.array_equal(tf.model.damping_ratio, self.model.damping_ratio))
        if not ok:
            nan = np.full(self.model.n_modes, np.nan)
            return nan, nan, int(tf.n_blocks) if tf is not None else 0
        return np.asarray(tf.frequency_se_hz), np.asarray(tf.damping_se), int(tf.n_blocks)

    def uncertainty(self, level: float = 0.95) -> dict[str, Any]:
        """Standard errors and ``level`` intervals of the modes' frequency and damping.

        From the block sandwich of the time-domain likelihood (:class:`oma.timefit.TimeFit`):
        frequency ``f +- t se``, damping log-symmetric ``zeta exp(+-t se / zeta)``, ``t`` the
        Student quantile with ``blocks - 1`` degrees of freedom. ``available`` is false (values
        null) for the H1 method, the free-residue likelihood of rounded data, and records too
        short to tell their own scatter (fewer than :data:`oma.quantised.MIN_BLOCKS` blocks).
        """
        from .output_only.uncertainty import t_interval

        f, z = self.model.natural_frequency_hz, self.model.damping_ratio
        se_f, se_z, blocks = self.standard_errors()
        f_iv = t_interval(f, se_f, blocks, level)
        z_iv = np.exp(t_interval(np.log(z), se_z / z, blocks, level))
        modes = []
        for i in range(self.model.n_modes):
            good = bool(np.isfinite(se_f[i]) and np.isfinite(se_z[i]))
            modes.append({
                "natural_frequency_hz": float(f[i]), "frequency_standard_error_hz": _num(se_f[i]) if good else None,
                "frequency_interval_hz": [_num(v) for v in f_iv[i]] if good else [None, None],
                "damping_ratio": float(z[i]), "damping_standard_error": _num(se_z[i]) if good else None,
                "damping_interval": [_num(v) for v in z_iv[i]] if good else [None, None]})
        return {"available": bool(modes) and all(m["frequency_standard_error_hz"] is not None for m in modes),
                "level": float(level), "blocks": blocks, "modes": modes}

    # plots delegate to oma.plots (matplotlib imported there, only when called)
    def plot_frf(self, reference=None, *, axes=None, **kwargs):
        """Identified (model and H1 estimate) versus reference FRF, magnitude, phase and coherence."""
        from .plots import plot_frf_comparison

        return plot_frf_comparison(self, reference=reference, axes=axes, **kwargs)

    def plot_force_spectrum(self, record: int = 0, *, ax=None, **kwargs):
        """Force PSD of one record with its harmonics marked and the background level."""
        from .plots import plot_force_spectrum

        return plot_force_spectrum(self.background[record], self.harmonics[record], ax=ax, **kwargs)

    def plot_detectability(self, *, ax=None, **kwargs):
        """Peak-to-valley response versus background variance with the sensor resolution line."""
        from .plots import plot_detectability

        return plot_detectability(self.detectability, ax=ax, **kwargs)

    def plot(self, reference=None, **kwargs):
        """All three figures; returns a list of ``(fig, axes)``."""
        return [self.plot_frf(reference, **kwargs), self.plot_force_spectrum(), self.plot_detectability()]


def _force_error_variance(record: Record) -> float:
    """Variance of a record's force error per sample, N^2: sensor noise plus rounding ``q^2 / 12``."""
    s = record.sensors
    if s is None:
        return 0.0
    return (s.force_noise_variance_N2 or 0.0) + (s.force_resolution_N or 0.0) ** 2 / 12.0


def _fit_band(est: FRFEstimate, fs: float) -> tuple[float, float]:
    """Lines worth fitting: from the first line up to 2.5 times the highest coherent line.

    A line is coherent when the running median (five lines) of its multiple coherence exceeds the
    99 % point of the multiple coherence of unrelated Gaussian signals, a Beta(q, n_d - q)
    variable for ``q`` inputs and ``n_d`` averages (Goodman 1963; Bendat & Piersol). The band
    ends at :data:`MAX_BAND_HZ` at most, and below the anti-alias roll-off
    (:func:`oma.timefit.resolved_band_hz`).
    """
    from scipy import stats

    f = est.freq_hz
    mc = np.nan_to_num(est.multiple_coherence, nan=0.0)
    q = int(np.sum(np.any(est.table.measured, axis=0)))
    nd = max(est.n_averages, q + 1.0)
    threshold = float(stats.beta.ppf(0.99, q, max(nd - q, 0.5)))
    # a running median over five lines keeps out lines that are coherent by chance
    from scipy.ndimage import median_filter

    smooth = median_filter(mc, size=(1, 5), mode="nearest")
    coherent = np.any(smooth > threshold, axis=0)
    df = f[1] - f[0] if f.size > 1 else 1.0
    top = f[coherent].max() if np.any(coherent) else 0.1 * fs
    hi = min(max(2.5 * top, 8 * df), resolved_band_hz(fs), MAX_BAND_HZ)
    return float(f.min()), float(hi)


def identify(
    records: Sequence[Record],
    *,
    method: Method = "default",
    nperseg: int | None = None,
    band_hz: tuple[float, float] | None = None,
    refine_harmonics: bool = True,
    max_fit_error: float = 0.5,
    n_trials: int = 100,
    rng=0,
    decimate: bool = True,
) -> Identification:
    """Identify the tool-tip modal model from one or more milling records of the same pose.

    Parameters
    ----------
    records : sequence of Record
        Force (N) and tool-tip displacement, velocity or acceleration, same sampling rate, same
        pose. Each record's ``cut.window_s`` (if given) selects the fully engaged span.
    method : {'default', 'h1'}
        ``'h1'``: the paper's estimator (Welch H1) followed by the modal fit of :mod:`oma.fit`.
        ``'default'``: that fit refined by the time-domain maximum-likelihood fit of
        :mod:`oma.timefit` (much better on short cuts and on quantised displacement).
    nperseg : int, optional
        Welch segment length of the H1 estimate; a quarter of the shortest record by default.
    band_hz : (float, float), optional
        Band of the frequency-domain fit; by default from the first line to 2.5 times the highest
        line whose multiple coherence is significant, at most :data:`MAX_BAND_HZ`.
    refine_harmonics : bool
        Refine each record's spindle frequency from its force spectrum.
    max_fit_error : float
        Largest per-axis ``frf_fit_error`` of a trusted model.
    n_trials : int
        Realisations in the detectability simulation.
    rng : int or numpy.random.Generator
        Seed of the detectability simulation (the verdict is reproducible by default).
    decimate : bool
        Records sampled far above what the fits read are decimated first (:func:`analysis_factor`;
        the rate used is ``analysis_rate_hz``). Variances are reported at the recorded rate either
        way. False: the recorded rate throughout.

    Returns
    -------
    Identification

    Raises
    ------
    ValueError
        Unknown ``method``, no records.
    RecordError
        A record without force or motion channels, a bad cut window, records with different
        sampling rates or poses (joint angles more than
        :data:`oma._identify_checks.SAME_POSE_TOLERANCE_DEG` apart), a cut window too short for
        the force spectrum to resolve the milling harmonics
        (:func:`oma._identify_checks.min_samples_for_harmonics`).
    """
    with single_threaded_blas():
        return _identify(records, method=method, nperseg=nperseg, band_hz=band_hz,
                         refine_harmonics=refine_harmonics, max_fit_error=max_fit_error, n_trials=n_trials, rng=rng,
                         decimate=decimate)


def _analysis_records(records, signals, band_hz):
    """The records at the rate the fits read (:mod:`oma.decimation`), their prepared signals and the
    factor (``records`` and ``signals`` as they are when it is 1). Rounded displacement is kept at
    its rate: the time-domain likelihood uses its grid, which filtering would blur. The force
    sensor's white errors are those the filter leaves (``white_power(q) / q`` of their variance)."""
    if any(s.quantisation_step_m for s in signals):
        return records, signals, 1
    q = analysis_factor(records, band_hz if band_hz is not None else (0.0, MAX_BAND_HZ))
    if q == 1:
        return records, signals, 1
    keep = white_power(q) / q  # of a white noise's variance, per sample
    out = []
    for r in records:
        d, s = decimated(r, q), r.sensors
        if s is not None:
            # the sensor's white noise and rounding (step^2 / 12), as the filter leaves them
            d = replace(d, sensors=replace(
                s, force_noise_variance_N2=None if s.force_noise_variance_N2 is None else s.force_noise_variance_N2 * keep,
                force_resolution_N=None if s.force_resolution_N is None else s.force_resolution_N * np.sqrt(keep)))
        out.append(d)
    return out, [prepare_record(r) for r in out], q


def _identify(records, *, method, nperseg, band_hz, refine_harmonics, max_fit_error, n_trials, rng,
              decimate=True) -> Identification:
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, not {method!r}")
    records = list(records)
    if not records:
        raise ValueError("identify needs at least one record")
    fs = float(records[0].sample_rate_hz)
    for r in records[1:]:
        if abs(r.sample_rate_hz - fs) > 1e-9 * fs:
            raise RecordError(r.path, "sample_rate_hz", f"{fs} Hz like the first record", f"{r.sample_rate_hz} Hz")
    check_same_pose(records)
    signals: list[PreparedSignals] = [prepare_record(r) for r in records]
    if decimate:
        records, signals, q = _analysis_records(records, signals, band_hz)
    else:
        q = 1
    fs = float(records[0].sample_rate_hz)
    warnings: list[str] = []

    for r, s in zip(records, signals):
        check_duration(r, s.n_samples)
    harmonics, backgrounds = _milling_lines(records, signals, fs, refine_harmonics, warnings)
    durations = np.array([s.duration_s for s in signals])
    noise_var = np.sum([b.variance_N2 * d for b, d in zip(backgrounds, durations)], axis=0) / durations.sum()
    # the white level of the background, which the decimation filter's roll-off lowered
    noise_var = noise_var / white_power(q)

    est = estimate_frf(signals, harmonics=harmonics, estimator="h1", nperseg=nperseg)
    band = _fit_band(est, fs) if band_hz is None else (float(band_hz[0]), float(band_hz[1]))
    names = [r.name or f"record {i}" for i, r in enumerate(records)]
    with np.errstate(divide="ignore"):
        weights = np.where(np.isfinite(est.std_m_N), 1.0 / est.std_m_N, 0.0)
    model, mfit, tfit, artefacts = _fitted(records, signals, harmonics, est, weights, band, names, method, fs,
                                           max_fit_error, warnings)

    # an unquantised time-domain fit far worse than the H1 fit of the same records was led astray
    agree = True
    if tfit is not None and mfit is not None and not tfit.quantised:
        why = h1_disagreement(tfit.model, mfit.model, est, weights, band)
        if why:
            agree, model = False, mfit.model
            warnings.append(why)

    # no mode outside the band the records resolve; a model that needed one there is flagged
    tfit_reported = tfit is not None and agree
    model, band_warnings = keep_in_band(model, tfit if tfit_reported else None, fs)
    warnings += band_warnings
    band_ok = not band_warnings

    # the static compliance of modes above the band, flat in the H1 estimate beyond the model's
    # modes: where it is there it goes into the model (a time-domain fit has none), and the model
    # is not trusted, since those modes' own dynamics are not in it
    upper = upper_residual(model, est, weights, band)
    added = bool(np.any(upper.present)) and not np.any(model.residual_compliance_m_N)
    if added:
        model = model.with_modes(residual_compliance_m_N=upper.model_compliance())
    upper_warning = upper.warning(fs, added=added)
    if upper_warning:
        warnings.append(upper_warning)

    # fit error: for 'h1' the model against the H1 estimate (direct entries, weighted by the
    # inverse random error, in the fitted band); for the default the time-domain misfit beyond
    # the rounding noise (the H1 estimate itself is biased by the rounding, see oma.timefit)
    f = est.freq_hz
    ferr = h1_misfit(model, est, weights, band)
    if tfit_reported:
        ferr = np.where(np.isfinite(ferr), tfit.fit_error, np.nan)

    measured_axes = [a for a in range(3) if est.table.measured[a, a]]
    det, sufficient, short = _excitation(model, records, signals, harmonics, fs, durations, noise_var, measured_axes,
                                         n_trials, rng, warnings)
    for a in measured_axes:
        if a in short:
            warnings.append(short[a])
        if np.isfinite(ferr[a]) and ferr[a] > max_fit_error:
            what = "the measured displacement (beyond its rounding)" if tfit_reported else "the H1 estimate"
            # a degenerate fit's error can be astronomical (4e146 for a mode under a tracker's rounding step)
            size = f"{100 * ferr[a]:.0f}" if ferr[a] < 1e3 else f"{100 * ferr[a]:.2g}"
            warnings.append(f"{AXES[a]}: the model misses {what} by {size} % (fit error)")
    for hz in model.natural_frequency_hz:
        for h in harmonics:
            if h is not None and np.any(np.abs(h.freq_hz[h.significant] - hz) < 2.0 * (f[1] - f[0])):
                warnings.append(f"mode at {hz:.1f} Hz sits on a milling harmonic; its estimate is uncertain")
                break
    fit_ok = tfit.success if tfit_reported else (mfit.success and method == "h1")
    clean = artefacts is None or (artefacts.resolved and all(
        artefacts.share(i) <= MAX_TRUSTED_SHARE for i in range(len(records))))
    trusted = bool(
        fit_ok
        and band_ok
        and upper_warning is None
        and clean
        and agree
        and all(sufficient[a] for a in measured_axes)
        and all(not np.isfinite(ferr[a]) or ferr[a] <= max_fit_error for a in measured_axes)
    )
    if not trusted:
        warnings.append("the identified model is NOT trusted (see the warnings above)")
    source = {
        "method": "oma-h1" if not tfit_reported else ("oma-time-domain-ml" if tfit.quantised else "oma-time-domain-ls"),
        "records": names,
        "fit_error": _num(np.nanmax(ferr)) if np.any(np.isfinite(ferr)) else None,
        "trusted": trusted,
    }
    joints = next((r.joints_deg for r in records if r.joints_deg is not None), None)
    model = model.with_modes(source=source, joints_deg=joints)
    return Identification(
        model=model,
        frf=est.table,
        frf_fit_error=ferr,
        # white variances per sample at the recorded rate: q times the analysis rate's
        noise_variance_N2=noise_var * q,
        min_noise_variance_N2=det.min_variance_N2 * q,
        excitation_sufficient=sufficient,
        trusted=trusted,
        harmonics=tuple(harmonics),
        warnings=tuple(warnings),
        method=method,
        frf_estimate=est,
        modal_fit=mfit,
        time_fit=tfit,
        background=tuple(backgrounds),
        detectability=det,
        upper_residual=upper,
        analysis_rate_hz=fs,
    )


def _milling_lines(records, signals, fs, refine_harmonics, warnings):
    """Per record the milling harmonics of the force (None without a spindle speed; the speed
    refined from the force's comb, said when it moved by more than 0.5 %) and the background
    force's variance left beside them."""
    harmonics: list[Harmonics | None] = []
    backgrounds: list[BackgroundEstimate] = []
    for r, s in zip(records, signals):
        name = r.name or "record"
        rpm, teeth = r.cut.spindle_rpm, r.tool.teeth
        if rpm is None or rpm <= 0:
            warnings.append(f"{name}: no spindle speed; milling harmonics not removed")
            h = None
        else:
            h = find_harmonics(s.force_N, fs, rpm, teeth, refine=refine_harmonics)
            shift = h.spindle_hz / h.nominal_spindle_hz - 1.0
            if abs(shift) > 0.005:
                warnings.append(
                    f"{name}: spindle speed refined from the force spectrum: {rpm:.0f} rpm nominal, "
                    f"{h.spindle_rpm:.0f} rpm found ({100 * shift:+.1f} %)"
                )
        harmonics.append(h)
        noise = r.sensors.force_noise_variance_N2 if r.sensors is not None else None
        hh = h if h is not None else Harmonics(fs, fs, 1, [], [], [])
        backgrounds.append(background_variance(s.force_N, fs, hh, sensor_noise_variance_N2=noise))
    return harmonics, backgrounds


def _fitted(records, signals, harmonics, est, weights, band, names, method, fs, max_fit_error, warnings):
    """The modal model (H1's with ``method='h1'``, else the time-domain fit's), the H1 modal fit,
    the time-domain fit and its artefacts (None where not run)."""
    df = est.freq_hz[1] - est.freq_hz[0]
    mfit = None
    if method == "h1" or df <= MIN_RESOLVED_BANDWIDTH_HZ:
        try:
            mfit = fit_modal_model(est.table, weights=weights, band_hz=band,
                                   source={"method": "oma-h1", "records": names})
        except ValueError as exc:  # no stable mode in the H1 estimate
            if method == "h1":
                raise
            warnings.append(f"H1 modal fit failed ({exc}); modes searched in the time domain")
    tfit = None
    artefacts = None
    model = None if mfit is None else mfit.model
    if method != "default":
        return model, mfit, tfit, artefacts
    start = None if mfit is None else mfit.model
    resolved = start is not None and bool(
        np.all(df < 2.0 * start.damping_ratio * start.natural_frequency_hz)
    )
    # when the Welch lines are narrower than every fitted mode's half-power band, the H1 fit has
    # found the modes and the time-domain fit refines them; otherwise (short records) the
    # time-domain fit searches for the modes itself. When the fit from the H1 start, with the
    # samples no model explains left out (spikes, which spoil the H1 estimate too), still misses the
    # records by more than a trusted model may, and the start itself misses the H1 estimate as much,
    # the search adds the modes the start lacked. A start that explains the H1 estimate lacks no
    # mode: the time-domain model's trouble is then response it cannot follow (session 32: an
    # accelerometer record of modes above the band, start 0.5 % from the H1 estimate, searched for
    # 35 s of its 60 and reported the H1 fit all the same).
    noise_n2 = [_force_error_variance(r) for r in records]

    def refit(keep=None, previous=None, search_more=False):
        # refits after the first start from the last one's modes (the first may have been led astray)
        initial, search = (start, False) if resolved else (None, True)
        if previous is not None:
            initial, search = previous.model, search_more
        return fit_time_domain(signals, harmonics, initial, search=search, force_noise_variance_N2=noise_n2,
                               keep_samples=keep, source={"method": "oma-time-domain", "records": names})

    try:
        tfit = refit()
        if not tfit.quantised:
            # samples no model explains (spikes, edge artefacts) are left out and the fit repeated
            tfit, artefacts = fit_without_artefacts(signals, harmonics, tfit, refit)
        if (resolved and np.nanmax(tfit.fit_error, initial=0.0) > max_fit_error
                and np.nanmax(h1_misfit(start, est, weights, band), initial=0.0) > max_fit_error):
            # the search's modes in the band, refitted without the ones it pinned at the band's ends:
            # the start the H1 fit should have given, fitted as one it had given would be
            keep = None if artefacts is None else [~e for e in artefacts.excluded]
            searched = refit(keep, refit(keep, tfit, search_more=True))
            if np.nanmax(searched.fit_error, initial=0.0) < np.nanmax(tfit.fit_error, initial=0.0):
                tfit = searched
    except NoModeFound as exc:  # no mode at all: nothing in the records but rounding noise
        if mfit is None:
            try:
                mfit = fit_modal_model(est.table, weights=weights, band_hz=band,
                                       source={"method": "oma-h1", "records": names})
            except ValueError:
                raise ValueError(f"no mode could be identified from the records ({exc}); is the "
                                 "tool-tip displacement moving at all beyond the sensor resolution?") from exc
        model = mfit.model
        warnings.append(f"time-domain fit found no mode ({exc}); the H1 fit is reported")
    if tfit is not None:
        model = tfit.model
        if not tfit.success:
            warnings.append(f"time-domain fit: {tfit.message}")
    if artefacts is not None:
        warnings += artefact_warnings(artefacts, names, fs)
    return model, mfit, tfit, artefacts


def _excitation(model, records, signals, harmonics, fs, durations, noise_var, measured_axes, n_trials, rng,
                warnings):
    """Whether the records excite the model enough for the displacement sensor to resolve it, per
    axis: the detectability of the model over the longest record (:func:`detectability`), and the
    same criterion on the records themselves. Returns the detectability, the verdict per axis, and
    the warning of each measured axis found short (the caller adds it, each beside that axis's fit
    error)."""
    # detectability over the longest record: the records are identified together, so the model is
    # at least as well informed as by its best-excited record alone (several records of one pose
    # are never less trustworthy than one of them)
    resolution = None
    for r, s in zip(records, signals):
        if s.motion_quantity != "displacement":
            # a displacement sensor's resolution says nothing of velocity or acceleration channels
            # (session 32: the synthetic records declare the paper's tracker beside accelerometers)
            continue
        res = r.sensors.displacement_resolution_m if r.sensors is not None else None
        res = res if res is not None else s.quantisation_step_m
        if res is not None:
            resolution = max(resolution or 0.0, float(res))
    det = detectability(model, float(durations.max()), fs, resolution, noise_var, axes=measured_axes,
                        n_trials=n_trials, rng=rng)
    # the same criterion on the records themselves: the model's response to the measured
    # background force (harmonics, mean and trend removed; run in on the time-reversed force) must
    # also reach the resolution. A model fitted to an under-excited record is itself unreliable,
    # so the simulated (Monte-Carlo) verdict alone could be fooled by it. Best record, as above.
    p2v_meas = np.zeros(3)
    for s, h in zip(signals, harmonics) if resolution is not None else ():
        ok = s.force_axes
        f_bg = np.zeros_like(s.force_N)
        hz = h.freq_hz if h is not None else np.zeros(0)
        f_bg[ok] = s.force_N[ok] - fit_harmonic_signal(s.force_N[ok], fs, hz)
        x = simulate_response(model, np.hstack([f_bg[:, ::-1], f_bg]), fs)[:, s.n_samples :]
        p2v_meas = np.maximum(p2v_meas, np.ptp(x, axis=1))
    sufficient = np.array(det.sufficient)
    for a in range(3):
        if a not in measured_axes:  # no motion recorded along it: nothing shows the excitation
            sufficient[a] = False
            warnings.append(f"{AXES[a]}: no tool-tip motion along {AXES[a]} in the records; "
                            f"the model says nothing reliable along {AXES[a]}")
    if resolution is not None:
        for a in measured_axes:
            if p2v_meas[a] < resolution:
                sufficient[a] = False
    if resolution is None:
        displacement = any(sig.motion_quantity == "displacement" for sig in signals)
        warnings.append("no displacement resolution known; detectability not assessed" if displacement else
                        "no displacement recorded (velocity or acceleration): the detectability by a displacement "
                        "sensor's resolution is not assessed")
    short = {}
    for a in measured_axes:
        if det.assessed[a] and not det.sufficient[a]:
            short[a] = (f"{AXES[a]}: background force variance {noise_var[a]:.1f} N^2 is below the "
                        f"{det.min_variance_N2[a]:.5g} N^2 the displacement sensor can resolve in "
                        f"{durations.max():.2f} s: the {AXES[a]} modes are not reliably identified")
        elif resolution is not None and p2v_meas[a] < resolution:
            short[a] = (f"{AXES[a]}: the background force moves the tool by only "
                        f"{1e6 * p2v_meas[a]:.1f} um peak to valley"
                        f"{' in the best-excited record' if len(records) > 1 else ''}, below the "
                        f"{1e6 * resolution:.1f} um the displacement sensor can resolve: the {AXES[a]} modes are not "
                        "reliably identified")
    return det, sufficient, short
