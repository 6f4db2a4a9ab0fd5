"""Figures of output-only results (matplotlib imported here, only when a plot is asked for)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_output_only_modes"]


def plot_output_only_modes(modes, *, ax=None, harmonics: bool = True):
    """Damping ratio against natural frequency with the 95 % intervals of both, and the milling
    lines (solid: used or usable for scaling, dotted: folded from above Nyquist) as vertical lines.

    Parameters
    ----------
    modes : OutputOnlyModes
    ax : matplotlib Axes, optional
    harmonics : bool
        Draw the milling lines inside the band.

    Returns
    -------
    fig, ax
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 4))
    else:
        fig = ax.figure
    f, z = modes.freq_hz, 100 * modes.damping_ratio
    xerr = np.abs(modes.freq_interval_hz.T - f[None, :]) if f.size else None
    yerr = np.abs(100 * modes.damping_interval.T - z[None, :]) if f.size else None
    ax.errorbar(f, z, xerr=xerr, yerr=yerr, fmt="o", capsize=3, label=f"modes ({100 * modes.level:.0f} % intervals)")
    if harmonics:
        lo, hi = modes.band_hz
        first = True
        for h in modes.harmonics:
            aliased = h.aliased if h.aliased.size == h.freq_hz.size else np.zeros(h.freq_hz.size, bool)
            for fh, al, sig in zip(h.freq_hz, aliased, h.significant):
                if lo <= fh <= hi and sig:
                    ax.axvline(fh, color="0.6", ls=":" if al else "-", lw=0.8,
                               label="milling lines (removed)" if first else None)
                    first = False
    for fr in modes.rejected_hz:
        ax.axvline(fr, color="C3", ls="--", lw=0.8)
    ax.set_xlabel("natural frequency (Hz)")
    ax.set_ylabel("damping ratio (%)")
    ax.set_xlim(modes.band_hz)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("output-only modes")
    return fig, ax
