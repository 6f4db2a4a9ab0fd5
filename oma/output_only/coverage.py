"""Spectral peaks the identified modes do not explain: a backstop for a mode SSI missed.

SSI finds a mode as a cluster of poles stable over model orders; on a short record a clean mode
can fail to form one. An audit's independent generator (session 16: the oblique structure, a
17 Hz mode along Z, 5 s records) gave one record in twelve whose Z channel held a peak 8500 times
its floor at 16.6 Hz while the model had no mode within 4 Hz of it, and the model was trusted.
The refinement's scan for missed modes (:mod:`oma.output_only.ml`) looks only inside the bands of
the modes SSI found, so it cannot catch a mode alone in its band.

The check is model-free on purpose: a Welch spectrum of each channel of the residual (the milling
lines removed), its local maxima in the analysed band that stand ``PEAK_RATIO`` times above the
channel's median over the band and ``PROMINENCE`` times above their base (on each side the lowest
value before the spectrum rises above the peak, within a tenth of its frequency; the higher side's:
a peak, not a bump on a strong mode's skirt), away from every milling line and from the band's
edges, and not within ``max(3 zeta f, 2 bins)`` of any identified mode's frequency (whatever the
channel: a mode shows in every channel its direction or a neighbour's leakage reaches). What
remains is named;
``identify --output-only`` does not trust a model that leaves such a peak. The refinement's seeds
(:func:`oma.output_only.modes.output_only_modes`) are found the same way with a wider net: the
prominence over the lowest value within the reach on each side (``base='window'``), which also
takes bumps on a lump of close modes; the likelihood judges those.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

__all__ = ["UnexplainedPeak", "unexplained_peaks", "PEAK_RATIO"]

#: A peak counts when its Welch PSD is this many times the channel's median over the band. A
#: Welch estimate of a flat spectrum from ``n`` averages exceeds ``c`` times its mean with
#: probability about ``exp(-n c)`` per bin (chi-square, 2n degrees of freedom): at 20 and the
#: nine averages of a 5 s record (1 s segments, half overlapped), about 1e-78; robot modes in the
#: records seen stand 10^2-10^4 (the missed 17 Hz Z mode: 4662).
PEAK_RATIO = 20.0
#: ... and this many times the lowest value within a tenth of its frequency on either side.
PROMINENCE = 4.0
#: Welch segment length, s: 1 Hz bins. 4 s segments (0.25 Hz, two averages in a 5 s record) let a
#: strong mode's noisy skirt pass the prominence test in 12 of 12 records (docs/output_only.md);
#: a mode narrower than a bin (10 Hz at 2 %: 0.4 Hz) still puts its power in one.
SEGMENT_S = 1.0


@dataclass(frozen=True)
class UnexplainedPeak:
    """A peak of one channel's residual spectrum that no identified mode is near."""

    channel: int
    freq_hz: float
    ratio: float
    nearest_mode_hz: float
    #: Width of the peak at half its power in the channel's Welch spectrum, Hz (linear between
    #: bins; the Hann window's own 1.44 bins included); NaN when the peak does not fall to half
    #: within the prominence window.
    half_power_width_hz: float = float("nan")

    def describe(self, axis_names=("X", "Y", "Z")) -> str:
        name = axis_names[self.channel] if self.channel < len(axis_names) else f"channel {self.channel}"
        near = (f"the nearest mode is at {self.nearest_mode_hz:.2f} Hz" if np.isfinite(self.nearest_mode_hz)
                else "no mode was found")
        return (f"the {name} response has a spectral peak at {self.freq_hz:.2f} Hz ({self.ratio:.0f} times its "
                f"median over the band) that no identified mode explains ({near}): a mode SSI missed, or a tone; "
                "the model is not trusted (a longer record, or several records of the pose, may resolve it)")


