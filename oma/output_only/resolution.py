"""Is an identified mode one mode? The rank of the response's spectral matrix over its band.

A single mode moves the structure along one shape whatever its input, so over its band the
spectral matrix of the vibration channels is ``|H_r(f)|^2 psi_r psi_r^H`` plus what else is there:
rank one. Two modes with different shapes inside the band make it rank two. SSI can merge two
close modes into one cluster on a short record (session 17: 5 s records of an audit's independent
generator, the 10.0 Hz Z and 10.5 Hz X modes of the paper's cell, whose half-power bands overlap,
came out as one mode in 29 of 60 records, 7 of them trusted), and the refinement then fits one
mode to both; the coverage check (:mod:`oma.output_only.coverage`) looks only further than
``3 zeta f`` from a mode, so it cannot see a partner inside the band.

The check: the spectral matrix of the residual (milling lines regressed out; bins near a line left
out), one Hann-windowed periodogram per record (bins ``1/T``) summed over the records and over
the bins within ``BAND_ZETA zeta f`` of the mode (at least ``MIN_HALF_BINS`` bins each side).
With ``m`` identified modes whose half-power bands reach into that band, its singular values
``s_1 >= s_2 >= ...`` should have ``s_(m+1)`` at the level of what the model says is there besides
them: the skirts of the other identified modes (each mode's power measured in its own half-power
band, carried into this band by its response shape ``|f^d / D(f)|^2``; counted ``SKIRT_MARGIN``
times) and a noise floor (the channels' median power per bin over the analysed band, lines left
out; high where the records have no sensor noise: in accelerations the modes' mass lines). A
mode is called unresolved when ``s_(m+1)`` exceeds that by more than ``SHARE`` of ``s_1``: a
second shape holds that share of the band's response. Nothing is fitted; only the identified
frequencies and damping ratios are used, not their directions (a merged mode's direction is a
mixture of its members').

It cannot see two modes with the same shape (the matrix stays rank one), nor a fourth mode in a
band where three channels already hold three.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ml import LINE_GUARD_HZ
from .modes import _spectral_matrix

__all__ = ["UnresolvedMode", "unresolved_modes", "band_shapes", "SHARE"]

#: Share of the band's first singular value by which the next one must exceed what the skirts
#: (times ``SKIRT_MARGIN``) and the floor account for. Session 17 (docs/output_only.md): on 160
#: records of 5 s (393 modes that are one mode) the excess was 0.004 at most, on 240 of 20 s 0.010;
#: merged pairs gave 0.034 and more wherever the record showed both members (two gave 0.006 and
#: 0.017: a 1.4 s cut window, and a record whose Z response at 10 Hz was 3 % of X's).
SHARE = 0.03
#: The other modes' skirts count this many times over: they are carried from each mode's own band
#: by its identified shape, whose damping (which sets the skirt) a short record knows to tens of
#: percent. Session 17: a weak 17 Hz Z mode between in-plane modes at 12 and 26 Hz (5 s record)
#: had a second shape of 0.18 against 0.13 predicted from the skirts (flagged at 1x); merged pairs
#: have skirts of 0.02 at most (the partner is no identified mode), so the margin costs them little.
SKIRT_MARGIN = 2.0
#: The band tested: within this many half-power half-widths (``zeta f``) of the mode. Two: a
#: partner up to that far holds a fifth of its peak power at the mode and still shows.
BAND_ZETA = 2.0
#: ... and at least this many periodogram bins each side: a sum over fewer than about eight
#: (Hann-correlated) bins has too few degrees of freedom for its second singular value to show a
#: partner of similar power (a 5 s record, a 10 Hz / 2 % mode: two bins; its share came out 0.01).
MIN_HALF_BINS = 4


@dataclass(frozen=True)
class UnresolvedMode:
    """The rank test of one identified mode's band (:func:`band_shapes`); those
    :func:`unresolved_modes` returns hold a second shape of response.

    Attributes
    ----------
    index : int
        The mode's index among the identified modes.
    freq_hz : float
    band_hz : (float, float)
        The band tested, Hz.
    share : float
        ``s_(m+1) / s_1`` of the band's spectral matrix.
    expected_share : float
        What the other modes' skirts and the noise floor account for, as a share of ``s_1``.
    modes_in_band : int
        ``m``: identified modes whose half-power bands reach into the band (this one included).
    skirt_share : float
        The skirts' part of ``expected_share``.
    """

    index: int
    freq_hz: float
    band_hz: tuple
    share: float
    expected_share: float
    modes_in_band: int
    skirt_share: float = 0.0

    def describe(self) -> str:
        return (f"mode at {self.freq_hz:.2f} Hz: over {self.band_hz[0]:.2f}-{self.band_hz[1]:.2f} Hz the response "
                f"holds {self.modes_in_band + 1} shapes (singular value {self.modes_in_band + 1} of the spectral "
                f"matrix is {100 * self.share:.0f} % of the first, the other modes' skirts and the noise account "
                f"for {100 * self.expected_share:.0f} %): two or more modes taken for one, whose frequency, damping "
                "and stiffness are a blend; the model is not trusted (a longer record, or several records of the "
                "pose, may separate them)")

    def to_dict(self) -> dict:
        return {"mode_index": self.index, "freq_hz": self.freq_hz, "band_hz": [float(b) for b in self.band_hz],
                "second_shape_share": self.share, "expected_share": self.expected_share,
                "skirt_share": self.skirt_share, "modes_in_band": self.modes_in_band}


def _shape(f, fr, zr, derivative):
    """A mode's power response ``|(f / fr)^d / D(f)|^2`` (only its ratios are used)."""
    r = f / fr
    return r ** (2 * derivative) / np.abs(1 - r ** 2 + 2j * zr * r) ** 2


