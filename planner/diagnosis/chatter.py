"""Chatter detection: a strong, narrow spectral line at a frequency that is not a spindle harmonic.

Stable milling vibration is forced: lines at the multiples of the spindle frequency (the tooth
lines strongest) on a broadband floor (for a robot, the floor carries the resonances its background
force excites). Chatter is self-excited: a limit cycle at a new frequency near a structural mode,
so a spectral LINE that is neither a harmonic nor a broad resonance. The detector asks three things
of the strongest non-harmonic line of a signal's spectrum (Welch, Hann, segments of ``segment_s``):

1. where the spindle really turns: the spindle frequency that maximises the energy of the comb
   ``h f_s`` near the nominal speed, up to the Nyquist frequency or the tooth line (the DTFT of a
   sampled signal is periodic in ``fs`` and symmetric, so evaluating it at ``h f_s`` counts an
   aliased harmonic where it folds to); the harmonics up to ``max_harmonic_hz`` (default ``fs``:
   one fold) are then fitted by least squares at their folded lines and removed, and the lines
   near them (``mask_lines`` plus the smearing of a spindle speed wandering by
   ``speed_tolerance``) are left out;
2. prominence: the line's density over the median density of the ring 3..12 lines away on either
   side (a line is narrower than the Hann main lobe of +-2 lines; a structural resonance is wider
   than the ring and lifts it too). For a noise-only Welch estimate with tens of averages the
   ratio stays below 3; ``min_prominence`` (10 dB) is far above;
3. strength: the line's power (its +-2 lines integrated) relative to the power of the strongest
   spindle harmonic, at least ``min_energy_ratio`` (-10 dB): chatter is a vibration of the size of
   the forced one, not a trace.

Chatter is declared when 2 and 3 hold. With an even number of teeth, period-doubling (flip)
chatter at ``(k + 1/2) f_tooth`` falls on spindle harmonics and is masked above; it is declared
when those harmonics (``h = N/2 mod N``) carry at least ``min_flip_ratio`` (-3 dB) of the power of
the strongest tooth line. Runout also feeds these lines, but far less: 30 um of runout in the
paper-like robot cell gives 0.06 of the tooth-line power at 2700 rpm and 0.17 at 1000 rpm (where
the spindle line meets the robot modes), flip chatter above 1.

Frequencies are reported as they appear in the sampled
signal (folded into ``[0, fs/2]``); the true chatter frequency may be ``k fs +- f``.

A chatter frequency the signal cannot show. When a model predicts chatter above the band searched
(``expected_chatter_hz``: the zero-order approximation's frequency at the cut's speed, e.g. a
spindle/tool mode at 748 Hz in a 1 kHz record), the chatter line lies where the record's
anti-alias filter removed it (8th order per pass at 0.4 fs: -87 dB at 748 Hz for 1 kHz) or, in a
record without one, where it folds to ``fold(f_c)``. A "no" then says nothing about that chatter:
its confidence is the bottom of the scale (0.1) and ``out_of_band`` is set; ``expected_alias_hz``
says where its alias would lie (a "yes" at that line may be the folded chatter).

The thresholds are physical choices made before looking at any measured data (see above); they are
keyword arguments, and the measured cuts of ``milling-vibration-hurco`` are a check, not a tuning
set.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from oma._arrays import readonly as _ro
from scipy import optimize
from scipy import signal as sps

from .spectral import fold_frequency, sinusoid_coefficients

__all__ = ["ChatterResult", "refine_spindle_frequency_aliased", "detect_chatter", "comb_energy"]


@dataclass(frozen=True)
class ChatterResult:
    """Outcome of :func:`detect_chatter`.

    Attributes
    ----------
    chatter : bool
    frequency_hz : float
        Strongest non-harmonic line, Hz, as seen in the sampled signal (NaN if none was found).
    prominence : float
        Its density over the local floor (ring median).
    energy_ratio : float
        Its power over the power of the strongest spindle harmonic.
    spindle_hz : float
        Refined spindle frequency, Hz.
    tooth_hz : float
        ``teeth * spindle_hz`` folded into ``[0, fs/2]``, Hz.
    freq_hz : ndarray
        Frequency lines of the spectrum, Hz.
    psd : ndarray
        Sum over channels of the Welch densities of the signals with harmonics removed.
    harmonic_mask : ndarray of bool
        Lines left out as harmonics.
    kind : str
        ``'hopf'`` (a new line), ``'flip'`` (period doubling on spindle harmonics) or ``'none'``.
    flip_ratio : float
        Power of the half-tooth-frequency harmonics over the strongest tooth line (NaN for odd
        teeth).
    confidence : float
        How far the decisive statistics are from their thresholds, in decades, clipped to
        ``[0.1, 1]`` (one decade: sure). Chatter: the smaller margin of the criteria that hold
        (prominence and strength for a new line, the flip ratio for period doubling). No
        chatter: the new-line verdict's margin is that of its most clearly failed criterion, the
        flip verdict's that of the flip ratio; the smaller of the two. A 60 dB line that misses
        the strength threshold by 10 % is a "no" with confidence 0.1, not 1. A "no" when the
        expected chatter frequency lies above the band searched: 0.1 (module notes).
    expected_chatter_hz : float
        The chatter frequency a model predicts, Hz, as given (NaN if none).
    expected_alias_hz : float
        Where it appears in the sampled signal (folded into ``[0, fs/2]``), Hz, when it lies above
        the band searched (NaN otherwise).
    out_of_band : bool
        The expected chatter frequency lies above the band searched: the chatter line is filtered
        out or aliased.
    """

    chatter: bool
    frequency_hz: float
    prominence: float
    energy_ratio: float
    spindle_hz: float
    tooth_hz: float
    freq_hz: np.ndarray = field(repr=False)
    psd: np.ndarray = field(repr=False)
    harmonic_mask: np.ndarray = field(repr=False)
    kind: str = "none"
    flip_ratio: float = float("nan")
    confidence: float = float("nan")
    expected_chatter_hz: float = float("nan")
    expected_alias_hz: float = float("nan")
    out_of_band: bool = False

    def __post_init__(self):
        object.__setattr__(self, "freq_hz", _ro(self.freq_hz))
        object.__setattr__(self, "psd", _ro(self.psd))
        object.__setattr__(self, "harmonic_mask", _ro(self.harmonic_mask, bool))

    def to_dict(self) -> dict:
        def num(x):
            return float(x) if np.isfinite(x) else None

        return {"chatter": bool(self.chatter), "frequency_hz": num(self.frequency_hz),
                "prominence": num(self.prominence), "energy_ratio": num(self.energy_ratio),
                "spindle_hz": float(self.spindle_hz), "tooth_hz": float(self.tooth_hz), "kind": self.kind,
                "flip_ratio": num(self.flip_ratio), "confidence": num(self.confidence),
                "expected_chatter_hz": num(self.expected_chatter_hz), "expected_alias_hz": num(self.expected_alias_hz),
                "out_of_band": bool(self.out_of_band)}


def _decades(value: float, threshold: float) -> float:
    """``log10(value / threshold)``: +inf for an infinite value, -inf for zero, NaN for NaN."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.log10(value / threshold))