def unexplained_peaks(residuals, sample_rate_hz: float, band_hz, freq_hz, damping_ratio, lines_hz=(), *,
                      line_relative_halfwidth: float = 0.0, ratio: float = PEAK_RATIO, segment_s: float = SEGMENT_S,
                      axes=None, base: str = "col") -> list[UnexplainedPeak]:
    """Peaks of the residual spectra that no mode explains (module docstring).

    Parameters
    ----------
    residuals : sequence of array_like, each (n_channels, n_samples)
        The records of one pose, milling lines removed, the same channels in each.
    sample_rate_hz : float
    band_hz : (float, float)
        The analysed band.
    freq_hz, damping_ratio : array_like
        The identified modes.
    lines_hz : array_like
        Milling lines of every record (peaks within two bins, plus ``line_relative_halfwidth`` times
        the line's frequency, of one are left out: a remainder of a line is not a mode).
    line_relative_halfwidth : float
        Extra half-width around each line as a share of its frequency (a tracked speed's relative
        wander, ``ResponseHarmonics.speed_variation``).
    axes : sequence of int, optional
        The axis index of each channel (default 0, 1, 2 ...).
    base : {'col', 'window'}
        What a peak's prominence is measured from: ``'col'`` (default; the verdict), its base
        (:func:`_base`); ``'window'``, the lowest value within the reach on each side whatever lies
        between, which also passes bumps on a sharp mode's skirt and on a lump of close modes (the
        candidates :func:`oma.output_only.modes.output_only_modes` seeds for the refinement cast
        this wider net: its likelihood judges them).

    Returns
    -------
    list of UnexplainedPeak
        At most one per channel, the tallest.
    """
    if base not in ("col", "window"):
        raise ValueError(f"base must be 'col' or 'window', found {base!r}")
    fs = float(sample_rate_hz)
    res = [np.array(r, dtype=float, ndmin=2) for r in residuals]
    n_min = min(r.shape[1] for r in res)
    nperseg = int(min(n_min, round(segment_s * fs)))
    if nperseg < 16:
        return []
    psd, weight = None, 0.0
    for r in res:
        f, p = sps.welch(r, fs=fs, nperseg=nperseg, axis=-1)
        w = r.shape[1]
        psd = p * w if psd is None else psd + p * w
        weight += w
    psd = psd / weight
    df = f[1] - f[0]
    lo, hi = float(band_hz[0]), float(band_hz[1])
    inside = (f >= lo + 2 * df) & (f <= hi - 2 * df)
    modes_f = np.asarray(freq_hz, dtype=float)
    modes_z = np.asarray(damping_ratio, dtype=float)
    lines = np.asarray(lines_hz, dtype=float).ravel()
    near_line = np.zeros(f.size, dtype=bool)
    for fl in lines:
        near_line |= np.abs(f - fl) <= 2 * df + line_relative_halfwidth * fl
    tol = np.maximum(3.0 * modes_z * modes_f, 2 * df)
    axes = list(range(psd.shape[0])) if axes is None else list(axes)
    out = []
    for ch in range(psd.shape[0]):
        p = psd[ch]
        if not np.all(np.isfinite(p)) or not np.any(inside):
            continue
        floor = float(np.median(p[inside]))
        if not floor > 0:
            continue
        peak = np.zeros(f.size, dtype=bool)
        peak[1:-1] = (p[1:-1] >= p[:-2]) & (p[1:-1] > p[2:])
        cand = np.flatnonzero(peak & inside & ~near_line & (p >= ratio * floor))
        # a peak, not a bump on a strong mode's skirt: it stands PROMINENCE times above its base
        # within a tenth of its frequency on each side (:func:`_base`: a skirt rises on the side
        # of its mode)
        half = np.maximum(np.round(0.1 * f[cand] / df).astype(int), 4)
        if base == "col":
            prominent = [p[k] >= PROMINENCE * _base(p, k, h) for k, h in zip(cand, half)]
        else:
            prominent = [p[k] >= PROMINENCE * max(np.min(p[max(k - h, 0):k]), np.min(p[k + 1:k + 1 + h]))
                         for k, h in zip(cand, half)]
        cand = cand[np.asarray(prominent, dtype=bool)]
        if modes_f.size:
            cand = cand[np.min(np.abs(f[cand, None] - modes_f[None, :]) - tol[None, :], axis=1) > 0]
        if cand.size:
            k = cand[np.argmax(p[cand])]
            nearest = float(modes_f[np.argmin(np.abs(modes_f - f[k]))]) if modes_f.size else float("nan")
            h = max(int(round(0.1 * f[k] / df)), 4)
            out.append(UnexplainedPeak(channel=axes[ch], freq_hz=float(f[k]), ratio=float(p[k] / floor),
                                       nearest_mode_hz=nearest, half_power_width_hz=_half_power_width(f, p, k, h)))
    return out


def _base(p, k: int, reach: int) -> float:
    """The base of the peak of ``p`` at bin ``k`` (its topographic prominence's key col): on each
    side the lowest value between the peak and the first higher one, looking at most ``reach``
    bins away; the higher of the two sides.

    Session 25: the lowest value within the reach on each side, whatever lay between, passed bumps
    on the skirt of a sharp mode whose other side the reach crossed: an independent audit's 200 Hz
    mode at 1 % damping had a Welch bin at 208 Hz 1.1 times its neighbours' and 5.5 times the
    lowest value 21 Hz below, beyond the mode (in 2 of 10 records, each left untrusted).

    These are the bases of :func:`scipy.signal.peak_prominences` with ``wlen = 2 reach + 1`` (equal
    on 198 447 local maxima of random spectra, ties included); written out because SciPy warns on a
    peak of zero prominence (a plateau) through a warning class it does not export."""
    bases = []
    for side in (p[k - 1::-1][:reach] if k > 0 else p[:0], p[k + 1:k + 1 + reach]):
        higher = np.flatnonzero(side > p[k])
        side = side[:higher[0]] if higher.size else side
        bases.append(float(np.min(side)) if side.size else float(p[k]))
    return max(bases)


def _half_power_width(f, p, k: int, reach: int) -> float:
    """Width of the peak of ``p`` at bin ``k`` where it falls to half its power on each side
    (linear between bins), looking at most ``reach`` bins away; NaN if it does not fall so far."""
    half = 0.5 * p[k]
    edges = []
    for step in (-1, 1):
        i = k
        while 0 <= i + step < p.size and abs(i + step - k) <= reach and p[i + step] > half:
            i += step
        j = i + step
        if not (0 <= j < p.size and abs(j - k) <= reach):
            return float("nan")
        edges.append(f[i] + (f[j] - f[i]) * (p[i] - half) / (p[i] - p[j]))
    return float(edges[1] - edges[0])
