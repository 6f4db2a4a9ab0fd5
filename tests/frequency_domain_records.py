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


def physical_superposition(mass, damping, stiffness, sample_rate_hz: float, duration_s: float, seed: int, *,
                           derivative: int = 2, noise: float = 0.02) -> np.ndarray:
    """As :func:`modal_superposition` for the physical system ``M x'' + C x' + K x = f`` (3 x 3
    matrices): the receptance ``(K - w^2 M + i w C)^-1`` solved at every bin, exact whatever the
    damping (a ``C`` that is not a combination of ``M`` and ``K`` gives complex modes, which no
    real-mode superposition holds). The same draws as :func:`modal_superposition`, so a diagonal
    system gives its record."""
    rng = np.random.default_rng(seed)
    n = int(round(sample_rate_hz * duration_s))
    f = np.fft.rfftfreq(n, 1 / sample_rate_hz)
    w = 2 * np.pi * f
    force = rng.standard_normal((3, f.size)) + 1j * rng.standard_normal((3, f.size))
    m, c, k = (np.asarray(a, dtype=float) for a in (mass, damping, stiffness))
    x = np.linalg.solve(k[None] - w[:, None, None] ** 2 * m[None] + 1j * w[:, None, None] * c[None],
                        force.T[:, :, None])[:, :, 0].T
    y = np.fft.irfft((1j * w) ** derivative * x, n=n, axis=1)
    return y + noise * np.std(y) * rng.standard_normal(y.shape)


def physical_modes(mass, damping, stiffness):
    """Natural frequencies (Hz) and damping ratios of ``M x'' + C x' + K x = 0``, from the poles
    ``lambda`` of its state matrix (``|lambda| / 2 pi``, ``-Re lambda / |lambda|``), in order of
    frequency, and each mode's complexity ``1 - |sum psi^2| / sum |psi|^2`` (0: a real mode)."""
    m, c, k = (np.asarray(a, dtype=float) for a in (mass, damping, stiffness))
    n = m.shape[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(m, k), -np.linalg.solve(m, c)]])
    lam, vec = np.linalg.eig(a)
    up = lam.imag > 0
    lam, psi = lam[up], vec[:n, up]
    order = np.argsort(np.abs(lam))
    lam, psi = lam[order], psi[:, order]
    complexity = 1 - np.abs(np.sum(psi ** 2, axis=0)) / np.sum(np.abs(psi) ** 2, axis=0)
    return np.abs(lam) / (2 * np.pi), -lam.real / np.abs(lam), complexity


def gyroscopic_pair(g: float):
    """Unit masses along X, Y, Z at 20, 23 and 40 Hz (3 % damping each), X and Y coupled by the
    skew velocity term ``g`` (1/s) of a spinning body: ``C = diag(2 zeta w) + g [[0, 1], [-1, 0]]``.
    The pair whirls (complexity 0.03 / 0.04 at g = 5, 0.10 / 0.13 at 10, 0.28 / 0.35 at 20) and
    moves apart (19.95 / 23.06, 19.82 / 23.21, 19.37 / 23.75 Hz) with its damping unchanged."""
    w = 2 * np.pi * np.array([20.0, 23.0, 40.0])
    skew = g * np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    return np.eye(3), np.diag(2 * 0.03 * w) + skew, np.diag(w ** 2)
