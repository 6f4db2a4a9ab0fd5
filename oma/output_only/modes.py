"""Output-only modes of milling response records: harmonics out, SSI-cov, order from the data.

Chain (robomill issue 14, item 1): per record, the spindle and tooth lines are located from the
record's speed and teeth and regressed out (:mod:`oma.output_only.harmonics`); the residual is
low-pass filtered and decimated to the analysis band, each channel scaled to unit variance, and
cut into ``n_segments`` contiguous segments whose output correlations are computed. Their mean is
the correlation of the data; SSI-cov poles at every even order, stability and clustering
(:mod:`oma.output_only.ssi`) give the modes. A cluster that sits on a milling line with almost no
damping is a harmonic the regression left behind (a wandering spindle), not a mode: it is
reported as such. SSI runs on two spectral tilts of the residual (acceleration and displacement)
and each band keeps the view that resolves more modes. The Whittle maximum-likelihood refinement
(:mod:`oma.output_only.ml`) gives the standard errors of frequency, damping and direction from its
information; SSI's delete-one-segment jackknife (:mod:`oma.output_only.uncertainty`) those of the
modes it does not fit, and the directions' errors while the reported directions are SSI's.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
from scipy import signal as sps
from scipy import stats

from .._arrays import readonly as _ro
from .._linalg import single_threaded_blas
from ..signals import integrate_frequency_domain
from .coverage import SEGMENT_S, unexplained_peaks
from .harmonics import HARMONIC_MAX_DAMPING, HARMONIC_TOLERANCE, at_milling_line, remove_response_harmonics
from .ml import LEFT_DAMPING, band_groups, refine_modes_ml
from .ssi import (StabilisedModes, mac, match_modes, real_direction, same_mode, segment_correlations, select_modes,
                  ssi_poles)
from .uncertainty import jackknife, segment_bounds, t_interval

__all__ = ["OutputOnlyModes", "output_only_modes", "real_direction"]

#: See ``ml_refine`` in :func:`output_only_modes`.
ML_MAX_SHIFT = 2.0
#: Starting damping ratio of a mode seeded from a residual spectral peak (``seed_peaks``): the
#: middle of robot modes' 2-10 % on a log scale; the refinement fits it. A peak narrower than that
#: starts at its own half-power width, ``width / (2 f)``, at least :data:`SEED_MIN_DAMPING`
#: (session 20: on real Hurco files tones at 277 and 543 Hz seeded at 4.5 % made groups 150-290 Hz
#: wide, 3-5 s of CPU, and refined to 0.1-0.3 % anyway). Not the other way: the 17 Hz Z mode under
#: a tracker's rounding (5 %, a test) measured 7 % wide and, started there, refined to 7.2 %
#: outside its interval (from 4.5 %: 6.1 %, inside).
SEED_DAMPING = 0.045
#: A residual peak is seeded when it stands this many times over its channel's median (a weaker
#: one is only named, by ``identify``'s check at ``coverage.PEAK_RATIO``): on session 16's audit
#: a 26-times peak under 15 um rounding (a harmonic of the rounding, no mode) was admitted by the
#: evidence gate as a false 19.9 Hz mode; the true modes' peaks stood 56-1419 times (the paper-like
#: cell's, any quantity) and the missed 17 Hz Z mode 4662 times. Twice the false one: a judgement
#: from one case.
SEED_PEAK_RATIO = 50.0
#: A seeded mode refined to less damping than this is a tone, not a robot mode (2-10 %).
SEED_MIN_DAMPING = 0.005
#: Modes of different SSI views (``ssi_derivatives``) whose bands ``f (1 +- w zeta)`` overlap
#: compete as one group (:func:`_choose_views`).
VIEW_GROUP_WIDTH = 3.0


@dataclass(frozen=True)
class OutputOnlyModes:
    """Modes identified from response signals alone (no scale).

    Attributes
    ----------
    freq_hz, damping_ratio : ndarray, shape (n_modes,)
    freq_se_hz, damping_se : ndarray, shape (n_modes,)
        Jackknife standard errors.
    freq_interval_hz, damping_interval : ndarray, shape (n_modes, 2)
        ``level`` intervals (Student's t, ``n_segments - 1`` degrees of freedom).
    directions : ndarray, shape (n_modes, 3)
        Real unit directions in the machine frame (zero on axes not recorded).
    shapes : ndarray of complex, shape (3, n_modes)
        Complex shapes in the signal's unit (zero rows for axes not recorded).
    support : ndarray, shape (n_modes,)
        Fraction of model orders with a stable pole in the mode's cluster (0 for a mode the
        refinement's residual scan added: no SSI cluster).
    harmonics : tuple of ResponseHarmonics
        One per record.
    direction_se_rad : ndarray, shape (n_modes,)
        Jackknife spread of the direction, rad (angle from the full-record direction).
    rejected_hz : ndarray
        Stable clusters taken for milling lines, Hz.
    band_hz : (float, float)
    n_segments : int
    level : float
    warnings : tuple of str
    input_level, input_level_log_se : ndarray, shape (n_modes,)
        The level of each mode's white input from the refinement (NaN where it did not fit the
        mode): ``P_r`` with the mode's displacement spectrum ``u_r u_r^T P_r / |1 - (f/f_r)^2 + 2 i
        zeta_r f/f_r|^2`` (two-sided, m^2/Hz), i.e. ``E|u_r . F|^2 / k_r^2`` per Hz, and the
        standard error of its logarithm (the refinement's information). With a stiffness,
        ``P_r k_r^2`` is the background force's power spectral density along ``u_r``
        (:mod:`oma.output_only.background`).
    half_freq_hz : ndarray, shape (n_modes, 2)
        Each refined mode's frequency refitted on the first and on the second half of the records
        (``drift_check`` of :func:`output_only_modes`; NaN where not refined): a difference beyond
        their noise says the mode drifted during the cut (:mod:`oma.output_only.identify`).
    complex_test : ndarray, shape (n_modes, 4)
        Per refined mode (``complex_check`` of :func:`output_only_modes`; NaN where not refined):
        the score statistic of complex directions against the real ones fitted, its degrees of
        freedom (chi-squared where the mode is real), the complexity of the direction one step
        towards complex ones gives (0 real, 1 circular), and 1 where the frequency and damping come
        from the group refitted with complex directions, else 0
        (:func:`oma.output_only._ml_inference._complex_directions`).
    """

    freq_hz: np.ndarray
    damping_ratio: np.ndarray
    freq_se_hz: np.ndarray
    damping_se: np.ndarray
    freq_interval_hz: np.ndarray
    damping_interval: np.ndarray
    directions: np.ndarray
    shapes: np.ndarray = field(repr=False)
    support: np.ndarray = field(repr=False)
    harmonics: tuple = field(repr=False)
    direction_se_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rejected_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    band_hz: tuple = (0.0, 0.0)
    n_segments: int = 0
    level: float = 0.95
    warnings: tuple = ()
    input_level: np.ndarray | None = None
    input_level_log_se: np.ndarray | None = None
    half_freq_hz: np.ndarray | None = None
    complex_test: np.ndarray | None = None

    def __post_init__(self):
        for name in ("input_level", "input_level_log_se"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(self.freq_hz.shape, np.nan))
        for name, width in (("half_freq_hz", 2), ("complex_test", 4)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full((self.freq_hz.size, width), np.nan))
        for name in ("freq_hz", "damping_ratio", "freq_se_hz", "damping_se", "freq_interval_hz",
                     "damping_interval", "directions", "support", "rejected_hz", "direction_se_rad",
                     "input_level", "input_level_log_se", "half_freq_hz", "complex_test"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "shapes", _ro(self.shapes, complex))
        object.__setattr__(self, "harmonics", tuple(self.harmonics))
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def n_modes(self) -> int:
        return int(self.freq_hz.size)

    def plot(self, ax=None, **kwargs):
        """Damping against frequency with intervals and the milling lines
        (:func:`oma.output_only.plots.plot_output_only_modes`)."""
        from .plots import plot_output_only_modes

        return plot_output_only_modes(self, ax=ax, **kwargs)

    def to_dict(self) -> dict[str, Any]:
        return {
            "modes": [
                {"natural_frequency_hz": float(f), "damping_ratio": float(z), "direction": [float(v) for v in u],
                 "frequency_interval_hz": [float(v) for v in fi], "damping_interval": [float(v) for v in zi],
                 "frequency_standard_error_hz": float(fs), "damping_standard_error": float(zs),
                 "direction_standard_error_deg": float(np.degrees(d)), "support": float(s),
                 "half_record_frequency_hz": [float(v) for v in h],
                 "complex_direction_test": {"statistic": float(c[0]), "degrees_of_freedom": float(c[1]),
                                            "complexity": float(c[2]), "complex_fit": bool(c[3] == 1.0)}}
                for f, z, u, fi, zi, fs, zs, s, d, h, c in zip(self.freq_hz, self.damping_ratio, self.directions,
                                                               self.freq_interval_hz, self.damping_interval,
                                                               self.freq_se_hz, self.damping_se, self.support,
                                                               self.direction_se_rad, self.half_freq_hz,
                                                               self.complex_test)
            ],
            "interval_level": self.level,
            "band_hz": [float(b) for b in self.band_hz],
            "harmonics": [h.to_dict() for h in self.harmonics],
            "rejected_as_harmonics_hz": [float(f) for f in self.rejected_hz],
        }


def output_only_modes(signals, *args, **kwargs) -> "OutputOnlyModes":
    with single_threaded_blas():
        return _output_only_modes(signals, *args, **kwargs)


def _output_only_modes(signals, sample_rate_hz: float, spindle_rpm, teeth, *, band_hz=(4.0, 100.0),
                       band_ratio: float | None = None, cycles: float = 2.0, lag_s: float | None = 0.12,
                       max_order: int = 60, n_segments: int = 10, level: float = 0.95, refine_harmonics: bool = True,
                       integrate: int = 0, fdd_directions: bool = False, alias_up_to: float = 0.5,
                       ml_refine: bool = True, ml_directions: bool = True, derivative: int = 2,
                       ssi_derivatives: tuple | None = (2, 0), ml_options: dict | None = None,
                       ml_evidence: bool = True, uncertainty: str = "information",
                       seed_peaks: bool = True, drift_check: bool = True,
                       complex_check: bool = True) -> OutputOnlyModes:
    """Modes, with intervals, from one or more response records of one pose.

    Parameters
    ----------
    signals : sequence of array_like, each shape (3, n_samples)
        Response along X, Y, Z (NaN rows for axes not recorded; the same axes in every record),
        one quantity (displacement, velocity or acceleration) throughout.
    sample_rate_hz : float
    spindle_rpm : sequence of float or None
        Nominal spindle speed of each record (None: no milling lines removed).
    teeth : sequence of int
    band_hz : (float, float)
        Analysis band; the signals are decimated to about 2.5 times its upper end.
    band_ratio : float, optional
        None (default): the band is analysed in one piece. Given: in sub-bands ``[lo, lo r)``, ``[lo r, lo r^2)`` ... (the last up to
        the band's top), each filtered and decimated to itself (with a 25 % margin on both sides)
        and only its own modes kept, so that a weak low mode is not drowned in a strong high one.
        Experimental: on the benchmark records its low sub-band lost modes in 6 records of 10.
    cycles : float
        With ``lag_s=None``: the correlation lags of a (sub-)band span this many periods of its
        lowest frequency.
    lag_s : float, optional
        Time span of the correlation lags (block rows ``= lag_s * fs_decimated``); 0.12 s was the
        best of 0.06-0.4 s on the benchmark records (modes of 10-25 Hz).
    max_order : int
        Largest SSI model order.
    n_segments : int
        Segments of the jackknife (over all records together).
    level : float
        Coverage of the intervals.
    refine_harmonics : bool
        Refine each spindle frequency from the response.
    integrate : {0, 1, 2}
        Integrate the residual this many times before SSI (frequency domain, high-pass at the
        band's lower end); SSI then runs on that one view (``ssi_derivatives`` is ignored) and
        the refinement still on the residual as recorded.
    alias_up_to : float
        Spindle multiples up to this many times the sampling rate are removed where they fold
        into the band (:func:`remove_response_harmonics`); 0.5 (default): none.
    fdd_directions : bool
        Directions from the singular vectors of the output spectral matrix over each mode's
        half-power band (frequency-domain decomposition, Brincker, Zhang & Andersen 2001), the
        one most like the SSI shape; SSI tilts the directions of close modes (10.0 / 10.5 Hz)
        by up to 20 degrees, which the scaling turns into stiffness errors of 100 %.
    ml_refine : bool
        Refine frequency, damping and direction of the SSI modes (number and rough place fixed)
        by maximising the Whittle likelihood of the output periodogram matrix around them
        (:func:`oma.output_only.ml.refine_modes_ml`), with standard errors from its information
        (``uncertainty``), so the intervals belong to the refined estimate. A refined frequency
        more than :data:`ML_MAX_SHIFT` SSI standard errors from SSI's is taken for a misfit (one
        SSI mode for two true ones) and SSI's values are kept.
    ml_directions : bool
        The refinement's directions for close modes (a group of several fitted jointly, where
        SSI's directions are pinned by little more than the difference of the poles), SSI's for
        the rest and wherever the refinement was not kept. Session 9, 20 records per case: the
        X stiffness of the close pair within 9.1-9.5 % (max) in the tooth, runout and on-mode
        cases (SSI's directions: 15-18 %), 11.7 % in the extra-mode case (24.5 %); with the
        refined directions for every mode (session 8) the extra-mode case's other modes were
        scaled from a mixed pair (Y 13.8 %, the 70 Hz mode 15.7 %). False: SSI's everywhere.
    derivative : {0, 1, 2}
        The signals are displacement, velocity or acceleration (the refinement's spectrum model).
    ssi_derivatives : tuple of int or None
        SSI is run on the residual as each of these derivatives of the displacement (default:
        acceleration and displacement, whatever was recorded) and, per group of overlapping
        bands, the modes of the view that resolves the most of them are kept
        (:func:`_choose_views`). The poles are the same in every view; the spectral tilt
        (``w^4`` between the two) decides which weak modes stand out of SSI's estimation noise
        (a 10.5 Hz mode 23 dB under a 70 Hz mode in the acceleration of its channel is lost in
        acceleration and found in displacement). None: the signals as recorded only.
    ml_options : dict, optional
        Passed to :func:`oma.output_only.ml.refine_modes_ml` (e.g. ``residual_terms``).
    ml_evidence : bool
        With ``ml_refine``: every mode must raise the Whittle likelihood of its band by more
        than the BIC penalty of its parameters (the group refitted without it, both with the
        coherent tail model), else it is dropped with a warning. The refinement also scans each
        group for a mode SSI formed no cluster for and adds it under the same gate (session 13;
        ``ml_options={'add_missing': None}`` turns the scan off).
    seed_peaks : bool
        With ``ml_refine``: residual spectral peaks no SSI mode explains
        (:func:`oma.output_only.coverage.unexplained_peaks` at ``SEED_PEAK_RATIO``, its wider net
        ``base='window'``) are added as
        candidates (damping ``SEED_DAMPING``, or the peak's half-power width where narrower;
        direction the spectral matrix's first singular vector
        at the peak) for the refinement and its evidence gate (session 16).
    drift_check : bool
        With ``ml_refine``: refit each refined group on the first and on the second half of the
        records (``OutputOnlyModes.half_freq_hz``), from the full-record optimum by a few scoring
        steps (session 26: DOMAIN.md's pose drift).
    complex_check : bool
        With ``ml_refine``: test each refined group's real directions against complex ones
        (``OutputOnlyModes.complex_test``; session 27).
    uncertainty : {'information', 'jackknife'}
        Standard errors of the refined modes: from the information at the optimum (default;
        the larger of the inverse Fisher information and the sandwich), or the delete-one-segment
        jackknife of the refinement (rounds 1-2; see :func:`_ml_refine`). Modes the refinement
        did not fit keep SSI's jackknife errors.
    """
    signals = [np.array(s, dtype=float, ndmin=2) for s in signals]
    fs = float(sample_rate_hz)
    axes = ~np.all(np.isnan(signals[0]), axis=1)
    warnings: list[str] = []
    harmonics, raw, residuals = _lines_removed(signals, axes, fs, spindle_rpm, teeth, refine=refine_harmonics,
                                               alias_up_to=alias_up_to, integrate=integrate, highpass_hz=band_hz[0])
    lo, hi = float(band_hz[0]), float(min(band_hz[1], 0.45 * fs))
    lines = np.concatenate([h.freq_hz for h in harmonics]) if harmonics else np.zeros(0)
    views = [residuals] if integrate or not ssi_derivatives else \
        [[_reweight(r, fs, derivative, d, lo) for r in raw] for d in ssi_derivatives]
    modes, rejected, n_seg = _ssi_modes(views, fs, lo, hi, harmonics, lines, band_ratio=band_ratio, cycles=cycles,
                                        lag_s=lag_s, max_order=max_order, n_segments=n_segments)
    if n_seg < 3:
        warnings.append("record too short for the segment jackknife: no intervals")
    if ml_refine and seed_peaks:
        modes = _with_seeds(modes, raw, fs, (lo, hi), lines, harmonics, warnings)
    if fdd_directions and modes.n:
        modes = replace(modes, shapes=_fdd_shapes(raw, fs, modes.freq_hz, modes.damping, modes.shapes))
    if ml_refine and modes.n:
        options = {"band_hz": (lo, hi), "halves": drift_check, "complex_check": complex_check, **(ml_options or {})}
        modes = _refined(modes, raw, fs, lines, derivative, n_segments, options,
                         evidence=ml_evidence, directions=ml_directions, uncertainty=uncertainty, warnings=warnings)
    return _reported(modes, axes, lines, (lo, hi), harmonics, rejected, n_seg, level, warnings)


@dataclass(frozen=True)
class _Modes:
    """The modes in hand at one stage of :func:`output_only_modes`, one entry per mode: SSI's values
    and jackknife errors, replaced by the refinement's where it is kept."""

    freq_hz: np.ndarray
    damping: np.ndarray
    shapes: np.ndarray                  # (n_channels, n), in the signal's unit
    support: np.ndarray                 # SSI's; 0 for a seeded peak or a mode the refinement's scan added
    freq_se: np.ndarray
    damping_se: np.ndarray
    direction_se: np.ndarray
    seeded: np.ndarray                  # a residual peak, no SSI cluster
    refined: np.ndarray | None = None           # the refinement's values kept (None: none)
    from_information: np.ndarray | None = None  # errors from the refinement's information (None: none)
    input_level: np.ndarray | None = None       # the refinement's background level at the mode (None: NaN)
    input_level_se: np.ndarray | None = None    # ... and its log error
    half_freq: np.ndarray | None = None         # (2, n): refitted on the records' halves (None: NaN)
    complex_test: np.ndarray | None = None      # (4, n): the test of complex directions (None: NaN)

    def __post_init__(self):
        n = self.n
        for name, fill in (("refined", False), ("from_information", False), ("input_level", np.nan),
                           ("input_level_se", np.nan)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(n, fill))
        for name, rows in (("half_freq", 2), ("complex_test", 4)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full((rows, n), np.nan))

    @property
    def n(self) -> int:
        return self.freq_hz.size

    @classmethod
    def without_errors(cls, freq_hz, damping, shapes, *, seeded: bool) -> "_Modes":
        """Modes with no SSI cluster and no SSI error (seeded peaks, or modes the scan added)."""
        n = len(freq_hz)
        nan = np.full(n, np.nan)
        return cls(np.asarray(freq_hz, dtype=float), np.asarray(damping, dtype=float), shapes, np.zeros(n),
                   nan, nan.copy(), nan.copy(), np.full(n, seeded))

    def take(self, idx) -> "_Modes":
        return _Modes(**{k: v[:, idx] if k in _COLUMNS else v[idx] for k, v in vars(self).items()})

    def plus(self, other: "_Modes") -> "_Modes":
        return _Modes(**{k: np.column_stack([v, getattr(other, k)]) if k in _COLUMNS else
                         np.append(v, getattr(other, k)) for k, v in vars(self).items()})


#: The fields of :class:`_Modes` that hold a column per mode.
_COLUMNS = ("shapes", "half_freq", "complex_test")


def _lines_removed(signals, axes, fs, spindle_rpm, teeth, *, refine, alias_up_to, integrate, highpass_hz):
    """Per record the milling lines found and regressed out of the recorded axes
    (:func:`remove_response_harmonics`): the lines, the residuals, and the residuals SSI reads
    (integrated ``integrate`` times)."""
    harmonics, raw, residuals = [], [], []
    for s, rpm, z in zip(signals, spindle_rpm, teeth):
        rh = remove_response_harmonics(s[axes], fs, rpm, int(z), refine=refine, alias_up_to=alias_up_to)
        harmonics.append(rh)
        raw.append(rh.residual)
        residuals.append(integrate_frequency_domain(rh.residual, fs, order=integrate, highpass_hz=highpass_hz)
                         if integrate else rh.residual)
    return harmonics, raw, residuals


def _ssi_modes(views, fs, lo, hi, harmonics, lines, *, band_ratio, cycles, lag_s, max_order, n_segments):
    """SSI's modes over ``[lo, hi]`` from each view of the residuals, with their jackknife errors:
    the clusters on milling lines set aside (their frequencies returned), per group of overlapping
    bands the view that resolves the most (:func:`_choose_views`), duplicates dropped. Returns the
    modes, the rejected frequencies and the number of segments."""
    edges = [lo]
    while band_ratio is not None and edges[-1] * band_ratio < hi / 1.2:
        edges.append(edges[-1] * band_ratio)
    edges.append(hi)
    runs = [_band_modes(v, fs, edges[k], edges[k + 1], first=k == 0, last=k == len(edges) - 2,
                        cycles=cycles, lag_s=lag_s, max_order=max_order,
                        n_segments=n_segments, jackknife_now=len(views) == 1)
            for v in views for k in range(len(edges) - 1)]
    parts = [m for m, _, _ in runs]
    f_all = np.concatenate([m.freq_hz for m in parts])
    sel = StabilisedModes(f_all, np.concatenate([m.damping for m in parts]), np.hstack([m.shapes for m in parts]),
                          np.concatenate([m.support for m in parts]), tuple(range(f_all.size)))
    order_ = np.argsort(f_all)      # StabilisedModes sorts by frequency: so must the errors
    fse_all, zse_all, use_all = (np.concatenate([getattr(m, a) for m in parts])[order_]
                                 for a in ("freq_se", "damping_se", "direction_se"))
    view_all = np.concatenate([np.full(m.n, i // (len(edges) - 1)) for i, m in enumerate(parts)])[order_]
    n_seg = min(n for _, n, _ in runs)
    keep = ~at_milling_line(sel.freq_hz, sel.damping_ratio, lines)
    for h in harmonics:
        # a tracked line (the speed varied by ``speed_variation``) leaves a remainder as wide as its
        # wander: a pole within that of a line and damped less than a few times it is the line's
        if h.tracked and h.freq_hz.size and sel.n_modes:
            near = np.min(np.abs(h.freq_hz[None, :] / sel.freq_hz[:, None] - 1.0), axis=1)
            keep &= ~((near < max(HARMONIC_TOLERANCE, h.speed_variation))
                      & (sel.damping_ratio < max(HARMONIC_MAX_DAMPING, 4.0 * h.speed_variation)))
    harmonic = ~keep
    if len(views) > 1:
        keep &= _choose_views(sel.freq_hz, sel.damping_ratio, sel.support, view_all, keep)
        # the SSI jackknife of the kept modes only, each in its own run
        part_all = np.concatenate([np.full(m.n, i) for i, m in enumerate(parts)])[order_]
        for i in np.unique(part_all[keep]):
            ks = np.flatnonzero(keep & (part_all == i))
            fse_all[ks], zse_all[ks], use_all[ks] = _ssi_jackknife(runs[i][2], sel.freq_hz[ks], sel.shapes[:, ks])
    # duplicates: two clusters of one mode (same frequency within 2 %, MAC > 0.9): keep the better supported
    order = np.argsort(-sel.support)
    for a_i, a in enumerate(order):
        if not keep[a]:
            continue
        for b in order[a_i + 1:]:
            if keep[b] and same_mode(sel.freq_hz[a], sel.shapes[:, a], sel.freq_hz[b], sel.shapes[:, b:b + 1])[0]:
                keep[b] = False
    modes = _Modes(sel.freq_hz[keep], sel.damping_ratio[keep], sel.shapes[:, keep], sel.support[keep],
                   fse_all[keep], zse_all[keep], use_all[keep], np.zeros(int(np.sum(keep)), dtype=bool))
    return modes, sel.freq_hz[harmonic], n_seg


def _with_seeds(modes: _Modes, raw, fs, band, lines, harmonics, warnings) -> _Modes:
    """``modes`` and, in order of frequency, the residual spectral peaks no mode explains as
    candidates for the refinement (``seed_peaks`` of :func:`output_only_modes`).

    On a short record a clean mode can form no SSI cluster (session 16: a 17 Hz Z mode 4662 times
    its channel's median in a 5 s record); the refinement's evidence gate keeps a seed only if the
    spectrum supports it."""
    wander = max((h.speed_variation for h in harmonics), default=0.0)
    peaks = unexplained_peaks(raw, fs, band, modes.freq_hz, modes.damping, lines, line_relative_halfwidth=wander,
                              ratio=SEED_PEAK_RATIO, base="window")
    widths = {}
    for p in peaks:   # one seed per frequency (channels may share a peak): its widest measure
        key = round(p.freq_hz, 6)
        widths[key] = float(np.fmax(widths.get(key, np.nan), p.half_power_width_hz))
    seeds = sorted(widths)
    if not seeds:
        return modes
    damping = [float(np.clip(widths[f] / (2.0 * f), SEED_MIN_DAMPING, SEED_DAMPING)) if np.isfinite(widths[f])
               else SEED_DAMPING for f in seeds]
    warnings.extend(f"a residual spectral peak at {f:.2f} Hz that no SSI mode explains was tried as a mode"
                    for f in seeds)
    both = modes.plus(_Modes.without_errors(seeds, damping, _peak_shapes(raw, fs, seeds), seeded=True))
    return both.take(np.argsort(both.freq_hz, kind="stable"))


def _refined(modes: _Modes, raw, fs, lines, derivative, n_segments, options, *, evidence, directions,
             uncertainty, warnings) -> _Modes:
    """``modes`` after the Whittle-ML refinement (``ml_refine``, ``ml_evidence``, ``ml_directions``
    of :func:`output_only_modes`): the modes its evidence gate drops removed, those its scan adds
    appended, the refined values and errors kept where the fit is not a misfit."""
    f_hat, f_se = modes.freq_hz, modes.freq_se
    ev = {} if evidence else None
    out = _ml_refine(raw, fs, f_hat, modes.damping, modes.shapes, lines, derivative, n_segments, evidence=ev,
                     uncertainty=uncertainty, **options)
    if options.get("input_slope", True) and _n_moved(out, f_hat, f_se):
        # the sloped input level trades with a close pair's frequencies: where it moves a mode
        # off SSI's (a misfit, below), the flat input is tried before SSI's values are kept
        # (session 15: 1 of 10 records' Z mode beside X, which then lost its background scale),
        # in the groups holding such a mode only (the others' fits do not depend on it)
        redo = np.isin(out.group[:f_hat.size], out.group[:f_hat.size][_moved(out, f_hat, f_se)])
        ev_flat = {} if evidence else None
        flat = _ml_refine(raw, fs, f_hat, modes.damping, modes.shapes, lines, derivative, n_segments,
                          evidence=ev_flat, uncertainty=uncertainty, **{**options, "input_slope": False, "fit_only": redo})
        if _n_moved(flat, f_hat, f_se) < _n_moved(out, f_hat, f_se):
            out, ev = _merged(out, ev, flat, ev_flat, redo)
            at = ", ".join(f"{f:.2f}" for f in f_hat[redo])
            warnings.append(f"the refinement with a sloped background level moved a mode off SSI's frequency; "
                            f"the flat level was used for the modes at {at} Hz (a white background force "
                            "assumed there)")
    n_new = out.freq_hz.size - modes.n
    if n_new:
        # modes the refinement's residual scan added (no SSI cluster): their "SSI" values are the
        # refinement's, with no SSI error (so never taken for "moved"; no interval unless the
        # refinement's information gives one)
        new = slice(modes.n, None)
        modes = modes.plus(_Modes.without_errors(out.freq_hz[new], out.damping[new], out.shapes[:, new], seeded=False))
        for k in range(modes.n - n_new, modes.n):
            gain = f" (likelihood gain {ev[k][0]:.1f} against penalty {ev[k][1]:.1f})" if ev else ""
            warnings.append(f"mode at {modes.freq_hz[k]:.2f} Hz found by the refinement's scan of what its group's "
                            f"model left unexplained, not by SSI{gain}")
    # a mode whose likelihood gain is under its BIC penalty is not supported by the data, one the
    # fit moved onto another's peak is a second candidate for it, and one the fit took out of its
    # band is not a mode at its pole: the refinement dropped it and refitted its group without it
    weak = ev["dropped"] if ev else np.zeros(modes.n, dtype=bool)
    for k in np.flatnonzero(weak):
        what = "stable SSI cluster" if modes.support[k] > 0 else "seeded peak"
        why = ("the refinement moved it out of its band onto another mode's peak (a second candidate for that "
               "mode)" if ev["duplicate"][k] else
               "the refinement's fit of its group took it out of its band or to a damping over "
               f"{100 * LEFT_DAMPING:.0f} % (what the spectrum holds there is background, not a mode at this pole), "
               "and the group refitted without it keeps its other modes in their bands"
               if ev["left_band"][k] else
               f"the spectrum's likelihood gains {ev[k][0]:.1f} with it, under its penalty {ev[k][1]:.1f}")
        warnings.append(f"{what} at {modes.freq_hz[k]:.2f} Hz not kept: {why}")
    modes, out = modes.take(~weak), out.take(~weak)
    # a refinement that moves a frequency by more than ML_MAX_SHIFT SSI standard errors is taken
    # for a misfit (e.g. one SSI mode for two true ones): SSI's values are kept; so are they where a
    # group's fit failed
    fitted = out.fitted & ~_moved(out, modes.freq_hz, modes.freq_se)
    f_se, z_se, u_se, shapes = modes.freq_se, modes.damping_se, modes.direction_se, modes.shapes
    from_information = np.zeros(modes.n, dtype=bool)
    if out.se is not None:
        with_se = fitted & np.isfinite(out.se[0]) & np.isfinite(out.se[1])
        f_se, z_se = (np.where(with_se, new, old) for new, old in zip(out.se[:2], (f_se, z_se)))
        if uncertainty == "information":
            from_information = with_se
    if directions:
        # only for close modes (a group of several, where SSI's directions are pinned by little more
        # than the difference of their poles) and only where the refinement is kept (a group it
        # moved off SSI's frequencies keeps SSI's directions too)
        close = np.zeros(modes.n, dtype=bool)
        widths = {k: v for k, v in options.items() if k in ("half_width", "min_half_width_hz")}
        for g in band_groups(modes.freq_hz, modes.damping, **widths):
            close[g] = len(g) > 1
        use = fitted & close
        shapes = np.where(use[None, :], out.shapes, shapes)
        if out.se is not None:
            u_se = np.where(use & np.isfinite(out.se[2]) & (out.se[2] > 0), out.se[2], u_se)
    return replace(modes, freq_hz=np.where(fitted, out.freq_hz, modes.freq_hz),
                   damping=np.where(fitted, out.damping, modes.damping), shapes=shapes, freq_se=f_se,
                   damping_se=z_se, direction_se=u_se, refined=fitted, from_information=from_information,
                   input_level=np.where(fitted, out.levels[0], np.nan),
                   input_level_se=np.where(fitted, out.levels[1], np.nan),
                   half_freq=None if out.halves is None else np.where(fitted[None, :], out.halves, np.nan),
                   # of every group's fit, also where SSI's values are kept (a real-direction fit
                   # that moves a mode off SSI's pole may be one the phase defeats: session 27, a
                   # whirling pair's lower mode)
                   complex_test=None if out.complex_test is None else
                   np.where(out.fitted[None, :], out.complex_test, np.nan))


def _reported(modes: _Modes, axes, lines, band, harmonics, rejected, n_seg, level, warnings) -> OutputOnlyModes:
    """The modes reported, in order of frequency, with their intervals: tones, seeds the
    refinement could not fit and poles on the band's edge set aside with a warning each."""
    lo, hi = band
    f_hat, z_hat = modes.freq_hz, modes.damping
    # a pole whose half-power band crosses the analysed band's edge is fitted on part of its peak
    # only: the background's slope at the edge reads as a heavily damped mode (session 12: 4.1-4.3 Hz
    # at 13-22 % damping, 2 of 40 records of structures unlike the paper's). Not a mode; said so.
    inside = (f_hat * (1.0 - z_hat) >= lo) & (f_hat * (1.0 + z_hat) <= hi)
    # a seeded peak the refinement turned into a tone on a milling line (a real Hurco file: a peak
    # 3 Hz off a 266.5 Hz tooth line went onto it at 0 % damping) is the line's, not a mode; so is
    # an SSI mode the refinement took onto a line (SSI's own rule for its poles, :func:`at_milling_line`:
    # session 22, a real Hurco file's 264.7 Hz mode finished at 265.9 Hz and 0.08 %, beside the
    # 266.7 Hz tooth line, where SSI's own poles had been rejected as the line's)
    tone = modes.refined & (at_milling_line(f_hat, z_hat, lines) | (modes.seeded & (z_hat < SEED_MIN_DAMPING)))
    for k in np.flatnonzero(tone):
        what = "seeded peak" if modes.seeded[k] else "mode"
        warnings.append(f"{what} refined to {f_hat[k]:.2f} Hz at {100 * z_hat[k]:.2f} % damping: a tone or a "
                        "milling line's remainder, not kept as a mode")
    # a seed the refinement could not fit has only its starting values (4.5 %, no error): no mode
    unfitted_seed = modes.seeded & ~modes.refined
    for k in np.flatnonzero(unfitted_seed):
        warnings.append(f"seeded peak at {f_hat[k]:.2f} Hz not kept: the refinement could not fit it")
    for k in np.flatnonzero(~inside):
        warnings.append(f"pole at {f_hat[k]:.2f} Hz ({100 * z_hat[k]:.0f} % damping) not reported as a mode: its "
                        f"half-power band crosses the edge of the analysed band {lo:g}-{hi:g} Hz (widen the band "
                        "to identify it)")
    kept = np.flatnonzero(inside & ~(tone | unfitted_seed))
    m = modes.take(kept[np.argsort(f_hat[kept], kind="stable")])  # added modes come last: in order of frequency
    full_shapes = np.zeros((3, m.n), dtype=complex)
    full_shapes[axes] = m.shapes
    directions = np.array([real_direction(full_shapes[:, k]) for k in range(m.n)]).reshape(-1, 3)
    # SSI's jackknife: Student t with n_seg - 1 degrees of freedom; the refinement's information:
    # normal, the damping's interval symmetric in its logarithm (the parameter it is fitted in)
    f_iv, z_iv = t_interval(m.freq_hz, m.freq_se, n_seg, level), t_interval(m.damping, m.damping_se, n_seg, level)
    if np.any(m.from_information):
        zq = stats.norm.ppf(0.5 + 0.5 * level)
        k = m.from_information
        f_iv[k] = np.column_stack([m.freq_hz[k] - zq * m.freq_se[k], m.freq_hz[k] + zq * m.freq_se[k]])
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero damping (a line, untrusted) has none
            log_se = m.damping_se[k] / m.damping[k]
        z_iv[k] = np.column_stack([m.damping[k] * np.exp(-zq * log_se), m.damping[k] * np.exp(zq * log_se)])
    return OutputOnlyModes(
        freq_hz=m.freq_hz, damping_ratio=m.damping, freq_se_hz=m.freq_se, damping_se=m.damping_se,
        freq_interval_hz=f_iv, damping_interval=z_iv,
        directions=directions, shapes=full_shapes, support=m.support, harmonics=tuple(harmonics),
        direction_se_rad=m.direction_se, rejected_hz=rejected, band_hz=band, n_segments=n_seg, level=level,
        warnings=tuple(warnings), input_level=m.input_level, input_level_log_se=m.input_level_se,
        half_freq_hz=m.half_freq.T, complex_test=m.complex_test.T,
    )


def _choose_views(freq_hz, damping, support, view, valid, *, width: float = VIEW_GROUP_WIDTH):
    """Per group of modes whose bands ``f (1 +- width zeta)`` overlap (over all views), keep the
    modes of the one view that resolves the most of them (ties: the larger summed support).

    Each view is a self-consistent SSI model; the spectral tilt decides which weak modes stand
    out of its estimation noise, so the view with more modes in a band has seen one the other
    lost, while mixing clusters of different views would count one mode twice (close modes are
    tilted differently in each view, so a per-pair MAC test misses such duplicates)."""
    out = np.zeros(freq_hz.size, dtype=bool)
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return out
    lo = freq_hz * (1 - width * damping)
    hi = freq_hz * (1 + width * damping)
    order = idx[np.argsort(lo[idx])]
    groups, cur, cur_hi = [], [order[0]], hi[order[0]]
    for k in order[1:]:
        if lo[k] <= cur_hi:
            cur.append(k)
            cur_hi = max(cur_hi, hi[k])
        else:
            groups.append(cur)
            cur, cur_hi = [k], hi[k]
    groups.append(cur)
    for g in groups:
        g = np.array(g)
        best = max(np.unique(view[g]), key=lambda v: (np.sum(view[g] == v), np.sum(support[g][view[g] == v])))
        out[g[view[g] == best]] = True
    return out


def _reweight(x, fs, from_derivative, to_derivative, highpass_hz):
    """``x`` (a displacement, velocity or acceleration: ``from_derivative`` 0, 1, 2) as the
    ``to_derivative``-th derivative of the displacement: its spectrum times ``(i w)^(to - from)``
    (lines below ``highpass_hz`` and DC zeroed when integrating). The modes' poles and directions
    are the same in every view; only the spectral tilt (``w^4`` between displacement and
    acceleration) changes which modes stand out of SSI's estimation noise."""
    k = int(to_derivative) - int(from_derivative)
    if k == 0:
        return x
    if k < 0:
        return integrate_frequency_domain(x, fs, order=-k, highpass_hz=highpass_hz) if k >= -2 else \
            _reweight(integrate_frequency_domain(x, fs, order=2, highpass_hz=highpass_hz), fs, 0, k + 2, highpass_hz)
    spec = np.fft.rfft(x, axis=-1)
    w = 2 * np.pi * np.fft.rfftfreq(x.shape[-1], 1.0 / fs)
    return np.fft.irfft(spec * (1j * w) ** k, n=x.shape[-1], axis=-1)


class _Refined(NamedTuple):
    """What :func:`_ml_refine` returns, per mode: the starting modes, then those its scan added."""

    freq_hz: np.ndarray
    damping: np.ndarray
    shapes: np.ndarray       # (n_channels, n), in the signal's unit
    fitted: np.ndarray       # the group's fit succeeded
    se: tuple | None         # standard errors of frequency (Hz), damping (ratio), direction (rad)
    levels: tuple            # the background level at the mode and its log error (NaN where not fitted)
    group: np.ndarray        # index of the fitted group
    halves: np.ndarray | None = None  # (2, n): the frequency refitted on the records' first and second halves
    complex_test: np.ndarray | None = None  # (4, n): the test of complex directions

    def take(self, idx) -> "_Refined":
        return _Refined(self.freq_hz[idx], self.damping[idx], self.shapes[:, idx], self.fitted[idx],
                        None if self.se is None else tuple(a[idx] for a in self.se),
                        tuple(a[idx] for a in self.levels), self.group[idx],
                        *(None if a is None else a[:, idx] for a in (self.halves, self.complex_test)))


def _moved(out: "_Refined", f_ssi, f_se) -> np.ndarray:
    """The mask of the SSI modes (shape as ``f_ssi``) whose refinement ``out`` moved their
    frequency by more than :data:`ML_MAX_SHIFT` SSI standard errors."""
    n = f_ssi.size
    shift = np.abs(out.freq_hz[:n] - f_ssi) > ML_MAX_SHIFT * np.where(np.isfinite(f_se), f_se, np.inf)
    return out.fitted[:n] & shift


def _merged(out: "_Refined", ev, redo_out: "_Refined", redo_ev, redo):
    """The refinement ``out`` (``ev`` its evidence or None) with the groups holding a starting mode
    marked ``redo`` taken from ``redo_out`` (``redo_ev``), the refinement of those groups alone:
    the starting modes in their order, then the modes the scans added (``out``'s outside those
    groups, then ``redo_out``'s)."""
    n = redo.size
    src = [(redo_out, redo_ev, k) if redo[k] else (out, ev, k) for k in range(n)]
    src += [(out, ev, k) for k in range(n, out.freq_hz.size) if not redo[out.group[k]]]
    src += [(redo_out, redo_ev, k) for k in range(n, redo_out.freq_hz.size)]

    def pick(get):
        return np.array([get(o)[k] for o, _, k in src])

    ses = None if out.se is None or redo_out.se is None else \
        tuple(pick(lambda o, i=i: o.se[i]) for i in range(len(out.se)))
    merged = _Refined(pick(lambda o: o.freq_hz), pick(lambda o: o.damping),
                      np.column_stack([o.shapes[:, k] for o, _, k in src]), pick(lambda o: o.fitted), ses,
                      tuple(pick(lambda o, i=i: o.levels[i]) for i in range(len(out.levels))), pick(lambda o: o.group),
                      *(None if getattr(out, name) is None or getattr(redo_out, name) is None else
                        np.column_stack([getattr(o, name)[:, k] for o, _, k in src]) for name in ("halves", "complex_test")))
    if ev is None or redo_ev is None:
        return merged, None
    new_ev = {j: e[k] for j, (_, e, k) in enumerate(src) if k in e}
    for key in ("dropped", "duplicate", "left_band", "added"):
        new_ev[key] = np.array([e[key][k] for _, e, k in src], dtype=bool)
    return merged, new_ev


def _n_moved(out, f_ssi, f_se) -> int:
    """How many of the SSI modes a refinement ``out`` moved by more than ``ML_MAX_SHIFT`` SSI
    standard errors (taken for a misfit; the modes its scan added are not counted)."""
    return int(np.sum(_moved(out, f_ssi, f_se)))


def _ml_refine(residuals, fs, f_hat, z_hat, shapes, lines, derivative, n_segments, evidence=None,
               uncertainty: str = "information", **options):
    """Whittle-ML refinement (:func:`oma.output_only.ml.refine_modes_ml`) in unit-variance channels,
    with its standard errors (:class:`_Refined`).

    ``uncertainty``: ``'information'`` (default), the larger of the inverse Fisher information and
    the sandwich at the optimum (:func:`oma.output_only._ml_inference._information_se`); ``'jackknife'``, the
    delete-one-segment jackknife of the refinement (the same segments as SSI's, each refitted from
    the full-record optimum), the method of rounds 1-2, kept for comparison (its damping intervals
    of the close pair covered 75-80 %, docs/output_only.md).
    """
    if uncertainty not in ("information", "jackknife"):
        raise ValueError(f"uncertainty must be 'information' or 'jackknife', found {uncertainty!r}")
    ch = np.sqrt(np.mean(np.concatenate([r for r in residuals], axis=1) ** 2, axis=1))
    ch = np.where(ch > 0, ch, 1.0)
    unit = [r / ch[:, None] for r in residuals]
    # real directions in the signal's unit first (rotating a complex shape to real after scaling the
    # channels would weigh its phase by the loudest channel), then in unit-variance channels
    u0 = np.array([real_direction(shapes[:, k]) / ch for k in range(f_hat.size)]).T.reshape(ch.size, -1)
    u0 = u0 / np.maximum(np.linalg.norm(u0, axis=0), np.finfo(float).tiny)
    total = sum(r.shape[1] for r in unit)
    cuts = []
    for i, r in enumerate(unit):
        bounds = segment_bounds(r.shape[1], max(int(round(n_segments * r.shape[1] / total)), 1))
        cuts += [(i, a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    jackknife_cuts = cuts if uncertainty == "jackknife" and len(cuts) >= 3 else None
    f, z, u, fitted, rep, se, input_level, group, *checks = refine_modes_ml(
        unit, fs, f_hat, z_hat, u0, derivative=derivative, lines_hz=lines, segments=jackknife_cuts, evidence=evidence,
        direction_scale=ch, **options)
    levels = (np.where(fitted, input_level, np.nan), np.where(fitted, se[3], np.nan))
    out = np.zeros((shapes.shape[0], f.size), dtype=complex)
    out[:, :f_hat.size] = shapes
    for k in np.flatnonzero(fitted):
        v = u[:, k] * ch
        out[:, k] = v / np.linalg.norm(v) * (np.linalg.norm(shapes[:, k]) if k < f_hat.size else 1.0)
    if uncertainty == "information":
        return _Refined(f, z, out, fitted, (se[0], z * se[1], se[2]), levels, group, *checks)
    if rep is None:
        return _Refined(f, z, out, fitted, None, levels, group, *checks)
    # the jackknife spread of the direction's angle from the full-record one (rad)
    f_se = jackknife(rep[0])[1]
    z_se = jackknife(rep[1])[1]
    a = rep[2]
    cnt = np.isfinite(a).sum(axis=0)
    u_se = np.where(cnt >= 3, np.sqrt((cnt - 1) / np.maximum(cnt, 1) * np.nansum(a ** 2, axis=0)), np.nan)
    return _Refined(f, z, out, fitted, (f_se, z_se, u_se), levels, group, *checks)


def _spectral_matrix(residuals, fs, nperseg: int):
    """Frequencies and the spectral matrix ``G[i, j, f]`` of the residual channels, summed over
    the records (Welch cross spectra, ``nperseg`` samples a segment)."""
    g = 0.0
    for r in residuals:
        f, p = sps.csd(r[:, None, :], r[None, :, :], fs=fs, nperseg=nperseg, axis=-1)
        g = g + p
    return f, g


def _peak_shapes(residuals, fs, freq_hz) -> np.ndarray:
    """First singular vector of the spectral matrix at each frequency (the bin nearest it, the
    segments :mod:`oma.output_only.coverage` finds the peaks with), (n_channels, n)."""
    f, g = _spectral_matrix(residuals, fs, int(min(min(r.shape[1] for r in residuals), round(SEGMENT_S * fs))))
    out = np.empty((residuals[0].shape[0], len(freq_hz)), dtype=complex)
    for k, fr in enumerate(freq_hz):
        u, _, _ = np.linalg.svd(g[:, :, int(np.argmin(np.abs(f - fr)))])
        out[:, k] = u[:, 0]
    return out


def _fdd_shapes(residuals, fs, freq_hz, damping, ssi_shapes, *, segment_s: float = 2.0):
    """Singular vectors of the averaged spectral matrix over each mode's half-power band."""
    nper = int(min(min(r.shape[1] for r in residuals), 2 ** np.round(np.log2(segment_s * fs))))
    l = residuals[0].shape[0]
    f, g = _spectral_matrix(residuals, fs, nper)
    out = np.array(ssi_shapes, dtype=complex)
    for k, (fr, zr) in enumerate(zip(freq_hz, damping)):
        sel = np.abs(f - fr) <= max(zr * fr, f[1] - f[0])
        if not np.any(sel):
            continue
        u, sv, _ = np.linalg.svd(np.mean(g[:, :, sel], axis=-1))
        j = int(np.argmax(mac(u, ssi_shapes[:, k:k + 1])[:, 0]))
        out[:, k] = u[:, j] * np.linalg.norm(ssi_shapes[:, k])
    return out.reshape(l, -1)


def _band_modes(residuals, fs, lo, hi, *, first, last, cycles, lag_s, max_order, n_segments, jackknife_now=True):
    """SSI-cov modes with jackknife errors in ``[lo, hi)`` (see :func:`output_only_modes`), the
    number of segments, and what :func:`_ssi_jackknife` needs (the segment correlations): with
    ``jackknife_now=False`` the errors are NaN, to be computed later for the modes kept."""
    f_pass = (0.8 * lo, min(1.25 * hi, 0.45 * fs))
    q = max(int(np.floor(fs / (4.0 * f_pass[1]))), 1)
    fsd = fs / q
    if first:
        sos = sps.butter(4, f_pass[1], btype="lowpass", fs=fs, output="sos")
    else:
        sos = sps.butter(4, f_pass, btype="bandpass", fs=fs, output="sos")
    dec = [sps.sosfiltfilt(sos, r, axis=-1)[:, ::q] for r in residuals]
    scale = np.sqrt(np.sum([np.sum(d ** 2, axis=1) for d in dec], axis=0) / sum(d.shape[1] for d in dec))
    scale = np.where(scale > 0, scale, 1.0)
    block_rows = int(np.clip(np.ceil(cycles * fsd / max(lo, 1e-3) if lag_s is None else lag_s * fsd), 4, 200))
    n_lag = 2 * block_rows
    total = sum(d.shape[1] for d in dec)
    seg_corr, seg_w = [], []
    for d in dec:
        n_here = max(int(round(n_segments * d.shape[1] / total)), 1)
        bounds = segment_bounds(d.shape[1], n_here)
        for a, b in zip(bounds[:-1], bounds[1:]):
            if b - a < 2:
                continue
            seg_corr.append(segment_correlations(d / scale[:, None], a, b, n_lag))
            seg_w.append(b - a)
    if not seg_corr:
        raise ValueError(f"records too short for output-only identification: segments of at least "
                         f"{n_lag / fsd:.2f} s are needed for modes down to {lo:g} Hz")
    seg_corr = np.array(seg_corr)
    seg_w = np.array(seg_w, dtype=float)
    corr = np.tensordot(seg_w / seg_w.sum(), seg_corr, axes=1)
    opts = dict(block_rows=block_rows, max_order=max_order, band_hz=(f_pass[0], min(f_pass[1], 0.45 * fsd)))
    sel = select_modes(ssi_poles(corr, fsd, **opts))
    own = (sel.freq_hz >= lo) & ((sel.freq_hz < hi) | last)
    f_hat, z_hat, shapes, support = sel.freq_hz[own], sel.damping_ratio[own], sel.shapes[:, own], sel.support[own]
    n_seg = len(seg_w)
    ctx = (seg_corr, seg_w, fsd, opts, scale)
    nan = np.full(f_hat.size, np.nan)
    modes = _Modes(f_hat, z_hat, shapes * scale[:, None], support, nan, nan.copy(), nan.copy(),
                   np.zeros(f_hat.size, dtype=bool))
    if jackknife_now:
        f_se, z_se, u_se = _ssi_jackknife(ctx, f_hat, modes.shapes)
        modes = replace(modes, freq_se=f_se, damping_se=z_se, direction_se=u_se)
    return modes, n_seg, ctx


def _ssi_jackknife(ctx, f_hat, shapes):
    """Delete-one-segment jackknife standard errors of frequency, damping and direction (rad) of
    the SSI modes ``f_hat``, ``shapes`` (in the signal's unit) of one :func:`_band_modes` run."""
    seg_corr, seg_w, fsd, opts, scale = ctx
    shapes = np.asarray(shapes) / scale[:, None]
    n_seg = len(seg_w)
    rep_f = np.full((n_seg, f_hat.size), np.nan)
    rep_z = np.full((n_seg, f_hat.size), np.nan)
    rep_u = np.full((n_seg, f_hat.size), np.nan)
    if f_hat.size and n_seg >= 3:
        for b in range(n_seg):
            w = seg_w.copy()
            w[b] = 0.0
            c = np.tensordot(w / w.sum(), seg_corr, axes=1)
            rep_f[b], rep_z[b], phi = match_modes(ssi_poles(c, fsd, **opts), f_hat, shapes)
            for k in range(f_hat.size):
                if np.all(np.isfinite(phi[:, k])):
                    cosine = abs(real_direction(phi[:, k] * scale) @ real_direction(shapes[:, k] * scale))
                    rep_u[b, k] = np.arccos(min(cosine, 1.0))
    _, f_se = jackknife(rep_f)
    _, z_se = jackknife(rep_z)
    # angle of each replicate's direction from the full estimate's, its jackknife spread (rad)
    u_se = np.array([np.sqrt((np.sum(np.isfinite(a)) - 1) / max(np.sum(np.isfinite(a)), 1) * np.nansum(a ** 2))
                     if np.sum(np.isfinite(a)) >= 3 else np.nan for a in rep_u.T])
    return f_se, z_se, u_se