def _confidence(kind: str, prominence: float, energy_ratio: float, flip_ratio: float, min_prominence: float,
                min_energy_ratio: float, min_flip_ratio: float) -> float:
    """:attr:`ChatterResult.confidence` from the statistics and their thresholds."""
    hopf = min(_decades(prominence, min_prominence), _decades(energy_ratio, min_energy_ratio))
    flip = _decades(flip_ratio, min_flip_ratio)
    if kind == "hopf":
        margin = hopf
    elif kind == "flip":
        margin = flip
    else:  # both verdicts negative: no line found (NaN statistics) is a clear no, as is odd teeth
        no_hopf = -hopf if np.isfinite(prominence) and np.isfinite(energy_ratio) else np.inf
        no_flip = -flip if np.isfinite(flip_ratio) else np.inf
        margin = min(no_hopf, no_flip)
    return float(np.clip(margin, 0.1, 1.0))


#: Confidence of a "no" when the expected chatter frequency lies above the band searched: the
#: bottom of the scale (the detector did not look where the chatter would be).
OUT_OF_BAND_CONFIDENCE = 0.1


def _with_expected(res: ChatterResult, expected_hz, band_top_hz: float, fs: float) -> ChatterResult:
    """``res`` with the expected chatter frequency, and a "no" that could not see it marked unsure."""
    if expected_hz is None or not np.isfinite(expected_hz):
        return res
    expected_hz = float(expected_hz)
    if expected_hz <= band_top_hz:
        return replace(res, expected_chatter_hz=expected_hz)
    conf = res.confidence if res.chatter else min(res.confidence, OUT_OF_BAND_CONFIDENCE)
    return replace(res, expected_chatter_hz=expected_hz, expected_alias_hz=float(fold_frequency(expected_hz, fs)),
                   out_of_band=True, confidence=conf)


def comb_energy(xw, fs, f0, n_harm):
    """Energy of the DTFT of the windowed signals at ``h f0``, h = 1..n_harm."""
    n = xw.shape[-1]
    z = np.exp(-2j * np.pi * f0 * np.arange(n) / fs)
    cur = np.ones(n, dtype=complex)
    total = 0.0
    for h in range(1, n_harm + 1):
        cur = cur * z
        total += float(np.sum(np.abs(np.einsum("cn,n->c", xw, cur)) ** 2))
    return total


