"""A measured (or estimated) receptance FRF matrix on a frequency grid.

Stored as python-control stores frequency data: ``(n_out, n_in, n_freq)``, here always 3 x 3 in the
machine frame (X, Y, Z), with a mask of which entries were actually measured. Receptance in m/N.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["FRFTable", "AXES"]

AXES = ("X", "Y", "Z")


@dataclass(frozen=True)
class FRFTable:
    """Receptance FRFs, machine frame.

    Parameters
    ----------
    freq_hz : ndarray, shape (n_freq,)
        Increasing frequencies, Hz.
    receptance_m_N : ndarray, shape (3, 3, n_freq), complex
        ``G[out, in, k]``; entries not measured are 0 and ``measured[out, in]`` is False.
    measured : ndarray of bool, shape (3, 3)
    coherence : ndarray, shape (3, 3, n_freq), optional
    meta : dict, optional
        Free provenance (source file, estimator, averages).
    """

    freq_hz: np.ndarray
    receptance_m_N: np.ndarray
    measured: np.ndarray
    coherence: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        f = np.array(self.freq_hz, dtype=float).ravel()
        g = np.array(self.receptance_m_N, dtype=complex).reshape(3, 3, f.size)
        m = np.array(self.measured, dtype=bool).reshape(3, 3)
        for name, a in (("freq_hz", f), ("receptance_m_N", g), ("measured", m)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if self.coherence is not None:
            c = np.array(self.coherence, dtype=float).reshape(3, 3, f.size)
            c.setflags(write=False)
            object.__setattr__(self, "coherence", c)

    @classmethod
    def from_entries(cls, freq_hz, entries: dict[str, np.ndarray], **kwargs) -> "FRFTable":
        """Build from named entries such as ``{"XX": G_xx, "YY": G_yy}`` (output axis then input)."""
        f = np.asarray(freq_hz, dtype=float)
        g = np.zeros((3, 3, f.size), dtype=complex)
        m = np.zeros((3, 3), dtype=bool)
        for key, values in entries.items():
            i, j = AXES.index(key[0].upper()), AXES.index(key[1].upper())
            g[i, j] = values
            m[i, j] = True
        return cls(f, g, m, **kwargs)

    @classmethod
    def from_model(cls, model, freq_hz, *, entries=("XX", "YY", "ZZ")) -> "FRFTable":
        """Sample a :class:`~oma.modal.ModalModel` (anything with ``receptance(freq_hz)``)."""
        g = model.receptance(freq_hz)
        return cls.from_entries(
            freq_hz, {e: g[AXES.index(e[0]), AXES.index(e[1])] for e in entries}
        )

    @classmethod
    def merge(cls, tables: "list[FRFTable]") -> "FRFTable":
        """One table from several (e.g. an XX and a YY file), on the first table's frequencies.

        Entries measured in more than one table are taken from the first; the others are linearly
        interpolated onto the first grid (see :meth:`receptance`).
        """
        first = tables[0]
        g = np.array(first.receptance_m_N)
        m = np.array(first.measured)
        for t in tables[1:]:
            other = t.receptance(first.freq_hz)
            new = t.measured & ~m
            g[new] = other[new]
            m |= new
        return cls(first.freq_hz, g, m, meta={"merged": [t.meta for t in tables]})

    def entry(self, key: str) -> np.ndarray:
        """One entry by name, e.g. ``"XY"`` (output X, input Y)."""
        i, j = AXES.index(key[0].upper()), AXES.index(key[1].upper())
        if not self.measured[i, j]:
            raise KeyError(f"FRF entry {key} was not measured")
        return self.receptance_m_N[i, j]

    @property
    def entry_names(self) -> list[str]:
        """Names of the measured entries, row-major (``XX, XY, ...``)."""
        return [AXES[i] + AXES[j] for i in range(3) for j in range(3) if self.measured[i, j]]

    def receptance(self, freq_hz) -> np.ndarray:
        """Linear interpolation of the table at other frequencies, (3, 3, n), m/N.

        Gives a measured FRF the same interface as a modal model; outside the measured band the
        end values are held (callers that care should check the band).
        """
        f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        out = np.zeros((3, 3, f.size), dtype=complex)
        for i in range(3):
            for j in range(3):
                if self.measured[i, j]:
                    g = self.receptance_m_N[i, j]
                    out[i, j] = np.interp(f, self.freq_hz, g.real) + 1j * np.interp(f, self.freq_hz, g.imag)
        return out
