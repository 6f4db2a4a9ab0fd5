"""Records of the paper's cell whose modes drift during the cut (DOMAIN.md's ``pose_drift``), made
without robomill's simulator: each modal equation integrated exactly over every sample with that
sample's frequency. Shared by the tests and ``benchmarks/bench_oma_drift.py``."""

from __future__ import annotations

import numpy as np
from numba import njit

from oma.record import Channel, Record
from oma.synthetic import (PAPER_BACKGROUND_VARIANCE_N2, band_limited_milling_force, paper_like_cut,
                           paper_like_material, paper_like_model, paper_like_tool)

PREROLL_S = 3.0


@njit(cache=True)
def _modal_acceleration(w, zeta, force, dt):
    """Acceleration of ``q'' + 2 zeta w q' + w^2 q = force`` (per unit modal mass), ``w`` (n,) rad/s
    at each sample: the exact transition of the sample's frozen oscillator, the force held."""
    q = 0.0
    v = 0.0
    out = np.empty(w.size)
    for i in range(w.size):
        wi = w[i]
        wd = wi * np.sqrt(1.0 - zeta * zeta)
        e = np.exp(-zeta * wi * dt)
        c = np.cos(wd * dt)
        s = np.sin(wd * dt)
        p11 = e * (c + zeta * wi / wd * s)
        p12 = e * s / wd
        p21 = -e * wi * wi / wd * s
        p22 = e * (c - zeta * wi / wd * s)
        out[i] = force[i] - 2.0 * zeta * wi * v - wi * wi * q
        q, v = (p11 * q + p12 * v + (-2.0 * zeta * wi * p12 - (p22 - 1.0)) / (wi * wi) * force[i],
                p21 * q + p22 * v + p12 * force[i])
    return out


def drifting_record(change: float, seed: int, *, duration_s: float = 20.0, sample_rate_hz: float = 1000.0):
    """A drifting record, and the frequencies' scale at each of its samples."""
    model, tool, cut, material = paper_like_model(), paper_like_tool(), paper_like_cut(2700.0), paper_like_material()
    rng = np.random.default_rng(seed)
    fs = sample_rate_hz
    n_pre, n = int(PREROLL_S * fs), int(duration_s * fs)
    t = (np.arange(n_pre + n) - n_pre) / fs
    force = band_limited_milling_force(tool, cut, material.cutting_coefficients, t, 0.5 * fs, runout_m=None)
    force += np.sqrt(np.asarray(PAPER_BACKGROUND_VARIANCE_N2))[:, None] * rng.standard_normal(force.shape)
    scale = 1.0 + change * np.clip(t, 0.0, None) / duration_s
    y = np.zeros((3, t.size))
    for f0, zeta, k, u in zip(model.natural_frequency_hz, model.damping_ratio, model.stiffness_N_m,
                              model.directions):
        w0 = 2 * np.pi * f0
        y += np.outer(u, _modal_acceleration(w0 * scale, float(zeta), (u @ force) * w0 ** 2 / k, 1.0 / fs))
    channels = tuple(Channel(a.lower(), "acceleration", a, "m/s2") for a in "XYZ")
    rec = Record(fs, channels, y[:, n_pre:], tool, cut, material=material, name=f"drift {change:+g} seed {seed}")
    return rec, scale[n_pre:]