def refine_spindle_frequency_aliased(x, sample_rate_hz: float, nominal_hz: float, *, teeth: int = 1,
                                     search: float = 0.05, max_harmonic_hz: float | None = None) -> float:
    """Spindle frequency maximising the energy of the harmonic comb, aliased harmonics included, Hz.

    Parameters
    ----------
    x : array_like, shape (n_channels, n)
    sample_rate_hz, nominal_hz : float
    teeth : int
        Teeth of the tool: the comb reaches at least the tooth-passing line, folded if it lies above
        the Nyquist frequency.
    search : float
        Relative half-width of the search around ``nominal_hz``.
    max_harmonic_hz : float, optional
        Highest harmonic frequency of the comb (default: the Nyquist frequency or the tooth-passing
        line, whichever is higher). A comb reaching far into the alias zones has many teeth on
        noise, and its energy can peak on a chance alignment of aliases.
    """
    x = np.array(x, dtype=float, ndmin=2)
    x = x[~np.any(np.isnan(x), axis=1)]
    fs = float(sample_rate_hz)
    n = x.shape[-1]
    xw = sps.detrend(x, axis=-1) * sps.get_window("hann", n)[None, :]
    top = max(0.5 * fs, 1.001 * teeth * nominal_hz * (1.0 + search)) if max_harmonic_hz is None \
        else float(max_harmonic_hz)
    lo, hi = nominal_hz * (1.0 - search), nominal_hz * (1.0 + search)
    n_harm = max(int(np.floor(top / hi)), 1)
    n_fft = int(2 ** np.ceil(np.log2(8 * n)))
    spec = np.sum(np.abs(np.fft.rfft(xw, n=n_fft, axis=-1)) ** 2, axis=0)
    fgrid = np.fft.rfftfreq(n_fft, 1.0 / fs)
    step = 0.1 * fs / n / n_harm
    cands = np.arange(lo, hi + step, step)
    energy = np.zeros(cands.size)
    for h in range(1, n_harm + 1):
        energy += np.interp(fold_frequency(h * cands, fs), fgrid, spec)
    i = int(np.argmax(energy))
    a, b = cands[max(i - 2, 0)], cands[min(i + 2, cands.size - 1)]
    res = optimize.minimize_scalar(lambda f0: -comb_energy(xw, fs, f0, n_harm), bounds=(a, b),
                                   method="bounded", options={"xatol": 1e-7 * nominal_hz})
    return float(res.x)


