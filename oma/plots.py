"""Figures of the OMA results, like Nguyen & Melkote (2020) Figs. 3, 6 and 7.

Plot functions take results, compute no physics, and return ``(fig, axes)``. Matplotlib is imported
inside each function, so importing :mod:`oma` never pulls it in.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_frf_comparison", "plot_force_spectrum", "plot_detectability", "plot_stabilisation"]

AXES = ("X", "Y", "Z")


def _new_axes(n_rows, n_cols, axes=None, **kw):
    import matplotlib.pyplot as plt

    if axes is not None:
        axes = np.asarray(axes).reshape(n_rows, n_cols)
        return axes.flat[0].figure, axes
    fig, axes = plt.subplots(n_rows, n_cols, squeeze=False, **kw)
    return fig, axes


def _wrap_near(phase_deg, guide_deg):
    """Each phase moved by a multiple of 360 degrees to within 180 degrees of the guide."""
    return guide_deg + (np.asarray(phase_deg) - guide_deg + 180.0) % 360.0 - 180.0


def _unwrapped_near(h, guide_deg):
    """Unwrapped phase of ``h`` (degrees), shifted as a whole by the multiple of 360 degrees
    that brings it closest (in the median) to the guide curve sampled at the same lines."""
    ph = np.degrees(np.unwrap(np.angle(h)))
    if ph.size == 0:
        return ph
    return ph - 360.0 * np.round(np.median(ph - guide_deg) / 360.0)


def _model_grid(lo, hi, model, n_min=800, n_max=20000):
    """Lines for drawing a model: fine enough that the phase of its sharpest mode is followed
    (a quarter of the narrowest half-power bandwidth ``2 zeta f_n``), between ``n_min`` and ``n_max``."""
    n = n_min
    fn, z = getattr(model, "natural_frequency_hz", None), getattr(model, "damping_ratio", None)
    if fn is not None and np.size(fn):
        bw = float(np.min(2.0 * np.asarray(z) * np.asarray(fn)))
        if bw > 0:
            n = int(min(max(n_min, 4.0 * (hi - lo) / bw), n_max))
    return np.linspace(max(lo, 1e-3), hi, n)


def plot_frf_comparison(identification, reference=None, *, axes=None, freq_range_hz=None, n_sigma: float = 2.0):
    """Identified versus reference receptance per axis: magnitude, phase and coherence.

    A measured reference (an :class:`~oma.frf_table.FRFTable`) is drawn on its own lines inside
    the plotted range, never interpolated or extended beyond its band; a modal-model reference is
    evaluated on a fine grid. Phases are unwrapped along frequency, not cut at +-180 degrees: the
    identified model's curve is unwrapped from its lowest line, a reference curve is unwrapped and
    shifted by the multiple of 360 degrees that lays it on the model's branch, and each point of
    the H1 estimate is drawn on the branch within 180 degrees of the model (its phase is only
    defined modulo 360 degrees, and its random error would otherwise throw it across the cut).

    Parameters
    ----------
    identification : oma.identify.Identification
        Its H1 estimate (points with the ``n_sigma`` random-error band), its model (line).
    reference : FRFTable or ModalModel, optional
        E.g. an impact-hammer FRF or the truth of a simulation (dashed).
    axes : array of Axes, shape (3, n_axes), optional
    freq_range_hz : (float, float), optional
    n_sigma : float
        Width of the error band in random-error standard deviations.

    Returns
    -------
    fig, axes
    """
    est = identification.frf_estimate
    table = est.table
    measured = [a for a in range(3) if table.measured[a, a]]
    fig, ax = _new_axes(3, len(measured), axes, sharex=True, figsize=(4 * len(measured), 7))
    f = table.freq_hz
    lo, hi = freq_range_hz if freq_range_hz is not None else (f.min(), min(f.max(), 100.0))
    sel = (f >= lo) & (f <= hi)
    fine = _model_grid(lo, hi, identification.model)
    g_model = identification.model.receptance(fine)
    ref_lines = None  # (freq_hz, receptance (3, 3, n), measured (3, 3)) of the reference
    if reference is not None:
        if hasattr(reference, "freq_hz") and hasattr(reference, "receptance_m_N"):
            # a measured table: its own lines in the plotted range, no interpolation
            rf = np.asarray(reference.freq_hz)
            rsel = (rf >= lo) & (rf <= hi)
            ref_lines = (rf[rsel], np.asarray(reference.receptance_m_N)[:, :, rsel], np.asarray(reference.measured))
        else:
            fine_ref = _model_grid(lo, hi, reference)
            ref_lines = (fine_ref, reference.receptance(fine_ref), np.ones((3, 3), dtype=bool))
    band_lo, band_hi = est.magnitude_band(n_sigma=n_sigma)
    for c, a in enumerate(measured):
        h = table.receptance_m_N[a, a]
        model_phase = np.degrees(np.unwrap(np.angle(g_model[a, a])))
        ax[0, c].fill_between(f[sel], band_lo[a, a, sel], band_hi[a, a, sel], color="C0", alpha=0.2, lw=0,
                              label=f"H1 +-{n_sigma:g} sigma")
        ax[0, c].semilogy(f[sel], np.abs(h[sel]), ".", color="C0", ms=3, label="H1 estimate")
        ax[0, c].semilogy(fine, np.abs(g_model[a, a]), "-", color="C1", label="identified model")
        h1_phase = _wrap_near(np.degrees(np.angle(h[sel])), np.interp(f[sel], fine, model_phase))
        ax[1, c].plot(f[sel], h1_phase, ".", color="C0", ms=3, label="H1 estimate")
        ax[1, c].plot(fine, model_phase, "-", color="C1", label="identified model")
        if ref_lines is not None and ref_lines[2][a, a] and ref_lines[0].size:
            rf, rg = ref_lines[0], ref_lines[1][a, a]
            ax[0, c].semilogy(rf, np.abs(rg), "--", color="k", label="reference")
            ax[1, c].plot(rf, _unwrapped_near(rg, np.interp(rf, fine, model_phase)), "--", color="k",
                          label="reference")
        if table.coherence is not None:
            ax[2, c].plot(f[sel], table.coherence[a, a, sel], "-", color="C0", label="ordinary")
        ax[2, c].plot(f[sel], identification.frf_estimate.multiple_coherence[a, sel], "-", color="C2",
                      label="multiple")
        ax[0, c].set_title(f"{AXES[a]}{AXES[a]}")
        ax[0, c].set_ylabel("|G| (m/N)")
        ax[1, c].set_ylabel("phase (deg, unwrapped)")
        ax[2, c].set_ylabel("coherence")
        ax[2, c].set_ylim(0, 1.05)
        ax[2, c].set_xlabel("frequency (Hz)")
    ax[0, 0].legend(fontsize="small")
    ax[2, 0].legend(fontsize="small")
    fig.tight_layout()
    return fig, ax


def plot_force_spectrum(background, harmonics, *, ax=None):
    """Force PSD per axis with the milling harmonics marked and the background PSD (Fig. 3b).

    Parameters
    ----------
    background : oma.harmonics.BackgroundEstimate
    harmonics : oma.harmonics.Harmonics or None
    ax : Axes, optional
    """
    fig, axs = _new_axes(1, 1, None if ax is None else [ax], figsize=(7, 4))
    a0 = axs[0, 0]
    f = background.freq_hz
    for k in range(3):
        if np.all(np.isnan(background.psd[k])):
            continue
        a0.semilogy(f, background.psd[k], lw=0.8, color=f"C{k}",
                    label=f"F{AXES[k].lower()}: background {background.variance_N2[k]:.0f} N^2")
        a0.semilogy(f, background.psd_clean[k], lw=1.5, ls=":", color=f"C{k}")
    if harmonics is not None:
        for fh, tooth, sig in zip(harmonics.freq_hz, harmonics.tooth_passing, harmonics.significant):
            a0.axvline(fh, color="k" if tooth else "0.5", lw=0.6 if sig else 0.3, ls="-" if sig else "--")
        a0.set_title(f"force spectrum; spindle {harmonics.spindle_hz:.2f} Hz (nominal "
                     f"{harmonics.nominal_spindle_hz:.2f} Hz), tooth-passing lines black")
    a0.set_xlabel("frequency (Hz)")
    a0.set_ylabel("PSD (N^2/Hz)")
    a0.legend(fontsize="small")
    fig.tight_layout()
    return fig, a0


def plot_detectability(det, *, ax=None):
    """Peak-to-valley response versus white-force variance with the sensor resolution (Fig. 7)."""
    fig, axs = _new_axes(1, 1, None if ax is None else [ax], figsize=(6, 4))
    a0 = axs[0, 0]
    for k in range(3):
        if np.all(np.isnan(det.peak_to_valley_m[k])):
            continue
        a0.loglog(det.variance_N2, det.peak_to_valley_m[k] * 1e6, color=f"C{k}", label=f"{AXES[k]} (median)")
        a0.fill_between(det.variance_N2, det.peak_to_valley_low_m[k] * 1e6, det.peak_to_valley_high_m[k] * 1e6,
                        color=f"C{k}", alpha=0.15, lw=0)
        if np.isfinite(det.background_variance_N2[k]):
            a0.axvline(det.background_variance_N2[k], color=f"C{k}", ls=":", lw=1)
        if np.isfinite(det.min_variance_N2[k]):
            a0.plot(det.min_variance_N2[k], det.resolution_m * 1e6, "o", color=f"C{k}")
    if det.resolution_m is not None:
        a0.axhline(det.resolution_m * 1e6, color="k", ls="--", label=f"resolution {det.resolution_m * 1e6:.1f} um")
    else:
        a0.text(0.5, 0.5, "no displacement resolution known: not assessed", transform=a0.transAxes,
                ha="center", va="center")
    a0.set_xlabel("white force variance (N^2)")
    a0.set_ylabel("peak-to-valley displacement (um)")
    a0.set_title(f"detectability over {det.duration_s:.2f} s (dotted: measured background)")
    if a0.get_legend_handles_labels()[0]:
        a0.legend(fontsize="small")
    fig.tight_layout()
    return fig, a0


def plot_stabilisation(diagram, *, ax=None):
    """Stabilisation diagram: pole frequency versus model order, stable poles filled."""
    fig, axs = _new_axes(1, 1, None if ax is None else [ax], figsize=(7, 4))
    a0 = axs[0, 0]
    for order, (fn, _, stable) in zip(diagram.orders, diagram.poles):
        a0.plot(fn[~stable], np.full(int(np.sum(~stable)), order), "o", mfc="none", color="0.6", ms=3)
        a0.plot(fn[stable], np.full(int(np.sum(stable)), order), "o", color="C0", ms=3)
    for fsel in diagram.natural_frequency_hz:
        a0.axvline(fsel, color="C1", lw=0.8)
    a0.set_xlabel("frequency (Hz)")
    a0.set_ylabel("model order")
    fig.tight_layout()
    return fig, a0
