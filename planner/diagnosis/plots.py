"""Plots of a diagnosis (matplotlib is imported inside the functions only).

Each function takes results, computes no physics, and returns ``(fig, axes)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_diagnosis", "plot_residual", "plot_frf", "plot_evidence", "plot_chatter"]

AXES = ("X", "Y", "Z")


def _new(ax, **kw):
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(**kw)
        return fig, ax
    return ax.figure, ax


def plot_residual(data: dict, ax=None):
    """Residual of the named cause's part, before and after the extension."""
    fig, ax = _new(ax)
    r = data["residual"]
    f = np.asarray(r["freq_hz"])
    if r["kind"] == "harmonics":
        before = np.sqrt(np.sum(np.asarray(r["before"]) ** 2, axis=0))
        after = np.sqrt(np.sum(np.asarray(r["after"]) ** 2, axis=0))
        noise = np.sqrt(np.sum(np.asarray(r["noise"]) ** 2, axis=0))
        w = 0.35 * (f[1] - f[0] if f.size > 1 else 1.0)
        ax.bar(f - w / 2, before, width=w, label="before")
        ax.bar(f + w / 2, after, width=w, label="after")
        ax.plot(f, noise, "k:", label="noise (1 sigma)")
        ax.set_ylabel("|measured - predicted| force harmonic [N]")
        ax.set_title("force harmonics: residual (validation half)")
    elif r["kind"] == "psd":
        for i, name in enumerate(AXES):
            if np.all(np.asarray(r["measured"])[i] == 0):
                continue
            ax.semilogy(f, r["before"][i], color=f"C{i}", lw=1.0, label=f"{name} before")
            ax.semilogy(f, r["after"][i], color=f"C{i}", ls="--", lw=1.0, label=f"{name} after")
        ax.set_ylabel("residual displacement PSD [m^2/Hz]")
        ax.set_title("displacement residual (validation half)")
    else:
        for i, name in enumerate(AXES):
            ax.plot(f, r["measured"][i], color=f"C{i}", lw=0.8, label=f"{name} measured")
            ax.plot(f, r["before"][i], color=f"C{i}", ls=":", lw=1.2)
            ax.plot(f, r["after"][i], color=f"C{i}", ls="--", lw=1.2)
        ax.set_ylabel("ln force PSD (dotted: before, dashed: after)")
        ax.set_title("closed-loop force spectrum (validation half)")
    ax.set_xlabel("frequency [Hz]")
    ax.legend(fontsize=7, ncol=2)
    return fig, ax


def plot_frf(data: dict, axes=None):
    """Direct receptances of the model with and without the extension, and the H1 estimate."""
    import matplotlib.pyplot as plt

    if axes is None:
        fig, axes = plt.subplots(2, 1, sharex=True)
    fig = axes[0].figure
    frf = data["frf"]
    f = frf["freq_hz"]
    for i, name in enumerate(AXES):
        axes[0].loglog(f, np.abs(frf["before"][i]), color=f"C{i}", ls=":", lw=1.2, label=f"{name} model")
        axes[0].loglog(f, np.abs(frf["after"][i]), color=f"C{i}", lw=1.0, label=f"{name} extended")
        axes[1].semilogx(f, np.degrees(np.angle(frf["before"][i])), color=f"C{i}", ls=":", lw=1.2)
        axes[1].semilogx(f, np.degrees(np.angle(frf["after"][i])), color=f"C{i}", lw=1.0)
        if "measured" in frf and np.all(np.isfinite(frf["measured"][i])):
            fm = frf["measured_freq_hz"]
            keep = (fm > 0) & (fm <= f[-1])
            axes[0].loglog(fm[keep], np.abs(frf["measured"][i][keep]), ".", color=f"C{i}", ms=2)
            axes[1].semilogx(fm[keep], np.degrees(np.angle(frf["measured"][i][keep])), ".", color=f"C{i}", ms=2)
    axes[0].set_ylabel("|G| [m/N]")
    axes[1].set_ylabel("phase [deg]")
    axes[1].set_xlabel("frequency [Hz]")
    axes[0].set_title("FRF: model (dotted), extended (solid), H1 estimate (dots)")
    axes[0].legend(fontsize=7, ncol=2)
    return fig, axes