def detect_chatter(signals, sample_rate_hz: float, spindle_hz: float, teeth: int, *, refine: bool = True,
                   search: float = 0.05, segment_s: float = 2.0, min_prominence: float = 10.0,
                   min_energy_ratio: float = 0.1, min_flip_ratio: float = 0.5, mask_lines: int = 3,
                   speed_tolerance: float = 0.003, max_harmonic_hz: float | None = None, min_hz: float | None = None,
                   max_hz: float | None = None, expected_chatter_hz: float | None = None) -> ChatterResult:
    """Is there chatter in these vibration (or force) signals?

    Parameters
    ----------
    signals : array_like, shape (n_channels, n)
        Acceleration, displacement or force, one row per axis (NaN rows are ignored).
    sample_rate_hz : float
    spindle_hz : float
        Nominal spindle frequency, Hz (``rpm / 60``).
    teeth : int
    refine : bool
        Refine the spindle frequency (:func:`refine_spindle_frequency_aliased`).
    segment_s : float
        Welch segment length, s (at most a quarter of the record).
    min_prominence, min_energy_ratio, min_flip_ratio : float
        Decision thresholds (module notes).
    mask_lines : int
        Lines left out on either side of a (folded) harmonic ...
    speed_tolerance : float
        ... plus ``speed_tolerance * h * f_s`` (at most 4 lines) for harmonic ``h``: a spindle
        speed that wanders by this fraction smears the high harmonics (0.3 %: a regulated spindle
        under load).
    max_harmonic_hz : float, optional
        Highest harmonic considered, before folding (default ``fs``: harmonics up to one fold, for
        a sensor whose anti-alias filter is unknown; pass ``fs / 2`` for records filtered before
        sampling). Each folded harmonic masks about 3 Hz of the spectrum: a comb reaching far into
        the alias zones would mask most of it.
    min_hz, max_hz : float, optional
        Band searched for the line (default: 4 lines .. 0.45 fs).
    expected_chatter_hz : float, optional
        The chatter frequency a model predicts at this speed, Hz. Above the band searched, a "no"
        gets confidence 0.1 and the result says where the chatter would fold (module notes).

    Returns
    -------
    ChatterResult
    """
    x = np.array(signals, dtype=float, ndmin=2)
    x = x[~np.any(np.isnan(x), axis=1)]
    if x.size == 0:
        raise ValueError("no finite signal to analyse")
    if not np.all(np.isfinite(x)):
        raise ValueError("infinite values in the signals: nothing can be said of chatter from them")
    fs = float(sample_rate_hz)
    n = x.shape[-1]
    f0 = (refine_spindle_frequency_aliased(x, fs, spindle_hz, teeth=teeth, search=search) if refine
          else float(spindle_hz))
    # the harmonics up to max_harmonic_hz, where they appear in the sampled signal
    top = fs if max_harmonic_hz is None else float(max_harmonic_hz)
    n_harm = max(int(np.floor(max(top, 1.001 * teeth * f0) / f0)), 1)
    hh = np.arange(1, n_harm + 1) * f0
    harm = fold_frequency(hh, fs)
    nperseg = int(min(round(segment_s * fs), max(n // 4, 64)))
    df = fs / nperseg
    # least squares over the harmonics whose folded lines are distinct (an alias of a line already
    # fitted would make the problem singular; their sum is fitted once)
    chosen = []
    for j, fr in enumerate(harm):
        if hh[j] > fs and j >= teeth:  # beyond one fold only masked (the tooth line always fitted)
            break
        if fr > 2 * df and fr < 0.5 * fs - 2 * df and all(abs(fr - harm[i]) > 2 * df for i in chosen):
            chosen.append(j)
    c, fitted = sinusoid_coefficients(x, fs, hh[chosen])
    resid = x - fitted
    f, p = sps.welch(resid, fs=fs, nperseg=nperseg, detrend="linear", axis=-1)
    psd = p.sum(axis=0)
    width = mask_lines * df + np.minimum(speed_tolerance * hh, 4.0 * df)
    mask = np.any(np.abs(f[:, None] - harm[None, :]) <= width[None, :], axis=1)
    lo = 4 * df if min_hz is None else float(min_hz)
    hi = 0.45 * fs if max_hz is None else float(max_hz)
    allowed = (~mask) & (f >= lo) & (f <= hi)
    # harmonic line powers from the least-squares amplitudes: |c|^2 / 2 per channel (aliases that
    # land on the same line are counted once, together)
    line_power = np.sum(np.abs(c[:, 1:]) ** 2 / 2.0, axis=0)
    strongest_harmonic = float(np.max(line_power)) if line_power.size else 0.0
    tooth = float(fold_frequency(teeth * f0, fs))
    flip_ratio = float("nan")
    h = np.asarray(chosen, dtype=int) + 1
    if teeth % 2 == 0 and np.any(h % teeth == 0):
        half = (h % teeth) == teeth // 2
        flip_ratio = float(np.max(line_power[half]) / np.max(line_power[h % teeth == 0])) if np.any(half) else 0.0
    flip = bool(np.isfinite(flip_ratio) and flip_ratio >= min_flip_ratio)
    if not np.any(allowed):
        freq = float(fold_frequency(teeth * f0 / 2.0, fs)) if flip else float("nan")
        kind = "flip" if flip else "none"
        return _with_expected(
            ChatterResult(flip, freq, float("nan"), float("nan"), f0, tooth, f, psd, mask, kind, flip_ratio,
                          _confidence(kind, np.nan, np.nan, flip_ratio, min_prominence, min_energy_ratio,
                                      min_flip_ratio)), expected_chatter_hz, hi, fs)
    k = int(np.flatnonzero(allowed)[np.argmax(psd[allowed])])
    idx = np.arange(f.size)
    ring = allowed & (np.abs(idx - k) >= 3) & (np.abs(idx - k) <= 12)
    floor = float(np.median(psd[ring])) if np.any(ring) else float("nan")
    prominence = float(psd[k] / floor) if floor > 0 else float("inf")
    near = np.abs(idx - k) <= 2
    line = float(np.sum(psd[near]) * df)
    ratio = line / strongest_harmonic if strongest_harmonic > 0 else float("inf")
    # centroid of the line's lines for a sub-line frequency
    w = psd[near]
    freq = float(np.sum(f[near] * w) / np.sum(w))
    hopf = bool(prominence >= min_prominence and ratio >= min_energy_ratio)
    kind = "hopf" if hopf else ("flip" if flip else "none")
    if kind == "flip":
        freq = float(fold_frequency(teeth * f0 / 2.0, fs))
    return _with_expected(
        ChatterResult(hopf or flip, freq, prominence, ratio, f0, tooth, f, psd, mask, kind, flip_ratio,
                      _confidence(kind, prominence, ratio, flip_ratio, min_prominence, min_energy_ratio,
                                  min_flip_ratio)), expected_chatter_hz, hi, fs)
