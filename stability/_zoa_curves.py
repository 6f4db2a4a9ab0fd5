"""The chatter-frequency grid and the limit curves of the zero-order approximation: the
eigenvalues of the oriented receptance along the grid and their continued branches
(:mod:`stability.zoa` holds the method's notes; this is its first half, split off by size)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool

from .oriented import _readonly as _ro, average_directional_matrix

TWO_PI = 2.0 * np.pi

#: Chatter-frequency lines per ``zeta fn`` at a mode's peak added by
#: :func:`default_chatter_frequencies` where the log grid is coarser (as ``planner.atlas._kernel``:
#: with 4 the interpolated depth that preselects the lobes is within a few per cent at the peak).
MODE_STEPS = 4.0
#: At most this many added lines on each side of a mode (a damping ratio of 1e-5 needs 25 at
#: 10 000 log lines, 1e-7 needs 43).
MODE_LINES = 48


def _mode_lines(natural_frequency_hz, damping_ratio, stiffness_N_m, f_lo: float, f_hi: float,
               n_log: int) -> np.ndarray:
    """Lines added around each mode to a log grid of ``n_log`` lines over ``f_lo .. f_hi``, Hz.

    A mode turns the eigenvalues over a band ``~2 zeta fn`` wide; a lobe starts (``Re lambda``
    crosses 0) within it and reaches its lowest depth ``zeta fn`` further on. Where the log grid's
    relative step is coarser than ``zeta / MODE_STEPS``, the lines ``fn (1 + zeta sinh(j /
    MODE_STEPS))`` are added for ``|j| <= MODE_LINES`` while their local spacing ``zeta cosh(u) /
    MODE_STEPS`` is finer than the log grid's (the same rule as the atlas kernel,
    ``planner.atlas._kernel._a_grid``, and :func:`stability.zoa_batch._k_grid`). Modes with an
    infinite stiffness add nothing. Returns the lines inside ``(f_lo, f_hi)``, unsorted.
    """
    fn = np.atleast_1d(np.asarray(natural_frequency_hz, dtype=float))
    zeta = np.atleast_1d(np.asarray(damping_ratio, dtype=float))
    stiff = np.atleast_1d(np.asarray(stiffness_N_m, dtype=float))
    step = (np.log(f_hi) - np.log(f_lo)) / (int(n_log) - 1)
    h = 1.0 / MODE_STEPS
    out = []
    for r in range(fn.size):
        ratio = step / (zeta[r] * h) if zeta[r] > 0 else np.inf
        if not stiff[r] < np.inf or ratio <= 1.0:
            continue
        m = MODE_LINES if not np.isfinite(ratio) else min(MODE_LINES, int(np.arccosh(ratio) / h))
        f = fn[r] * (1.0 + zeta[r] * np.sinh(np.arange(-m, m + 1) * h))
        out.append(f[(f > f_lo) & (f < f_hi)])
    return np.concatenate(out) if out else np.zeros(0)


def _merge_lines(log_grid: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """``log_grid`` and ``extra`` lines sorted, a line within 1e-12 (relative) of the line before
    it dropped."""
    if extra.size == 0:
        return log_grid
    f = np.sort(np.concatenate([log_grid, extra]))
    keep = np.ones(f.size, dtype=bool)
    keep[1:] = f[1:] > f[:-1] * (1.0 + 1e-12)
    return f[keep]


def default_chatter_frequencies(structure, *, n_freq: int = 10_000) -> np.ndarray:
    """Chatter-frequency grid, Hz: the table's own frequencies for a measured FRF, otherwise
    ``n_freq`` log-spaced points from a third of the lowest to three times the highest natural
    frequency (constant relative resolution, so a 10 Hz robot mode and a 1.4 kHz spindle mode are
    resolved alike) plus, around a mode too lightly damped for that resolution, the lines of
    :func:`_mode_lines` (none at 10 000 lines unless ``zeta < 2.6e-3``; at 2 000, ``zeta < 1.3e-2``)."""
    if hasattr(structure, "natural_frequency_hz"):
        fn = np.asarray(structure.natural_frequency_hz, dtype=float)
        f_lo, f_hi = fn.min() / 3.0, fn.max() * 3.0
        extra = _mode_lines(fn, structure.damping_ratio, structure.stiffness_N_m, f_lo, f_hi, int(n_freq))
        return _merge_lines(np.geomspace(f_lo, f_hi, int(n_freq)), extra)
    if hasattr(structure, "freq_hz"):
        f = np.asarray(structure.freq_hz, dtype=float)
        return f[f > 0]
    raise TypeError("structure must be a ModalModel or an FRFTable (with .receptance(freq_hz))")


@dataclass(frozen=True)
class ZOACurves:
    """The ZOA critical depth and phase per chatter frequency, two eigenvalue branches.

    Attributes
    ----------
    freq_hz : ndarray, shape (n_freq,)
        Chatter frequencies, Hz.
    depth_m : ndarray, shape (2, n_freq)
        Critical axial depth ``1 / (2 Re lambda)``, m; ``inf`` where ``Re lambda <= 0``.
    phase_rad : ndarray, shape (2, n_freq)
        ``eps`` in (0, 2 pi): the phase between inner and outer modulation is ``eps + 2 pi k``.
    teeth : int
    eigenvalue : ndarray of complex, shape (2, n_freq)
        The eigenvalues ``lambda`` of ``G(w) B0``, 1/m, in the order of ``depth_m``.
    continued_row : ndarray of int, shape (n_freq,)
        Row of ``depth_m``/``phase_rad``/``eigenvalue`` that holds, at each frequency, the
        eigenvalue continued smoothly in frequency from branch 0 at the lowest frequency (the other
        row continues branch 1); see :meth:`continued`.

    Notes
    -----
    Rows 0 and 1 are sorted at every frequency (row 0 has the larger ``Re lambda``, so the smaller
    critical depth): ``depth_m.min(axis=0) == depth_m[0]``. A lobe follows one eigenvalue, which
    moves from one sorted row to the other wherever the two real parts cross; the lobes are the
    curves of :meth:`continued` (the frequency grid is taken in increasing order).
    """

    freq_hz: np.ndarray
    depth_m: np.ndarray
    phase_rad: np.ndarray
    teeth: int
    eigenvalue: np.ndarray
    continued_row: np.ndarray

    def rpm(self, k: int) -> np.ndarray:
        """Spindle speed of lobe ``k`` at every chatter frequency, shape (2, n_freq), rpm (rows as
        ``phase_rad``: sorted, not continued)."""
        return 60.0 * self.freq_hz / (self.teeth * (self.phase_rad / TWO_PI + k))

    def continued(self) -> tuple[np.ndarray, np.ndarray]:
        """Depth, m, and phase, rad, of the two continued branches, each shape (2, n_freq).

        Branch ``c`` is one eigenvalue followed continuously in frequency, so its depth and phase
        are continuous wherever its real part stays positive; lobe ``k`` of branch ``c`` is the
        curve ``(60 f / (N (phase[c] / 2 pi + k)), depth[c])``.
        """
        rows = np.stack([self.continued_row, 1 - self.continued_row]).astype(np.intp)
        return (np.take_along_axis(np.asarray(self.depth_m), rows, axis=0),
                np.take_along_axis(np.asarray(self.phase_rad), rows, axis=0))


def _continued_row(freq_hz: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Row of ``lam`` (shape (2, n), sorted per frequency) holding the continuation of branch 0.

    ``lambda_0 - lambda_1`` is ``+-2 sqrt(tr^2/4 - det)``, analytic in frequency away from a double
    eigenvalue; its sign is chosen so that it turns by less than 90 degrees between neighbouring
    (increasing) frequencies, which is continuity as long as the grid resolves the eigenvalues.
    """
    order = np.argsort(freq_hz, kind="stable")
    gap = lam[0, order] - lam[1, order]
    flip = (np.conj(gap[:-1]) * gap[1:]).real < 0
    row = np.empty(freq_hz.size, dtype=np.int8)
    row[order] = np.concatenate([[0], np.cumsum(flip) % 2])
    return row