def _band(f, fr, zr, df, usable):
    """The bins tested for a mode at ``fr`` and the band's half-width, Hz."""
    hw = max(BAND_ZETA * zr * fr, MIN_HALF_BINS * df)
    return usable & (np.abs(f - fr) <= hw), hw


def _skirts(f, g, sel, fr, zr, freq, zeta, inside, usable, derivative, df):
    """Summed power of the identified modes outside the band (``inside`` False) in the bins
    ``sel``: each mode's first singular value over its own half-power band, carried by its shape."""
    total = 0.0
    for fj, zj, here in zip(freq, zeta, inside):
        if here:
            continue
        own = usable & (np.abs(f - fj) <= max(zj * fj, df))
        if not np.any(own):
            continue
        peak = np.linalg.svd(np.sum(g[:, :, own], axis=-1), compute_uv=False)[0]
        shape = _shape(f, fj, zj, derivative)
        total += peak * np.sum(shape[sel]) / np.sum(shape[own])
    return total


def unresolved_modes(residuals, sample_rate_hz: float, band_hz, freq_hz, damping_ratio, lines_hz=(), *,
                     derivative: int = 0, share: float = SHARE,
                     line_relative_halfwidth: float = 0.0) -> list[UnresolvedMode]:
    """The identified modes whose band holds more shapes than modes (module docstring).

    Parameters
    ----------
    residuals, sample_rate_hz, band_hz, freq_hz, damping_ratio
        As :func:`oma.output_only.coverage.unexplained_peaks` (the noise floor is the channels'
        median power over ``band_hz``).
    lines_hz : array_like
        Milling lines of every record (bins within :data:`~oma.output_only.ml.LINE_GUARD_HZ`, or within
        ``line_relative_halfwidth`` times the line's frequency, a tracked speed's wander, left out).
    derivative : {0, 1, 2}
        Displacement, velocity or acceleration (the skirts' shape).
    share : float
        :data:`SHARE`.
    """
    stats = band_shapes(residuals, sample_rate_hz, band_hz, freq_hz, damping_ratio, lines_hz,
                        derivative=derivative, line_relative_halfwidth=line_relative_halfwidth)
    return [st for st in stats if st is not None
            and st.share > st.expected_share + (SKIRT_MARGIN - 1.0) * st.skirt_share + share]


def band_shapes(residuals, sample_rate_hz: float, band_hz, freq_hz, damping_ratio, lines_hz=(), *,
                derivative: int = 0, line_relative_halfwidth: float = 0.0) -> list:
    """Per mode the :class:`UnresolvedMode` record of its band's shares, flagged or not (None where
    nothing is left to test: as many modes in the band as channels); see :func:`unresolved_modes`."""
    res = [np.array(r, dtype=float, ndmin=2) for r in residuals]
    freq = np.asarray(freq_hz, dtype=float)
    zeta = np.asarray(damping_ratio, dtype=float)
    n_ch = res[0].shape[0]
    if freq.size == 0 or n_ch < 2:
        return [None] * freq.size
    f, g = _spectral_matrix(res, float(sample_rate_hz), min(r.shape[1] for r in res))
    df = f[1] - f[0]
    usable = np.ones(f.size, dtype=bool)
    for fl in np.asarray(lines_hz, dtype=float).ravel():
        usable &= np.abs(f - fl) > max(LINE_GUARD_HZ, line_relative_halfwidth * fl)
    analysed = usable & (f >= band_hz[0]) & (f <= band_hz[1])
    if not np.any(analysed):
        return [None] * freq.size
    floor = float(np.median(np.real(np.trace(g[:, :, analysed])))) / n_ch
    out = []
    for k, (fr, zr) in enumerate(zip(freq, zeta)):
        if not (np.isfinite(fr) and np.isfinite(zr) and zr > 0):
            out.append(None)
            continue
        sel, hw = _band(f, fr, zr, df, usable)
        inside = np.abs(freq - fr) <= hw + zeta * freq
        m = int(np.sum(inside))
        sv = np.linalg.svd(np.sum(g[:, :, sel], axis=-1), compute_uv=False) if np.sum(sel) > m else None
        if m >= n_ch or sv is None or not sv[0] > 0:
            out.append(None)  # as many modes as channels (or bins): nothing left to test
            continue
        skirts = _skirts(f, g, sel, fr, zr, freq, zeta, inside, usable, derivative, df) / sv[0]
        expected = skirts + floor * np.sum(sel) / sv[0]
        out.append(UnresolvedMode(index=k, freq_hz=float(fr), band_hz=(float(fr - hw), float(fr + hw)),
                                  share=float(sv[m] / sv[0]), expected_share=float(expected), modes_in_band=m,
                                  skirt_share=float(skirts)))
    return out
