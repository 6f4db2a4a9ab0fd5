"""Semi-discretization (SDM) stability of milling with a modal model.

First-order semi-discretization of Insperger & Stepan (Int. J. Numer. Meth. Eng. 61, 2004;
*Semi-Discretization for Time-Delay Systems*, Springer 2011). The modal equations in the cutting
frame (formats.md force model, :mod:`stability.oriented`)::

    eta'' + 2 Z W eta' + W^2 eta = M^-1 U3^T [ K(t) (x(t) - x(t - T)) - (C / V) P(t) x'(t) ]
    x = U eta     (tool-tip displacement in f, n)

with ``K(t)`` the time-varying directional matrix of the whole depth (helix integrated exactly
over ``z``: the limit of infinitely many axial slices), ``P(t) = sum_j int_0^a r r^T g dz`` and
``C`` the process-damping coefficient (N/m; ``V = pi D n / 60``), are semi-discretized over the
tooth period ``T`` in ``m`` steps: on step ``i`` the periodic coefficients are replaced by their
exact step means and the delayed displacement by the straight line between its values at the step
ends; each step is then solved exactly (matrix exponential of an augmented matrix). The state
after one period is a linear map of the state and the displacement history at its start: the
monodromy matrix. The cut is stable when its spectral radius is below one.

Speed (measured in ``benchmarks/bench_lobes.py`` against the straightforward dense product):

* the monodromy is built by propagating only the ``2 n x N`` block of the current state
  (``N = 2 n + d m``) through the steps and recording the ``d`` history rows once, never forming
  the ``N x N`` step matrices (:func:`dense_monodromy` is that straightforward construction), in
  a loop compiled by numba (the project's dependency for the simulator);
* all exponentials of one step count are computed in one batched call; steps with no tooth
  engaged share one;
* history entries that no engaged step reads are zero columns of the monodromy and are dropped
  before the eigenvalue problem (at low radial immersion most of them);
* the spectral radius comes from a short Arnoldi iteration (the monodromy's spectrum decays fast:
  20 Krylov vectors give the dominant multiplier to rounding), checked by its residual, with LAPACK
  as the fallback;
* everything is vectorised over speeds: all speeds sharing a step count are searched together,
  one batched exponential, assembly and Arnoldi per round of the search;
* the limit depth at each speed is found by a bracketing root search on ``log`` of the spectral
  radius (bracketing by factors of 2 from a guess, then the Illinois variant of regula falsi,
  then a ladder of depths below the boundary probed for islands of instability),
  never a depth grid.

Process damping: per unit height an engaged tooth adds the force ``-(C / V) (v . r) r`` on the
tool, ``r = sin(phi) f + cos(phi) n`` and ``v`` the tool velocity: it opposes motion into the cut
surface (Budak & Tunc, CIRP Annals 58, 2009; Altintas, Eynian & Onozuka, CIRP Annals 57, 2008);
the simulator (:mod:`stability.simulate`) uses the same model.

The residual compliance of a modal model (static flexibility of out-of-band modes) has no state
and is left out here, with a warning.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, replace

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool

from ._sdm_kernels import _assemble_loop, _compiled, _dominant, _dominant_matrix_free, _expm_batch
from .oriented import damping_coefficients, dynamic_coefficients, engaged_axial_step_mean, helix_lag_per_m

__all__ = [
    "SDMProblem",
    "Multipliers",
    "SpeedLimit",
    "Resolution",
    "as_modal_model",
    "steps_per_period",
    "choose_resolution",
    "dense_monodromy",
]

log = logging.getLogger(__name__)
TWO_PI = 2.0 * np.pi
#: Reduced monodromy size from which :meth:`SDMProblem._radii` finds the dominant multiplier
#: without forming the matrix. Measured on the kr500 example's two tool modes (one evaluation of
#: 3 depths): as fast as the dense path at N = 40-100 (8 000-4 000 rpm), 1.3x faster at N = 180
#: (2 000 rpm), ~3x at N = 500-1 000 (1 000-500 rpm), 45x where the dense path fell back to LAPACK.
MATRIX_FREE_MIN_SIZE = 64


def as_modal_model(structure):
    """The structure as a :class:`~oma.modal.ModalModel`; SDM needs states, not sampled FRFs.

    Accepts a ``ModalModel`` or a 3x3 ``control.StateSpace`` (converted with
    ``ModalModel.from_statespace``). Raises ``ValueError`` for an FRF table.
    """
    if hasattr(structure, "natural_frequency_hz") and hasattr(structure, "directions"):
        return structure
    if hasattr(structure, "A") and hasattr(structure, "B"):
        from oma.modal import ModalModel

        return ModalModel.from_statespace(structure)
    if hasattr(structure, "freq_hz"):
        raise ValueError(
            "method 'sdm' needs a modal model (state space); a measured FRF table supports only "
            "method 'zoa' and the forced-vibration prediction. Fit a modal model to the FRF first."
        )
    raise TypeError(f"structure must be a ModalModel, found {type(structure).__name__}")


# ----------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Multipliers:
    """Characteristic multipliers of one cut at one depth.

    Attributes
    ----------
    spectral_radius : float
        ``max |mu|``; stable below 1.
    dominant : complex
        The multiplier of largest modulus (``Im mu >= 0`` of a pair).
    kind : str
        ``'flip'`` (real, negative: period doubling), ``'fold'`` (real, positive) or ``'hopf'``
        (complex pair: quasi-periodic chatter).
    size : int
        Dimension of the (reduced) monodromy matrix.
    """

    spectral_radius: float
    dominant: complex
    kind: str
    size: int


def _classify(mu: complex) -> str:
    # a real multiplier comes out of LAPACK/Arnoldi with an imaginary part at rounding level; a
    # complex pair near the real axis keeps one many orders larger than 1e-9 relative
    if abs(mu.imag) <= 1e-9 * abs(mu):
        return "flip" if mu.real < 0 else "fold"
    return "hopf"


#: Depths probed below a boundary for instability islands: ``ISLAND_RUNGS`` rungs, each
#: ``ISLAND_RATIO`` times the one above (down to 0.7^4 = 0.24 of the boundary). An island narrower
#: than a factor 1 / 0.7 in depth can still be missed.
ISLAND_RATIO, ISLAND_RUNGS = 0.7, 4


@dataclass(frozen=True)
class SpeedLimit:
    """Stability limit at one spindle speed (see :meth:`SDMProblem.limits`).

    ``kind`` and ``chatter_frequency_hz`` describe the dominant multiplier just above the limit;
    ``evaluations`` counts the spectral radii computed for this speed.
    """

    spindle_rpm: float
    depth_limit_m: float
    kind: str
    chatter_frequency_hz: float
    steps: int
    evaluations: int


class SDMProblem:
    """One modal model and one cut, prepared for semi-discretization.

    Parameters
    ----------
    structure : ModalModel or control.StateSpace
        Tool-tip modes, machine frame.
    tool, cut, coefficients
        Teeth, diameter, helix; engagement and cutting frame; ``Ktc``, ``Krc``, ``Kac`` (N/m^2).
    process_damping_N_m : float
        Process-damping coefficient ``C``, N/m (0 for none).
    """

    def __init__(self, structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients,
                 *, process_damping_N_m: float = 0.0):
        model = as_modal_model(structure)
        if np.any(np.asarray(model.residual_compliance_m_N) != 0):
            warnings.warn("SDM ignores the residual compliance of the modal model (it has no states)",
                          stacklevel=3)
        if not process_damping_N_m >= 0:
            raise ValueError(f"process_damping_N_m must be >= 0, found {process_damping_N_m}")
        self.model, self.tool, self.cut, self.coefficients = model, tool, cut, coefficients
        self.process_damping_N_m = float(process_damping_N_m)
        n = model.n_modes
        self.n = n
        u3 = cut.frame @ model.directions.T  # (3, n): mode shapes in f, n, a
        self.u = u3[:2]  # (2, n)
        # delayed coordinate xi = S eta (d values per history step), x = U eta = L xi
        if n <= 2:
            self.s_mat, self.l_mat = np.eye(n), self.u
        else:
            self.s_mat, self.l_mat = self.u, np.eye(2)
        self.d = self.s_mat.shape[0]
        self.minv_u3t = (u3 / model.modal_mass_kg[None, :]).T  # (n, 3) = M^-1 U3^T
        w = model.omega_rad_s
        # state y = [eta, eta' / w_ref]: balanced, so the exponentials keep full relative accuracy
        # (unscaled, the w^2 and 1 entries of a stiff mode differ by 1e8); a similarity
        # transformation, so the multipliers are unchanged.
        self.w_ref = float(np.max(w))
        self.a0 = np.zeros((2 * n, 2 * n))
        self.a0[:n, n:] = self.w_ref * np.eye(n)
        self.a0[n:, :n] = -np.diag(w**2) / self.w_ref
        self.a0[n:, n:] = -np.diag(2.0 * model.damping_ratio * w)
        self.highest_frequency_hz = float(np.max(model.natural_frequency_hz))
        self._dyn = dynamic_coefficients(coefficients)
        self._damp = damping_coefficients()
        self._straight = helix_lag_per_m(tool) == 0.0
        self._unit_means = {}

    # ------------------------------------------------------------------------------- pieces
    def tooth_period_s(self, spindle_rpm):
        """``T = 60 / (N n)``, s."""
        return 60.0 / (self.tool.teeth * np.asarray(spindle_rpm, dtype=float))

    def _engagement(self, steps: int, depth: np.ndarray) -> np.ndarray:
        """Exact step means of the engaged basis integrals, (B, m, 6), m, for depths (B,)."""
        m = int(steps)
        edges = TWO_PI / self.tool.teeth / m * np.arange(m + 1)
        if self._straight:  # linear in the depth: one unit-depth table per step count
            if m not in self._unit_means:
                self._unit_means[m] = engaged_axial_step_mean(self.tool, self.cut, edges[:-1], edges[1:], 1.0)
            return depth[:, None, None] * self._unit_means[m][None]
        return engaged_axial_step_mean(self.tool, self.cut, edges[None, :-1], edges[None, 1:], depth[:, None])

    def step_maps(self, spindle_rpm, depth, steps: int):
        """One-step maps ``y_{i+1} = Phi_i y_i + Gd_i xi_{i-m} + Lam_i xi_{i-m+1}`` for a batch.

        Parameters
        ----------
        spindle_rpm, depth : array_like, shape (B,) (or scalars)
        steps : int

        Returns
        -------
        phi : (B, m, 2n, 2n); gd, lam : (B, m, 2n, d); cutting : (m,) bool
            ``cutting`` is False on steps where no tooth of any batch member is engaged: there
            ``gd = lam = 0`` and ``Phi`` is the free-vibration exponential.
        """
        rpm, depth = np.broadcast_arrays(np.atleast_1d(np.asarray(spindle_rpm, dtype=float)),
                                         np.atleast_1d(np.asarray(depth, dtype=float)))
        n, d, m, bsz = self.n, self.d, int(steps), rpm.size
        dt = self.tooth_period_s(rpm) / m  # (B,)
        e = self._engagement(m, depth)  # (B, m, 6)
        k = np.einsum("ijk,bmk->bmij", self._dyn, e)
        p = None
        if self.process_damping_N_m > 0:
            speed = np.pi * self.tool.diameter_m * rpm / 60.0
            p = (self.process_damping_N_m / speed)[:, None, None, None] * np.einsum("ijk,bmk->bmij", self._damp, e)
        cutting = np.any(e != 0, axis=(0, 2))
        phi = np.empty((bsz, m, 2 * n, 2 * n))
        gd = np.zeros((bsz, m, 2 * n, d))
        lam = np.zeros((bsz, m, 2 * n, d))
        phi[:, ~cutting] = _expm_batch(self.a0[None] * dt[:, None, None])[:, None]
        idx = np.flatnonzero(cutting)
        if idx.size:
            kk = self.minv_u3t @ k[:, idx] / self.w_ref  # (B, c, n, 2), into the scaled velocity
            size = 2 * n + 2 * d
            aug = np.zeros((bsz, idx.size, size, size))
            aug[..., : 2 * n, : 2 * n] = self.a0
            aug[..., n : 2 * n, :n] += kk @ self.u
            if p is not None:
                aug[..., n : 2 * n, n : 2 * n] -= (self.minv_u3t @ p[:, idx]) @ self.u
            aug[..., n : 2 * n, 2 * n : 2 * n + d] = -kk @ self.l_mat
            aug[..., 2 * n : 2 * n + d, 2 * n + d :] = np.eye(d) / dt[:, None, None, None]
            ex = _expm_batch(aug * dt[:, None, None, None])
            phi[:, idx] = ex[..., : 2 * n, : 2 * n]
            lam[:, idx] = ex[..., : 2 * n, 2 * n + d :]
            gd[:, idx] = ex[..., : 2 * n, 2 * n : 2 * n + d] - lam[:, idx]
        return phi, gd, lam, cutting

    # ------------------------------------------------------------------------------ monodromy
    def _slots(self, cutting, *, reduce=True):
        """The history slots kept, their columns ``col_of`` and history rows ``row_of`` in the
        reduced monodromy (-1: a slot dropped), and its size ``N``."""
        m, n2, d = cutting.size, 2 * self.n, self.d
        # history slot p holds xi_{p-m}; step i reads slots i (gd) and i+1 (lam; slot m = xi_0)
        used = np.zeros(m, dtype=bool)
        used[cutting] = True
        used[1:][cutting[:-1]] = True
        if not reduce:
            used[:] = True
        slots = np.flatnonzero(used)
        col_of = np.full(m, -1)
        col_of[slots] = n2 + d * np.arange(slots.size)
        row_of = np.full(m, -1)
        row_of[slots] = d * np.arange(slots.size)
        return slots, col_of, row_of, n2 + d * slots.size

    def _assemble(self, phi, gd, lam, cutting, *, reduce=True):
        """Structured monodromy of a batch, (B, N, N), and the history slots kept."""
        slots, col_of, row_of, size = self._slots(cutting, reduce=reduce)
        mono = _compiled(_assemble_loop)(np.ascontiguousarray(phi), np.ascontiguousarray(gd), np.ascontiguousarray(lam),
                                  cutting.astype(np.bool_), col_of, row_of, np.ascontiguousarray(self.s_mat), size)
        return mono, slots

    def monodromy(self, spindle_rpm: float, depth: float, steps: int, *, reduce: bool = True) -> np.ndarray:
        """Monodromy matrix over one tooth period at one speed and depth, structured construction.

        State ordering: ``[y_0 (2n) | xi_{-m}, xi_{-m+1}, ..., xi_{-1} (d each)]``, ``y = [eta,
        eta' / w_ref]`` (``w_ref`` the highest natural angular frequency), ``xi = S eta``. With
        ``reduce`` the history entries no engaged step reads (zero columns) are dropped together
        with their rows, which keeps every non-zero multiplier.

        Returns
        -------
        ndarray, shape (N, N)
        """
        return self._assemble(*self.step_maps(spindle_rpm, depth, steps), reduce=reduce)[0][0]

    # ------------------------------------------------------------------------------ multipliers
    def _radii(self, rpm, depth, steps: int):
        """Dominant multiplier for each (speed, depth) of a batch with one step count.

        From a reduced monodromy of :data:`MATRIX_FREE_MIN_SIZE` rows up (low speeds, where a
        tooth period holds many mode periods) the matrix is not formed: Arnoldi runs on its
        product applied step by step (``O(m n^2)`` a product instead of ``O(N^2)``, and no
        ``O(m n^2 N)`` assembly), with the dense path's start vector and residual test, so the
        multiplier is the same to rounding (``tests/test_sdm.py``). Measured on the kr500
        example's tool modes at 500-1 000 rpm (``N`` 500-1 500): ~3x faster, 45x where the dense
        path fell back to LAPACK; a limit table of ``learn`` over 500-24 000 rpm spent 75 % of
        its time below 1 000 rpm.
        """
        phi, gd, lam, cutting = self.step_maps(rpm, depth, steps)
        _, col_of, row_of, size = self._slots(cutting)
        if size < MATRIX_FREE_MIN_SIZE:
            mu, _ = _dominant(self._assemble(phi, gd, lam, cutting)[0])
            return np.abs(mu), mu
        mu = _dominant_matrix_free(phi, gd, lam, cutting, col_of, row_of, self.s_mat, size)
        left = np.isnan(mu)
        if left.any():  # not converged at 160 vectors, or an invariant subspace: the formed path
            mu[left] = _dominant(self._assemble(phi[left], gd[left], lam[left], cutting)[0])[0]
        return np.abs(mu), mu

    def multipliers(self, spindle_rpm: float, depth: float, steps: int) -> Multipliers:
        """Spectral radius and dominant multiplier at one speed and depth."""
        mono, _ = self._assemble(*self.step_maps(spindle_rpm, depth, steps))
        mu = complex(_dominant(mono)[0][0])
        mu = mu.conjugate() if mu.imag < 0 else mu
        return Multipliers(abs(mu), mu, _classify(mu), mono.shape[1])

    def spectral_radius(self, spindle_rpm: float, depth: float, steps: int) -> float:
        """``max |mu|`` at one speed and depth."""
        return self.multipliers(spindle_rpm, depth, steps).spectral_radius

    def chatter_frequencies_hz(self, spindle_rpm, depth, steps: int) -> np.ndarray:
        """Dominant frequency of the critical Floquet solution for each (speed, depth), Hz.

        The eigenvector of the dominant multiplier ``mu`` is propagated over one period; with the
        Floquet factor ``mu^(t/T)`` removed, the rest is ``T``-periodic and its strongest harmonic
        ``h`` gives ``f = |arg(mu) / (2 pi) + h| / T``.
        """
        rpm, depth = np.broadcast_arrays(np.atleast_1d(np.asarray(spindle_rpm, dtype=float)),
                                         np.atleast_1d(np.asarray(depth, dtype=float)))
        phi, gd, lam, cutting = self.step_maps(rpm, depth, steps)
        mono, slots = self._assemble(phi, gd, lam, cutting)
        mu, z = _dominant(mono, vectors=True)
        flip = mu.imag < 0
        mu, z = np.where(flip, np.conj(mu), mu), np.where(flip[:, None], np.conj(z), z)
        bsz, m, n2 = rpm.size, int(steps), 2 * self.n
        hist = np.zeros((bsz, m + 1, self.d), dtype=complex)  # xi_{p-m}, p = 0..m (p = m: xi_0)
        hist[:, slots] = z[:, n2:].reshape(bsz, -1, self.d)
        y = z[:, :n2].astype(complex)
        hist[:, m] = y[:, : self.n] @ self.s_mat.T
        xs = np.empty((bsz, m, 2), dtype=complex)
        for i in range(m):
            xs[:, i] = y[:, : self.n] @ self.u.T
            y = (np.einsum("bij,bj->bi", phi[:, i], y) + np.einsum("bij,bj->bi", gd[:, i], hist[:, i])
                 + np.einsum("bij,bj->bi", lam[:, i], hist[:, i + 1]))
        arg = np.angle(mu)
        per = xs * np.exp(-1j * arg[:, None] * (np.arange(m) / m)[None, :])[:, :, None]
        spec = np.sum(np.abs(np.fft.fft(per, axis=1)) ** 2, axis=2)
        h = np.argmax(spec, axis=1)
        h = np.where(h > m // 2, h - m, h)
        return np.abs(arg / TWO_PI + h) / self.tooth_period_s(rpm)

    def chatter_frequency_hz(self, spindle_rpm: float, depth: float, steps: int) -> float:
        """:meth:`chatter_frequencies_hz` at one speed and depth."""
        return float(self.chatter_frequencies_hz(spindle_rpm, depth, steps)[0])

    # --------------------------------------------------------------------------------- limits
    def limits(self, spindle_rpm, steps, *, guess_m=None, depth_rtol: float = 1e-3,
               max_depth_m: float = 1.0, chatter_frequency: bool = True) -> list[SpeedLimit]:
        """Limit depth at each speed: where the spectral radius of the monodromy crosses 1.

        Speeds that share a step count are searched together. From the guess (default 1 mm) the
        depth is halved while unstable or doubled while stable until the boundary is bracketed,
        then the Illinois regula falsi on ``log(spectral radius)`` narrows the bracket to
        ``depth_rtol`` (relative width). Below the boundary found, a ladder of depths (each
        ``ISLAND_RATIO`` times the one above, ``ISLAND_RUNGS`` of them) is probed for islands of
        instability (flip lenses at low immersion); the lowest unstable rung restarts the search
        below it. An island narrower than a factor ``1 / ISLAND_RATIO`` in depth can still be
        missed. ``inf`` where the cut is still stable at ``max_depth_m`` (and on the ladder below
        the guess).

        Parameters
        ----------
        spindle_rpm : array_like, shape (n,)
        steps : int or array_like of int, shape (n,)
            Steps per tooth period at each speed.
        guess_m : array_like, shape (n,), optional
            Starting depths, m (non-finite: 1 mm).
        depth_rtol : float
            Relative width of the final bracket.
        max_depth_m : float
        chatter_frequency : bool
            Also compute the chatter frequency at the limit.

        Returns
        -------
        list of SpeedLimit, in the order of ``spindle_rpm``
        """
        rpm = np.atleast_1d(np.asarray(spindle_rpm, dtype=float))
        m_all = np.broadcast_to(np.asarray(steps, dtype=int), rpm.shape)
        guess = np.full(rpm.shape, np.nan) if guess_m is None else np.broadcast_to(
            np.asarray(guess_m, dtype=float), rpm.shape)
        out: list[SpeedLimit | None] = [None] * rpm.size
        for m in np.unique(m_all):
            sel = np.flatnonzero(m_all == m)
            res = self._search(rpm[sel], int(m), guess[sel], depth_rtol, max_depth_m, chatter_frequency)
            for i, r in zip(sel, res):
                out[i] = r
        # neighbours: the boundary is continuous in speed but for cusps and the edges of flip
        # lenses, so a neighbour's (lower) limit is probed too; an island narrower than the
        # ladder's rungs shows up there (measured: 1-DOF benchmark, a/D = 0.1, 7513 rpm)
        order = np.argsort(rpm, kind="stable")
        depth = np.array([out[i].depth_limit_m for i in order])
        nb = np.minimum(np.r_[np.inf, depth[:-1]], np.r_[depth[1:], np.inf])
        probe = (1.0 - depth_rtol) * nb
        sus = np.flatnonzero(np.isfinite(nb) & (probe < depth))
        for m in np.unique(m_all[order[sus]]) if sus.size else []:
            rows = sus[m_all[order[sus]] == m]
            idx = order[rows]
            rho, _ = self._radii(rpm[idx], probe[rows], int(m))
            redo = rho >= 1.0
            for i in idx:
                out[i] = replace(out[i], evaluations=out[i].evaluations + 1)
            if redo.any():
                res = self._search(rpm[idx[redo]], int(m), probe[rows][redo], depth_rtol, max_depth_m,
                                   chatter_frequency)
                for i, r in zip(idx[redo], res):
                    out[i] = replace(r, evaluations=r.evaluations + out[i].evaluations)
        return out

    def limit(self, spindle_rpm: float, steps: int, *, guess_m: float | None = None,
              depth_rtol: float = 1e-3, max_depth_m: float = 1.0,
              chatter_frequency: bool = True) -> SpeedLimit:
        """:meth:`limits` at one speed."""
        return self.limits([spindle_rpm], [steps], guess_m=[np.nan if guess_m is None else guess_m],
                           depth_rtol=depth_rtol, max_depth_m=max_depth_m,
                           chatter_frequency=chatter_frequency)[0]

    def _search(self, rpm, m, guess, rtol, max_depth, want_freq):
        bsz = rpm.size
        a = np.where(np.isfinite(guess) & (guess > 0), guess, 1e-3)
        a = np.minimum(a, max_depth)
        start = a.copy()
        lo, f_lo = np.zeros(bsz), np.full(bsz, np.nan)
        hi, f_hi = np.full(bsz, np.inf), np.full(bsz, np.nan)
        mu_hi = np.zeros(bsz, dtype=complex)
        evals = np.zeros(bsz, dtype=int)
        unbounded = np.zeros(bsz, dtype=bool)

        def evaluate(idx, depths):
            rho, mu = self._radii(rpm[idx], depths, m)
            np.add.at(evals, idx, 1)
            return np.log(rho), mu

        def bracket(todo):
            """Double while stable, halve while unstable, from ``a``, until ``lo`` / ``hi`` bracket the boundary."""
            while todo.size:
                f, mu = evaluate(todo, a[todo])
                st = f < 0
                lo[todo[st]], f_lo[todo[st]] = a[todo[st]], f[st]
                un = ~st
                hi[todo[un]], f_hi[todo[un]], mu_hi[todo[un]] = a[todo[un]], f[un], mu[un]
                a[todo[st]] = np.minimum(2.0 * a[todo[st]], max_depth)
                a[todo[un]] = a[todo[un]] / 2.0
                top = st & (lo[todo] >= max_depth)
                unbounded[todo[top]] = True
                if np.any(un & (a[todo] < 1e-12)):
                    raise RuntimeError(f"unstable at vanishing depth at {rpm[todo[un][0]]:g} rpm "
                                       "(an undamped or negatively damped structure?)")
                todo = todo[~(np.isfinite(f_lo[todo]) & np.isfinite(f_hi[todo])) & ~top]

        def refine():
            """Illinois regula falsi on ``log(rho)`` (``f_lo < 0 <= f_hi``) to ``rtol``."""
            g_lo, g_hi = f_lo.copy(), f_hi.copy()
            side = np.zeros(bsz, dtype=int)
            for it in range(200):
                act = np.flatnonzero(~unbounded & (hi - lo > rtol * hi))
                if act.size == 0:
                    break
                w = hi[act] - lo[act]
                c = (lo[act] * g_hi[act] - hi[act] * g_lo[act]) / (g_hi[act] - g_lo[act])
                c = np.clip(c, lo[act] + 1e-3 * w, hi[act] - 1e-3 * w)
                if it >= 60:  # safeguard: plain bisection
                    c = lo[act] + w / 2
                f, mu = evaluate(act, c)
                un = f >= 0
                iu, is_ = act[un], act[~un]
                g_lo[iu] = np.where(side[iu] == -1, g_lo[iu] / 2, g_lo[iu])
                hi[iu], f_hi[iu], g_hi[iu], mu_hi[iu], side[iu] = c[un], f[un], f[un], mu[un], -1
                g_hi[is_] = np.where(side[is_] == 1, g_hi[is_] / 2, g_hi[is_])
                lo[is_], f_lo[is_], g_lo[is_], side[is_] = c[~un], f[~un], f[~un], 1

        bracket(np.arange(bsz))
        refine()
        # ---- islands: at low immersion a flip lens can lie below a stable gap under the boundary
        # found (measured on the 1-DOF benchmark at a/D = 0.05: unstable at 1.45-3.93 mm under a
        # Hopf boundary at 4.95 mm). Probe a ladder of depths below it; the lowest unstable rung
        # becomes the new upper end of the bracket, and the ladder is walked again below the new
        # boundary (lenses can stack).
        rungs = ISLAND_RATIO ** np.arange(1, ISLAND_RUNGS + 1)
        check = np.arange(bsz)
        for _ in range(4):
            base = np.where(unbounded[check], np.minimum(start[check], max_depth), lo[check])
            depths = np.outer(base, rungs).ravel()
            f, mu = evaluate(np.repeat(check, rungs.size), depths)
            un = (f >= 0).reshape(check.size, rungs.size)
            rows = np.flatnonzero(un.any(axis=1))
            if rows.size == 0:
                break
            hit = check[rows]
            k = rungs.size - 1 - np.argmax(un[rows, ::-1], axis=1)  # the lowest unstable rung
            pos = rows * rungs.size + k
            hi[hit], f_hi[hit], mu_hi[hit] = depths[pos], f[pos], mu[pos]
            unbounded[hit] = False
            below = k + 1 < rungs.size  # the rung below it was probed, and was stable
            lo[hit], f_lo[hit] = 0.0, np.nan
            lo[hit[below]], f_lo[hit[below]] = depths[pos[below] + 1], f[pos[below] + 1]
            a[hit[~below]] = hi[hit[~below]] / 2.0
            bracket(hit[~below])
            refine()
            check = hit
        with np.errstate(invalid="ignore", divide="ignore"):
            root = lo + (hi - lo) * f_lo / (f_lo - f_hi)
        root = np.where(np.isfinite(root), root, hi)
        root[unbounded] = np.inf
        freq = np.full(bsz, np.nan)
        ok = ~unbounded
        if want_freq and ok.any():
            freq[ok] = self.chatter_frequencies_hz(rpm[ok], hi[ok], m)
        kinds = [_classify(complex(np.conj(x) if x.imag < 0 else x)) if o else "none" for x, o in zip(mu_hi, ok)]
        return [SpeedLimit(float(r), float(x), k, float(f), int(m), int(e))
                for r, x, k, f, e in zip(rpm, root, kinds, freq, evals)]


# ------------------------------------------------------------------------------- step count rule
# Step counts are rounded up to a multiple of this so that neighbouring speeds share a count and
# are searched in one batch (rounding up only refines the discretization).
STEP_QUANTUM = 8


def steps_per_period(problem: SDMProblem, spindle_rpm, *, steps_per_mode_period: float,
                     min_steps: int) -> np.ndarray:
    """Steps per tooth period for each speed: ``max(min_steps, c T f_max)`` rounded up to a
    multiple of ``STEP_QUANTUM``.

    ``T f_max`` is the number of periods of the highest mode in one tooth period; ``c`` is the
    resolution of that mode (steps per its period).
    """
    t = problem.tooth_period_s(spindle_rpm)
    raw = np.maximum(float(min_steps), steps_per_mode_period * t * problem.highest_frequency_hz)
    return (STEP_QUANTUM * np.ceil(raw / STEP_QUANTUM)).astype(int)


@dataclass(frozen=True)
class Resolution:
    """Step-count rule chosen by the convergence test (see :func:`choose_resolution`).

    ``history`` lists ``(steps per mode period, min steps, largest relative change of the limit)``
    for each doubling.
    """

    steps_per_mode_period: float
    min_steps: int
    rtol: float
    probe_rpm: tuple[float, ...]
    history: tuple[tuple[float, int, float], ...]
    converged: bool


def choose_resolution(problem: SDMProblem, rpm_range, *, rtol: float = 0.01, n_probes: int = 3,
                      start_steps_per_mode_period: float = 10.0, start_min_steps: int = 20,
                      max_doublings: int = 5) -> Resolution:
    """Choose the step count for a stated accuracy by a convergence test.

    Starting from ``start_steps_per_mode_period`` steps per period of the highest mode (and at
    least ``start_min_steps`` per tooth period), the resolution is doubled until the limit depth
    at ``n_probes`` speeds log-spaced inside ``rpm_range`` changes by less than ``rtol``
    (relative) between two levels; the finer level is returned. First-order semi-discretization
    converges as ``dt^2``, so the finer level's own error is about a third of that change.
    """
    lo, hi = float(min(rpm_range)), float(max(rpm_range))
    probes = np.geomspace(lo, hi, n_probes + 2)[1:-1] if hi > lo else np.array([lo])
    c, m0 = float(start_steps_per_mode_period), int(start_min_steps)

    def limits(c_, m_, guesses):
        ms = steps_per_period(problem, probes, steps_per_mode_period=c_, min_steps=m_)
        return np.array([x.depth_limit_m for x in problem.limits(
            probes, ms, guess_m=guesses, chatter_frequency=False, depth_rtol=rtol / 20)])

    prev = limits(c, m0, None)
    history = []
    for _ in range(max_doublings):
        c2, m2 = 2 * c, 2 * m0
        cur = limits(c2, m2, prev)
        with np.errstate(invalid="ignore"):
            change = np.abs(cur - prev) / np.abs(cur)
        change = np.where(np.isfinite(cur) | np.isfinite(prev), change, 0.0)
        worst = float(np.nanmax(change)) if np.any(np.isfinite(change)) else 0.0
        history.append((c2, m2, worst))
        c, m0, prev = c2, m2, cur
        if worst < rtol:
            return Resolution(c, m0, rtol, tuple(float(p) for p in probes), tuple(history), True)
    warnings.warn(f"SDM step count not converged to rtol={rtol} after {max_doublings} doublings "
                  f"(last change {history[-1][2]:.3g})", stacklevel=2)
    return Resolution(c, m0, rtol, tuple(float(p) for p in probes), tuple(history), False)


# ------------------------------------------------------------------------ straightforward reference
def dense_monodromy(problem: SDMProblem, spindle_rpm: float, depth: float, steps: int,
                    maps=None) -> np.ndarray:
    """The same monodromy as :meth:`SDMProblem.monodromy` (``reduce=False``), built the
    straightforward way: one dense ``N x N`` step matrix per step, multiplied together.

    State: ``[y | xi_{i-1}, ..., xi_{i-m}]`` as in the published scripts (a shift register);
    returned in the ordering of :meth:`SDMProblem.monodromy` for comparison. ``maps`` may supply
    the step maps ``(phi, gd, lam)`` of one speed, (m, ...) each. Slow by design: it is the
    baseline of the benchmark and the reference of the tests.
    """
    if maps is None:
        phi, gd, lam, _ = problem.step_maps(spindle_rpm, depth, steps)
        phi, gd, lam = phi[0], gd[0], lam[0]
    else:
        phi, gd, lam = maps
    n2, d, m, nn = 2 * problem.n, problem.d, int(steps), problem.n
    size = n2 + d * m
    total = np.eye(size)
    for i in range(m):
        step = np.zeros((size, size))
        step[:n2, :n2] = phi[i]
        # register slot r (1..m) holds xi_{i-r}: xi_{i-m} is slot m, xi_{i-m+1} slot m-1
        step[:n2, n2 + d * (m - 1) :] += gd[i]
        if m >= 2:
            step[:n2, n2 + d * (m - 2) : n2 + d * (m - 1)] += lam[i]
        else:
            step[:n2, :nn] += lam[i] @ problem.s_mat
        step[n2 : n2 + d, :nn] = problem.s_mat
        step[n2 + d :, n2 : n2 + d * (m - 1)] = np.eye(d * (m - 1))
        total = step @ total
    # register slot r = xi_{-r} -> structured slot p = m - r
    perm = np.arange(size)
    for p in range(m):
        r = m - p
        perm[n2 + d * p : n2 + d * (p + 1)] = n2 + d * (r - 1) + np.arange(d)
    return total[np.ix_(perm, perm)]
