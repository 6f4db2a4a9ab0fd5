"""The modal model of the tool-tip dynamics at one pose (``robomill-modal/1``).

Receptance matrix in the machine frame (formats.md), ``w`` in rad/s, ``u_r`` the unit direction of
mode ``r``::

    G(w) = sum_r u_r u_r^T / (k_r (1 - (w/w_r)^2 + 2 i zeta_r w/w_r)) + residual_compliance

Each mode is a single-degree-of-freedom oscillator ``m_r q'' + c_r q' + k_r q = u_r . F`` with
``m_r = k_r / w_r^2``, ``c_r = 2 zeta_r sqrt(k_r m_r)``; the tool tip moves ``u_r q``. This module
is the one place where Hz becomes rad/s for python-control.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._arrays import readonly as _readonly

__all__ = ["ModalModel", "hz_to_rad_s", "in_series"]


def hz_to_rad_s(freq_hz):
    """Frequency in Hz to angular frequency in rad/s."""
    return 2.0 * np.pi * np.asarray(freq_hz, dtype=float)


@dataclass(frozen=True)
class ModalModel:
    """Modal parameters of the tool tip, machine frame, SI.

    Parameters
    ----------
    natural_frequency_hz : array_like, shape (n_modes,)
        Undamped natural frequencies, Hz.
    damping_ratio : array_like, shape (n_modes,)
        Viscous damping ratios (0.05 = 5 %).
    stiffness_N_m : array_like, shape (n_modes,)
        Modal stiffness along the mode direction, N/m.
    directions : array_like, shape (n_modes, 3)
        Mode directions; normalised to unit length here.
    residual_compliance_m_N : array_like, shape (3, 3), optional
        Static flexibility of modes out of band, m/N.
    joints_deg : array_like, shape (6,), optional
        Robot pose the model belongs to, degrees (as in the file).
    source : dict, optional
        Provenance (method, records, fit error).
    """

    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    stiffness_N_m: np.ndarray
    directions: np.ndarray
    residual_compliance_m_N: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    joints_deg: np.ndarray | None = None
    source: dict[str, Any] | None = None

    def __post_init__(self):
        fn = np.atleast_1d(np.asarray(self.natural_frequency_hz, dtype=float))
        n = fn.size
        zeta = np.atleast_1d(np.asarray(self.damping_ratio, dtype=float))
        k = np.atleast_1d(np.asarray(self.stiffness_N_m, dtype=float))
        u = np.asarray(self.directions, dtype=float).reshape(n, 3)
        if zeta.shape != (n,) or k.shape != (n,):
            raise ValueError(
                f"modal parameters have mismatched lengths: {n} frequencies, "
                f"{zeta.size} damping ratios, {k.size} stiffnesses"
            )
        norms = np.linalg.norm(u, axis=1)
        if np.any(norms == 0):
            raise ValueError("a mode direction is the zero vector")
        object.__setattr__(self, "natural_frequency_hz", _readonly(fn))
        object.__setattr__(self, "damping_ratio", _readonly(zeta))
        object.__setattr__(self, "stiffness_N_m", _readonly(k))
        # Directions already of unit length (to rounding) are kept as given, so that building a
        # model from another model's directions (e.g. a model read back from its file) is exact.
        norms = np.where(np.abs(norms - 1.0) <= 4 * np.finfo(float).eps, 1.0, norms)
        object.__setattr__(self, "directions", _readonly(u / norms[:, None]))
        object.__setattr__(
            self, "residual_compliance_m_N", _readonly(np.reshape(self.residual_compliance_m_N, (3, 3)))
        )
        if self.joints_deg is not None:
            object.__setattr__(self, "joints_deg", _readonly(np.ravel(self.joints_deg)))

    # ----------------------------------------------------------------------------- derived
    @property
    def n_modes(self) -> int:
        return int(self.natural_frequency_hz.size)

    @property
    def omega_rad_s(self) -> np.ndarray:
        """Natural angular frequencies, rad/s."""
        return hz_to_rad_s(self.natural_frequency_hz)

    @property
    def modal_mass_kg(self) -> np.ndarray:
        """``m_r = k_r / w_r^2``, kg."""
        return self.stiffness_N_m / self.omega_rad_s**2

    @property
    def static_compliance_m_N(self) -> np.ndarray:
        """``G(0)``, shape (3, 3), m/N."""
        return np.einsum("ri,rj,r->ij", self.directions, self.directions, 1.0 / self.stiffness_N_m) + (
            self.residual_compliance_m_N
        )

    def receptance(self, freq_hz) -> np.ndarray:
        """Receptance matrix ``G``, shape (3, 3, n_freq), m/N, at frequencies in Hz."""
        f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        ratio = f[None, :] / self.natural_frequency_hz[:, None]  # (n_modes, n_freq)
        modal = 1.0 / (self.stiffness_N_m[:, None] * (1.0 - ratio**2 + 2j * self.damping_ratio[:, None] * ratio))
        g = np.einsum("ri,rj,rf->ijf", self.directions, self.directions, modal)
        return g + self.residual_compliance_m_N[:, :, None]

    def with_modes(self, **changes) -> "ModalModel":
        """A copy with some fields replaced."""
        from dataclasses import replace

        return replace(self, **changes)

    # ------------------------------------------------------------------ python-control boundary
    def to_statespace(self):
        """The model as a ``control.StateSpace`` with 3 force inputs and 3 displacement outputs.

        States are the modal coordinates and their velocities, ``[q_1..q_n, q'_1..q'_n]``;
        the residual compliance is the feed-through ``D``. Time in seconds.
        """
        import control

        n = self.n_modes
        w = self.omega_rad_s
        m = self.modal_mass_kg
        zeta = self.damping_ratio
        a = np.zeros((2 * n, 2 * n))
        a[:n, n:] = np.eye(n)
        a[n:, :n] = -np.diag(w**2)
        a[n:, n:] = -np.diag(2.0 * zeta * w)
        b = np.zeros((2 * n, 3))
        b[n:, :] = self.directions / m[:, None]
        c = np.zeros((3, 2 * n))
        c[:, :n] = self.directions.T
        return control.ss(a, b, c, np.array(self.residual_compliance_m_N), inputs=["Fx", "Fy", "Fz"],
                          outputs=["x", "y", "z"])

    @classmethod
    def from_statespace(cls, sys, **kwargs) -> "ModalModel":
        """Recover the modal model from a 3x3 ``control.StateSpace`` of proportionally damped modes.

        Each complex pole pair gives a natural frequency and damping ratio; its residue matrix
        ``R_r`` (the ``1/s`` coefficient of the pair, rank one: ``R_r = u_r u_r^T / (m_r)``) gives the
        direction and modal mass. The feed-through is the residual compliance. Extra keyword
        arguments go to the constructor (``joints_deg``, ``source``).
        """
        a, b, c, d = (np.asarray(x, dtype=float) for x in (sys.A, sys.B, sys.C, sys.D))
        if b.shape[1] != 3 or c.shape[0] != 3:
            raise ValueError(f"expected a system with 3 inputs and 3 outputs, found {c.shape[0]}x{b.shape[1]}")
        lam, v = np.linalg.eig(a)
        vinv = np.linalg.inv(v)
        keep = np.imag(lam) > 0
        freqs, zetas, stiff, dirs = [], [], [], []
        for i in np.flatnonzero(keep):
            s = lam[i]
            wn = abs(s)
            zeta = -s.real / wn
            # residue of the pole: C v_i w_i^T B; for a pair, G ~ R/(s - p) + conj(R)/(s - conj p),
            # and for a real mode R = u u^T / (m * 2 i w_d).
            res = np.outer(c @ v[:, i], vinv[i, :] @ b)
            wd = s.imag
            mat = np.real(res * 2j * wd)  # = u u^T / m
            evals, evecs = np.linalg.eigh((mat + mat.T) / 2)
            j = int(np.argmax(np.abs(evals)))
            u = evecs[:, j]
            inv_m = evals[j]
            k = wn**2 / inv_m
            sign = np.sign(u[np.argmax(np.abs(u))])
            freqs.append(wn / (2 * np.pi))
            zetas.append(zeta)
            stiff.append(k)
            dirs.append(u * sign)
        order = np.argsort(freqs)
        return cls(
            natural_frequency_hz=np.array(freqs)[order],
            damping_ratio=np.array(zetas)[order],
            stiffness_N_m=np.array(stiff)[order],
            directions=np.array(dirs).reshape(-1, 3)[order],
            residual_compliance_m_N=d,
            **kwargs,
        )


def in_series(first: ModalModel, *others: ModalModel, **kwargs) -> ModalModel:
    """Structures in series (e.g. robot arm and spindle/tool): their receptances add, so the modal
    sums concatenate and the residual compliances add. Keyword arguments go to the constructor
    (default ``joints_deg`` from the first model)."""
    models = (first, *others)
    kwargs.setdefault("joints_deg", first.joints_deg)
    return ModalModel(
        np.concatenate([m.natural_frequency_hz for m in models]),
        np.concatenate([m.damping_ratio for m in models]),
        np.concatenate([m.stiffness_N_m for m in models]),
        np.vstack([m.directions for m in models]),
        residual_compliance_m_N=sum(m.residual_compliance_m_N for m in models),
        **kwargs,
    )