class _Problem:
    """Evaluates the two eigenvalue branches at any chatter frequency (the receptance is re-evaluated,
    so refinement is exact for a modal model and follows the table's interpolation for an FRF)."""

    def __init__(self, structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients):
        self.structure, self.cut = structure, cut
        self.teeth = int(tool.teeth)
        self.b0 = average_directional_matrix(tool, cut, coefficients)
        self._frame = np.asarray(cut.frame)  # built once: the solvers ask for a few lines at a time
        self._grid_f = self._grid_gap = None

    def follow(self, curves: "ZOACurves") -> None:
        """Take the continued branches of ``curves``: at any frequency, branch ``c`` is then the
        root whose ``lambda_0 - lambda_1`` points along the gap interpolated from the grid."""
        order = np.argsort(curves.freq_hz, kind="stable")
        lam = np.asarray(curves.eigenvalue)[:, order]
        sign = 1 - 2 * np.asarray(curves.continued_row, dtype=float)[order]
        self._grid_f = np.asarray(curves.freq_hz, dtype=float)[order]
        self._grid_gap = (lam[0] - lam[1]) * sign

    def eigenvalues(self, freq_hz) -> np.ndarray:
        """Eigenvalues of ``G(w) B0``, shape (2, n), branch 0 with the larger real part."""
        # oriented_receptance (stability.oriented.cut_receptance's rows f, n) with the frame kept
        g = np.asarray(self.structure.receptance(np.atleast_1d(np.asarray(freq_hz, dtype=float))))
        g = np.einsum("ip,pqk,jq->ijk", self._frame, g, self._frame)[:2]  # (2, 3, n)
        m = np.einsum("ijk,jl->kil", g, self.b0)  # (n, 2, 2)
        tr = m[:, 0, 0] + m[:, 1, 1]
        det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
        half = tr / 2.0
        disc = np.sqrt(half * half - det)
        # take the root without cancellation first, the other from the product (det = l1 l2)
        disc = np.where((np.conj(half) * disc).real < 0, -disc, disc)
        l1 = half + disc
        with np.errstate(invalid="ignore", divide="ignore"):
            l2 = np.where(l1 != 0, det / l1, half - disc)
        swap = l2.real > l1.real
        return np.stack([np.where(swap, l2, l1), np.where(swap, l1, l2)])

    @staticmethod
    def depth_phase(lam):
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(lam.real > 0, 0.5 / lam.real, np.inf)
        phase = np.pi + 2.0 * np.arctan2(lam.imag, lam.real)
        return depth, phase

    def branch_eigenvalue(self, c, freq_hz) -> np.ndarray:
        """Eigenvalue of continued branch ``c`` (array, one per frequency) at ``freq_hz`` (call
        :meth:`follow` first)."""
        f = np.asarray(freq_hz, dtype=float)
        lam = self.eigenvalues(f)
        gap = self._grid_gap
        ref = np.interp(f, self._grid_f, gap.real) + 1j * np.interp(f, self._grid_f, gap.imag)
        sorted_first = (np.conj(ref) * (lam[0] - lam[1])).real >= 0  # row 0 continues branch 0
        return np.where(sorted_first == (np.asarray(c) == 0), lam[0], lam[1])

    def branch(self, c, freq_hz):
        """Depth and phase of continued branch ``c`` (array, one per frequency) at ``freq_hz``
        (call :meth:`follow` first)."""
        return self.depth_phase(self.branch_eigenvalue(c, freq_hz))