def plot_evidence(data: dict, ax=None):
    """What named the cause: the quantity its fit turned on."""
    fig, ax = _new(ax)
    ev = data.get("evidence", {})
    kind = ev.get("kind")
    if kind == "harmonics":
        f = np.asarray(ev["freq_hz"])
        w = 0.25 * (f[1] - f[0] if f.size > 1 else 1.0)
        for k, (key, label) in enumerate((("measured", "measured"), ("before", "model"), ("after", "extended"))):
            ax.bar(f + (k - 1) * w, np.sqrt(np.sum(np.asarray(ev[key]) ** 2, axis=0)), width=w, label=label)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("force harmonic amplitude (X, Y, Z combined) [N]")
        if "sensor_gain" in ev:
            tw = ax.twinx()
            tw.plot(ev["sensor_freq_hz"], ev["sensor_gain"], "k-", lw=0.8)
            tw.set_ylabel("fitted sensor gain |H|")
    elif kind == "delay":
        ax.plot(1e3 * np.asarray(ev["delay_grid_s"]), ev["cost"])
        ax.set_xlabel("delay of the displacement [ms]")
        ax.set_ylabel("fit-half residual sum [m^2]")
    elif kind == "mode_search":
        ax.loglog(ev["freq_hz"], ev["cost"])
        ax.set_xlabel("trial mode frequency [Hz]")
        ax.set_ylabel("fit-half residual sum [m^2]")
    elif kind == "drift":
        ax.plot(100 * np.asarray(ev["grid_relative_change"]), ev["grid_cost"], "o-")
        ax.set_xlabel("relative change of the natural frequencies over the record [%]")
        ax.set_ylabel("fit-half residual sum [m^2]")
    elif kind == "pd_search":
        c = np.asarray(ev["coefficient_N_m"], dtype=float)
        keep = c > 0
        ax.semilogx(c[keep], np.asarray(ev["cost"])[keep], "o-", label="force spectrum")
        ax.axhline(ev["cost"][0], color="k", ls=":", label="no process damping")
        ax.set_xlabel("process-damping coefficient C [N/m]")
        ax.set_ylabel("fit-half log-spectral residual")
        ax.legend(fontsize=7)
    elif kind == "coupling" and "measured_full" in data.get("frf", {}):
        frf = data["frf"]
        fm = frf["measured_freq_hz"]
        keep = (fm > 0) & (fm <= frf["freq_hz"][-1])
        for k, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
            ax.loglog(fm[keep], np.abs(frf["measured_full"][a, b][keep]), ".", ms=2, color=f"C{k}",
                      label=f"{AXES[a]}{AXES[b]} measured")
            ax.loglog(frf["freq_hz"], np.abs(frf["after_full"][a, b]), color=f"C{k}",
                      label=f"{AXES[a]}{AXES[b]} extended")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("cross receptance [m/N]")
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, "no evidence recorded", ha="center", va="center", transform=ax.transAxes)
    params = ev.get("parameters", {})
    text = ", ".join(f"{k}={v:.4g}" for k, v in params.items() if isinstance(v, (int, float)))
    ax.set_title(f"evidence: {ev.get('cause', data.get('cause', ''))}\n{text}", fontsize=8)
    return fig, ax


def plot_diagnosis(diagnosis, *, figsize=(12.0, 8.5)):
    """Residual before/after, FRF (magnitude, phase) with and without the extension, evidence."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=figsize)
    grid = fig.add_gridspec(2, 2)
    ax_res = fig.add_subplot(grid[0, 0])
    sub = grid[:, 1].subgridspec(2, 1)
    ax_mag = fig.add_subplot(sub[0])
    ax_ph = fig.add_subplot(sub[1], sharex=ax_mag)
    ax_ev = fig.add_subplot(grid[1, 0])
    data = diagnosis.plot_data
    plot_residual(data, ax_res)
    plot_frf(data, [ax_mag, ax_ph])
    plot_evidence(data, ax_ev)
    fig.suptitle(f"diagnosis: {diagnosis.cause} (part {diagnosis.part}, gain {100 * diagnosis.gain:.0f} %, "
                 f"z {diagnosis.significance:.1f})")
    fig.tight_layout()
    return fig, np.array([ax_res, ax_mag, ax_ph, ax_ev])


def plot_chatter(result, ax=None, *, title: str | None = None):
    """Spectrum of a chatter detection with the masked harmonics and the line found."""
    fig, ax = _new(ax)
    f = result.freq_hz
    ax.semilogy(f, result.psd, lw=0.7, label="harmonics removed")
    m = result.harmonic_mask
    ax.semilogy(f[m], result.psd[m], ".", ms=2, color="0.6", label="masked (harmonics)")
    if np.isfinite(result.frequency_hz):
        ax.axvline(result.frequency_hz, color="C3" if result.chatter else "C2", ls="--",
                   label=f"{'chatter' if result.chatter else 'line'} {result.frequency_hz:.1f} Hz")
    ax.axvline(result.tooth_hz, color="k", ls=":", label=f"tooth {result.tooth_hz:.1f} Hz")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("PSD (sum over channels)")
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title)
    return fig, ax
