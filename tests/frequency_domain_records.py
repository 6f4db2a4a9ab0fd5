"""Records synthesised in the frequency domain by modal superposition (nothing of robomill's
time-domain simulator): a white force on each axis through real modes, periodic over the record
(so the Whittle likelihood's model is exact), with white sensor noise. Shared by the tests and the
benchmarks of the output-only refinement on lightly damped modes."""

from __future__ import annotations

import numpy as np


def modal_superposition(modes, sample_rate_hz: float, duration_s: float, seed: int, *, derivative: int = 2,
                        noise: float = 0.02, force_slope: float = 0.0) -> np.ndarray:
    """Response (3, n) to a white force on each axis of the modes ``(frequency Hz, damping ratio,
    direction (3,))`` (unit modal mass: the receptance ``u u^T / (w_r^2 - w^2 + 2 i zeta w_r w)``),
    as displacement (``derivative`` 0) or its derivatives (1, 2: acceleration), plus white noise of
    ``noise`` times the response's sd. ``force_slope`` colours the force: its power spectrum goes
    as ``f^force_slope`` (0: white; -1: pink), referred to 1 Hz, zero at 0 Hz."""
    rng = np.random.default_rng(seed)
    n = int(round(sample_rate_hz * duration_s))
    f = np.fft.rfftfreq(n, 1 / sample_rate_hz)
    force = rng.standard_normal((3, f.size)) + 1j * rng.standard_normal((3, f.size))
    if force_slope:
        with np.errstate(divide="ignore"):
            colour = np.where(f > 0, np.abs(f) ** (0.5 * force_slope), 0.0)
        force = force * colour[None, :]
    x = np.zeros((3, f.size), dtype=complex)
    for fr, z, u in modes:
        u = np.asarray(u, dtype=float) / np.linalg.norm(u)
        x += u[:, None] * (u @ force)[None, :] / (1 - (f / fr) ** 2 + 2j * z * f / fr) / (2 * np.pi * fr) ** 2
    y = np.fft.irfft((2j * np.pi * f) ** derivative * x, n=n, axis=1)
    return y + noise * np.std(y) * rng.standard_normal(y.shape)
