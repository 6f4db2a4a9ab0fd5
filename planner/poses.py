"""Pose-dependent robot dynamics: modal models identified at a few robot poses, turned into a
model for any pose in their span.

A robot's tool-tip modes move with the arm configuration (Cordes, Hintze & Altintas, 2019;
Nguyen, Cvitanic & Melkote, 2020). Given :class:`~oma.modal.ModalModel` s identified at several
poses (each with ``joints_deg``), :meth:`PoseModels.fit`

1. **matches modes across poses**, starting from a reference pose (the medoid of the poses in
   joint space unless given) and visiting the other poses nearest-first (Prim order). A pose's
   modes are matched against *templates*: for every reference mode, its frequency and direction
   at the nearest already-matched pose that has it. The cost of pairing template ``t`` with mode
   ``j`` is ``(1 - MAC(u_t, u_j)) + |ln(f_j / f_t)|`` (Allemang, Sound & Vibration 37(8), 2003 for
   the modal assurance criterion ``MAC = (u_t . u_j)^2 / (|u_t|^2 |u_j|^2)``); pairs with
   ``MAC < min_mac`` or a frequency ratio beyond ``1 + max_freq_change`` are not allowed; the
   assignment minimising the total cost is the Hungarian one (Kuhn, 1955;
   :func:`scipy.optimize.linear_sum_assignment`). Only modes matched at *every* pose are
   interpolated; every other mode is listed in :attr:`PoseModels.dropped_modes` and a warning says
   which. Each direction's sign is aligned with its template, and the final sign makes the largest
   component at the reference pose positive. Modes are ordered by their frequency at the reference.
2. **interpolates** ``ln f``, ``ln zeta``, ``ln k`` (kept positive) and the three direction
   components of every mode with a radial-basis-function interpolant without smoothing
   (:class:`scipy.interpolate.RBFInterpolator`; Wendland, *Scattered Data Approximation*, 2005),
   in the coordinates of the joint subspace the poses span (below). The default kernel is the
   polyharmonic ``r^3`` plus a linear polynomial, which in one dimension is the natural cubic
   spline; on smooth pose laws its error fell faster with the number of poses than that of the
   thin-plate spline (``r^2 ln r``), in 1-D and 2-D (``benchmarks/bench_poses.py``). Directions
   are renormalised after interpolation. The interpolant reproduces the given models at the
   identified poses.
   The **residual compliance** is interpolated *piecewise linearly* (on the segments between
   poses for a 1-D span, on the Delaunay simplices of the poses otherwise): its weights are
   non-negative and sum to one, so a positive semi-definite residual stays so, which an RBF
   (which overshoots) does not guarantee.

The span rule is in :mod:`planner.pose_span`, the mode matching in :mod:`planner.pose_matching`.

Cost: :meth:`PoseModels.evaluate` works on the distinct rows of its input, vectorised; a pose
beyond a span of ``d >= 2`` dimensions costs one small non-negative least squares (about 0.1 ms).

Units: joints in degrees; frequencies Hz; stiffness N/m; compliance m/N.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from oma._arrays import readonly as _ro
from scipy.interpolate import RBFInterpolator

from oma.errors import ModelError
from oma.modal import ModalModel

from .pose_matching import mac_matrix, match_modes
from .pose_span import PoseOutOfSpanError, Span

__all__ = [
    "PoseModels",
    "model_list",
    "PoseEvaluation",
    "LOOResult",
    "PoseOutOfSpanError",
    "mac_matrix",
    "KERNELS",
]

#: RBF kernels without a shape parameter (scale-free), with the smallest polynomial degree each needs.
KERNELS = {"thin_plate_spline": 1, "cubic": 1, "quintic": 2, "linear": 0}

#: At most this many poses are kept in the cache of :meth:`PoseModels.at`.
_CACHE_SIZE = 4096


def _positive_tol(value, name: str) -> float:
    x = float(value)
    if not (math.isfinite(x) and x > 0):
        raise ValueError(f"{name} must be a positive number of degrees, found {value!r}")
    return x


def _unique_rows(q: np.ndarray):
    """Distinct rows of ``q`` (exact equality) and, for every row, the index of its distinct row.

    A lexicographic sort and a comparison of neighbours: several times faster than
    ``np.unique(axis=0)`` on (100 000, 6) float arrays.
    """
    if q.shape[0] <= 1:
        return q, np.zeros(q.shape[0], dtype=int)
    order = np.lexsort(q.T[::-1])
    qs = q[order]
    first = np.empty(q.shape[0], dtype=bool)
    first[0] = True
    np.any(qs[1:] != qs[:-1], axis=1, out=first[1:])
    inverse = np.empty(q.shape[0], dtype=int)
    inverse[order] = np.cumsum(first) - 1
    return qs[first], inverse


# =========================================================================== results
@dataclass(frozen=True, eq=False)
class PoseEvaluation:
    """Interpolated modal parameters at many poses.

    Parameters
    ----------
    joints_deg : ndarray, shape (n_points, n_joints)
        The poses, degrees.
    natural_frequency_hz, damping_ratio, stiffness_N_m : ndarray, shape (n_points, n_modes)
        Hz, ratio (0.05 = 5 %), N/m.
    directions : ndarray, shape (n_points, n_modes, 3)
        Unit mode directions, machine frame.
    residual_compliance_m_N : ndarray, shape (n_points, 3, 3)
        m/N.
    in_span : ndarray of bool, shape (n_points,)
        The span rule of the module doc; ``False`` is a ``pose_out_of_range``.
    beyond_range : ndarray of bool, shape (n_points,)
        The pose lies beyond the identified poses along the span; its values are those at the
        nearest point of the span (held, not extrapolated).
    distance_deg : ndarray, shape (n_points,)
        Distance to the identified span, degrees.
    """

    joints_deg: np.ndarray
    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    stiffness_N_m: np.ndarray
    directions: np.ndarray
    residual_compliance_m_N: np.ndarray
    in_span: np.ndarray
    beyond_range: np.ndarray
    distance_deg: np.ndarray

    def __post_init__(self):
        for name in ("joints_deg", "natural_frequency_hz", "damping_ratio", "stiffness_N_m", "directions",
                     "residual_compliance_m_N", "distance_deg"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        for name in ("in_span", "beyond_range"):
            object.__setattr__(self, name, _ro(getattr(self, name), dtype=bool))

    @property
    def n_points(self) -> int:
        return int(self.joints_deg.shape[0])

    def model(self, i: int) -> ModalModel:
        """The modal model at point ``i``, with its pose and span flags in ``source``."""
        return ModalModel(
            self.natural_frequency_hz[i], self.damping_ratio[i], self.stiffness_N_m[i], self.directions[i],
            residual_compliance_m_N=self.residual_compliance_m_N[i], joints_deg=self.joints_deg[i],
            source={"method": "pose interpolation (planner.poses)", "in_span": bool(self.in_span[i]),
                    "beyond_range": bool(self.beyond_range[i]), "distance_deg": float(self.distance_deg[i])},
        )

    def to_dict(self) -> dict:
        """Plain lists, for JSON."""
        return {name: getattr(self, name).tolist() for name in (
            "joints_deg", "natural_frequency_hz", "damping_ratio", "stiffness_N_m", "directions",
            "residual_compliance_m_N", "in_span", "beyond_range", "distance_deg")}


@dataclass(frozen=True, eq=False)
class LOOResult:
    """Leave-one-pose-out errors: each pose predicted from the others.

    Parameters
    ----------
    joints_deg : ndarray, shape (n_poses, n_joints)
    natural_frequency_hz : ndarray, shape (n_poses, n_modes)
        The identified frequencies (the truth the predictions are compared with), Hz.
    frequency_error, damping_error, stiffness_error : ndarray, shape (n_poses, n_modes)
        Signed relative errors ``(predicted - identified) / identified``.
    direction_mac : ndarray, shape (n_poses, n_modes)
        MAC of predicted and identified direction (1 = same).
    extrapolated : ndarray of bool, shape (n_poses,)
        The pose lies beyond the other poses along their span (a boundary pose): its prediction is
        the value held at the nearest point of the others' span, not an interpolation.
    distance_deg : ndarray, shape (n_poses,)
        Distance of the pose to the span of the others, degrees.
    """

    joints_deg: np.ndarray
    natural_frequency_hz: np.ndarray
    frequency_error: np.ndarray
    damping_error: np.ndarray
    stiffness_error: np.ndarray
    direction_mac: np.ndarray
    extrapolated: np.ndarray
    distance_deg: np.ndarray

    def __post_init__(self):
        for name in ("joints_deg", "natural_frequency_hz", "frequency_error", "damping_error",
                     "stiffness_error", "direction_mac", "distance_deg"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "extrapolated", _ro(self.extrapolated, dtype=bool))

    def summary(self, *, interior_only: bool = True) -> dict:
        """Largest ``|relative error|`` of each quantity and the smallest MAC, over the interior
        poses (``interior_only``) or all; ``nan`` when there are none."""
        rows = ~self.extrapolated if interior_only else np.ones(self.extrapolated.shape, dtype=bool)

        def worst(a, fn):
            return float(fn(a[rows])) if np.any(rows) else float("nan")

        return {
            "poses": int(np.count_nonzero(rows)),
            "max_abs_frequency_error": worst(np.abs(self.frequency_error), np.max),
            "max_abs_damping_error": worst(np.abs(self.damping_error), np.max),
            "max_abs_stiffness_error": worst(np.abs(self.stiffness_error), np.max),
            "min_direction_mac": worst(self.direction_mac, np.min),
        }

    def to_dict(self) -> dict:
        """Plain lists and the summaries, for JSON."""
        out = {name: getattr(self, name).tolist() for name in (
            "joints_deg", "natural_frequency_hz", "frequency_error", "damping_error", "stiffness_error",
            "direction_mac", "extrapolated", "distance_deg")}
        out["summary_interior"] = self.summary(interior_only=True)
        out["summary_all"] = self.summary(interior_only=False)
        return out


# =========================================================================== the model
def model_list(models) -> list[ModalModel]:
    """``models`` as a list, checked: at least one, every one a :class:`~oma.modal.ModalModel`."""
    models = list(models)
    if not models:
        raise ValueError("models: expected at least one modal model, found none")
    for i, m in enumerate(models):
        if not isinstance(m, ModalModel):
            raise TypeError(f"models[{i}] is a {type(m).__name__}, not a ModalModel")
    return models


@dataclass(frozen=True, eq=False)
class PoseModels:
    """Modal models at identified poses, matched mode by mode, interpolable in joint space.

    Build it with :meth:`fit` from :class:`~oma.modal.ModalModel` s; the constructor takes modes
    already matched across poses (same order, sign-aligned directions).

    Parameters
    ----------
    joints_deg : array_like, shape (n_poses, n_joints)
        Identified poses, degrees.
    natural_frequency_hz, damping_ratio, stiffness_N_m : array_like, shape (n_poses, n_modes)
        Matched modal parameters (Hz, ratio, N/m); all positive.
    directions : array_like, shape (n_poses, n_modes, 3)
        Matched, sign-aligned mode directions (normalised here).
    residual_compliance_m_N : array_like, shape (n_poses, 3, 3), optional
        m/N; zeros if not given.
    kernel : {'cubic', 'thin_plate_spline', 'quintic', 'linear'}
        RBF kernel (scale-free kernels only, so the result does not depend on a shape parameter).
    span_tol_deg : float
        Largest distance to the identified span of a pose in the span, degrees (module doc).
    subspace_tol_deg : float
        Deviation of the identified poses from their principal subspace below which a joint
        direction counts as not varied, degrees. The default 0.5 deg is well below
        ``span_tol_deg`` and above the rounding of joint angles in pose files and the sag of a
        smoothly curved joint path between neighbouring poses.
    hull_tol_deg : float
        How far beyond the identified poses *along* the span a pose may lie and still be in it,
        degrees; only rounding (joint angles are commonly written to 0.01 deg).
    reference_pose : int
        Index of the pose the modes were matched against.
    mode_index : array_like of int, shape (n_poses, n_modes), optional
        Where each matched mode sits in the input model of its pose.
    dropped_modes : tuple of (int, int, float)
        ``(pose, mode index in that pose's model, frequency in Hz)`` of every mode not matched at
        every pose (not interpolated).
    """

    joints_deg: np.ndarray
    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    stiffness_N_m: np.ndarray
    directions: np.ndarray
    residual_compliance_m_N: np.ndarray | None = None
    kernel: str = "cubic"
    span_tol_deg: float = 2.0
    subspace_tol_deg: float = 0.5
    hull_tol_deg: float = 0.01
    reference_pose: int = 0
    mode_index: np.ndarray | None = None
    dropped_modes: tuple = ()
    _span: Span = field(init=False, repr=False)
    _rbf: RBFInterpolator | None = field(init=False, repr=False)
    _cache: dict = field(init=False, repr=False)

    def __post_init__(self):
        q = np.array(self.joints_deg, dtype=float)
        if q.ndim != 2 or q.shape[0] < 1 or not np.all(np.isfinite(q)):
            raise ValueError(f"joints_deg must be a finite (n_poses, n_joints) array, found shape {q.shape}")
        n = q.shape[0]
        f = np.array(self.natural_frequency_hz, dtype=float)
        if f.ndim != 2 or f.shape[0] != n or f.shape[1] < 1:
            raise ValueError(f"natural_frequency_hz must have shape ({n}, n_modes), found {f.shape}")
        m = f.shape[1]
        zeta = np.array(self.damping_ratio, dtype=float)
        k = np.array(self.stiffness_N_m, dtype=float)
        u = np.array(self.directions, dtype=float)
        for name, a, shape in (("damping_ratio", zeta, (n, m)), ("stiffness_N_m", k, (n, m)),
                               ("directions", u, (n, m, 3))):
            if a.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, found {a.shape}")
        for name, a in (("natural_frequency_hz", f), ("damping_ratio", zeta), ("stiffness_N_m", k)):
            if not np.all(np.isfinite(a) & (a > 0)):
                bad = np.argwhere(~(np.isfinite(a) & (a > 0)))[0]
                raise ValueError(f"{name} must be positive (it is interpolated as a logarithm); "
                                 f"found {a[tuple(bad)]!r} at pose {bad[0]}, mode {bad[1]}")
        norms = np.linalg.norm(u, axis=-1)
        if not np.all(np.isfinite(norms) & (norms > 0)):
            raise ValueError("directions must be finite non-zero 3-vectors")
        u = u / norms[..., None]
        r = (np.zeros((n, 3, 3)) if self.residual_compliance_m_N is None
             else np.array(self.residual_compliance_m_N, dtype=float))
        if r.shape != (n, 3, 3):
            raise ValueError(f"residual_compliance_m_N must have shape ({n}, 3, 3), found {r.shape}")
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(map(repr, KERNELS))}; found {self.kernel!r}")
        for name in ("span_tol_deg", "subspace_tol_deg", "hull_tol_deg"):
            object.__setattr__(self, name, _positive_tol(getattr(self, name), name))
        for name, a in (("joints_deg", q), ("natural_frequency_hz", f), ("damping_ratio", zeta),
                        ("stiffness_N_m", k), ("directions", u), ("residual_compliance_m_N", r)):
            object.__setattr__(self, name, _ro(a))
        if self.mode_index is not None:
            object.__setattr__(self, "mode_index", _ro(self.mode_index, dtype=int))
        object.__setattr__(self, "dropped_modes", tuple(tuple(x) for x in self.dropped_modes))

        span = Span.build(q, self.subspace_tol_deg)
        rbf = None
        if span.dimension >= 1:
            degree = KERNELS[self.kernel]
            terms = math.comb(span.dimension + degree, degree)
            if n < terms:
                raise ValueError(
                    f"kernel {self.kernel!r} needs at least {terms} poses in a {span.dimension}-D span, "
                    f"found {n}")
            rbf = RBFInterpolator(span.coords, self._features(), kernel=self.kernel)
        object.__setattr__(self, "_span", span)
        object.__setattr__(self, "_rbf", rbf)
        object.__setattr__(self, "_cache", {})

    # ------------------------------------------------------------------ construction
    @classmethod
    def fit(
        cls,
        models: Sequence[ModalModel],
        *,
        kernel: Literal["thin_plate_spline", "cubic", "quintic", "linear"] = "cubic",
        reference: int | None = None,
        min_mac: float = 0.5,
        max_freq_change: float = 0.5,
        span_tol_deg: float = 2.0,
        subspace_tol_deg: float = 0.5,
        hull_tol_deg: float = 0.01,
    ) -> "PoseModels":
        """Match the modes of models identified at several poses and build the interpolant.

        Parameters
        ----------
        models : sequence of ModalModel
            One per pose; every one must carry ``joints_deg`` (all of the same length).
        kernel : {'cubic', 'thin_plate_spline', 'quintic', 'linear'}
            RBF kernel; see :class:`scipy.interpolate.RBFInterpolator`.
        reference : int, optional
            Index of the pose to match modes against; default the medoid of the poses (smallest
            sum of joint-space distances to the others), so that templates drift least.
        min_mac : float
            Smallest MAC of a matched pair (0..1).
        max_freq_change : float
            Largest relative frequency change of a matched pair between a pose and its template
            (0.5: the frequency ratio lies in [1/1.5, 1.5]).
        span_tol_deg, subspace_tol_deg, hull_tol_deg : float
            The span rule (module doc), degrees.

        Returns
        -------
        PoseModels

        Raises
        ------
        oma.errors.ModelError
            A model without ``joints_deg`` (the message names which), or poses of different
            lengths.
        ValueError
            No models, no mode matched at every pose, two models at the same pose, a bad option.

        Warns
        -----
        UserWarning
            Modes not matched at every pose; they are left out of the interpolation.
        """
        models = model_list(models)
        for i, model in enumerate(models):
            if model.joints_deg is None:
                raise ModelError(None, f"models[{i}].pose.joints_deg", "the robot pose (joint angles, deg)",
                                 "none")
        n_joints = models[0].joints_deg.size
        for i, model in enumerate(models):
            if model.joints_deg.size != n_joints:
                raise ModelError(None, f"models[{i}].pose.joints_deg", f"{n_joints} joint angles like models[0]",
                                 f"{model.joints_deg.size}")
        if not 0.0 <= min_mac <= 1.0:
            raise ValueError(f"min_mac must lie in [0, 1], found {min_mac!r}")
        if not (math.isfinite(max_freq_change) and max_freq_change > 0):
            raise ValueError(f"max_freq_change must be a positive number, found {max_freq_change!r}")
        joints = np.array([m.joints_deg for m in models], dtype=float)
        n = len(models)
        dist = np.linalg.norm(joints[:, None, :] - joints[None, :, :], axis=-1)
        if reference is None:
            reference = int(np.argmin(dist.sum(axis=1)))
        elif not (isinstance(reference, (int, np.integer)) and 0 <= reference < n):
            raise ValueError(f"reference must be a pose index in [0, {n - 1}], found {reference!r}")
        reference = int(reference)

        assign, sign = match_modes(models, dist, reference, min_mac, math.log1p(max_freq_change))
        kept = np.flatnonzero(np.all(assign >= 0, axis=0))
        if kept.size == 0:
            raise ValueError("no mode could be matched at every pose (check min_mac and max_freq_change)")
        ref = models[reference]
        # canonical order (frequency at the reference) and sign (largest component at the reference > 0)
        kept = kept[np.argsort(ref.natural_frequency_hz[kept], kind="stable")]
        canon = np.sign(ref.directions[kept, np.argmax(np.abs(ref.directions[kept]), axis=1)])
        idx = assign[:, kept]
        sgn = sign[:, kept] * canon[None, :]
        dropped = []
        for p, model in enumerate(models):
            for j in np.setdiff1d(np.arange(model.n_modes), idx[p]):
                dropped.append((p, int(j), float(model.natural_frequency_hz[j])))
        if dropped:
            listing = "; ".join(f"pose {p} mode {j} ({f:.4g} Hz)" for p, j, f in dropped)
            warnings.warn(f"{len(dropped)} mode(s) not matched at every pose are left out of the pose "
                          f"interpolation: {listing}", stacklevel=2)
        return cls(
            joints_deg=joints,
            natural_frequency_hz=np.stack([models[p].natural_frequency_hz[idx[p]] for p in range(n)]),
            damping_ratio=np.stack([models[p].damping_ratio[idx[p]] for p in range(n)]),
            stiffness_N_m=np.stack([models[p].stiffness_N_m[idx[p]] for p in range(n)]),
            directions=np.stack([models[p].directions[idx[p]] * sgn[p][:, None] for p in range(n)]),
            residual_compliance_m_N=np.stack([m.residual_compliance_m_N for m in models]),
            kernel=kernel, span_tol_deg=span_tol_deg, subspace_tol_deg=subspace_tol_deg,
            hull_tol_deg=hull_tol_deg, reference_pose=reference, mode_index=idx, dropped_modes=tuple(dropped),
        )

    # ------------------------------------------------------------------ derived
    @property
    def n_poses(self) -> int:
        return int(self.joints_deg.shape[0])

    @property
    def n_modes(self) -> int:
        return int(self.natural_frequency_hz.shape[1])

    @property
    def n_joints(self) -> int:
        return int(self.joints_deg.shape[1])

    @property
    def span_dimension(self) -> int:
        """Number of independent joint-space directions the identified poses vary in."""
        return self._span.dimension

    @property
    def span_basis(self) -> np.ndarray:
        """Unit joint-space directions of the span, shape (n_joints, span_dimension)."""
        return self._span.basis.copy()

    def _features(self) -> np.ndarray:
        n = self.n_poses
        return np.hstack([np.log(self.natural_frequency_hz), np.log(self.damping_ratio),
                          np.log(self.stiffness_N_m), self.directions.reshape(n, -1)])

    # ------------------------------------------------------------------ evaluation
    def _coerce(self, joints_deg) -> np.ndarray:
        q = np.asarray(joints_deg, dtype=float)
        if q.ndim == 1:
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != self.n_joints:
            raise ValueError(f"joints_deg has the wrong shape; expected (n_points, {self.n_joints}), "
                             f"found {np.shape(joints_deg)}")
        if not np.all(np.isfinite(q)):
            raise ValueError("joints_deg must be finite")
        return q

    def evaluate(self, joints_deg) -> PoseEvaluation:
        """The interpolated modal parameters and span flags at many poses, vectorised.

        Repeated poses are evaluated once (unique rows). Poses outside the span get the values at
        the nearest point of the span (never extrapolated) and ``in_span = False``.

        Parameters
        ----------
        joints_deg : array_like, shape (n_points, n_joints) or (n_joints,)
            Poses, degrees.

        Returns
        -------
        PoseEvaluation
        """
        q = self._coerce(joints_deg)
        uq, inverse = _unique_rows(q)
        f, zeta, k, u, r, in_span, beyond, dist = self._evaluate_unique(uq)
        return PoseEvaluation(q, f[inverse], zeta[inverse], k[inverse], u[inverse], r[inverse], in_span[inverse],
                              beyond[inverse], dist[inverse])

    def _evaluate_unique(self, q):
        m = self.n_modes
        z_near, weights, beyond, dist = self._span.locate(q, self.hull_tol_deg)
        in_span = ~beyond & (dist <= self.span_tol_deg)
        if self._rbf is None:
            y = np.broadcast_to(self._features()[0], (q.shape[0], 6 * m))
        else:
            y = self._rbf(z_near)
        f = np.exp(y[:, :m])
        zeta = np.exp(y[:, m:2 * m])
        k = np.exp(y[:, 2 * m:3 * m])
        u = y[:, 3 * m:].reshape(-1, m, 3)
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        r = np.einsum("pn,nij->pij", weights, self.residual_compliance_m_N)
        return f, zeta, k, u, r, in_span, beyond, dist

    def at(self, joints_deg, *, out_of_span: Literal["raise", "clamp"] = "raise") -> ModalModel:
        """The modal model at one pose.

        Parameters
        ----------
        joints_deg : array_like, shape (n_joints,)
            The pose, degrees.
        out_of_span : {'raise', 'clamp'}
            What to do with a pose outside the span: raise :class:`PoseOutOfSpanError`, or return
            the model at the nearest point of the span (``source['in_span']`` is then ``False``).

        Returns
        -------
        ModalModel
            With ``joints_deg`` the pose and ``source`` holding ``in_span``, ``beyond_range`` and
            ``distance_deg``. Results are cached per pose.

        Raises
        ------
        PoseOutOfSpanError
            ``out_of_span='raise'`` and the pose is outside the span.
        """
        if out_of_span not in ("raise", "clamp"):
            raise ValueError(f"out_of_span must be 'raise' or 'clamp', found {out_of_span!r}")
        q = np.asarray(joints_deg, dtype=float)
        if q.ndim != 1:
            raise ValueError(f"joints_deg must be one pose of {self.n_joints} joint angles, found shape {q.shape}")
        q = self._coerce(q)[0]
        key = q.tobytes()
        model = self._cache.get(key)
        if model is None:
            model = self.evaluate(q).model(0)
            if len(self._cache) >= _CACHE_SIZE:
                self._cache.clear()
            self._cache[key] = model
        if out_of_span == "raise" and not model.source["in_span"]:
            raise PoseOutOfSpanError(q, model.source["distance_deg"], model.source["beyond_range"],
                                     self.span_tol_deg)
        return model

    # ------------------------------------------------------------------ validation
    def subset(self, poses) -> "PoseModels":
        """The interpolant built from some of the poses only (same matching and options)."""
        idx = np.asarray(poses, dtype=int).reshape(-1)
        return PoseModels(
            self.joints_deg[idx], self.natural_frequency_hz[idx], self.damping_ratio[idx], self.stiffness_N_m[idx],
            self.directions[idx], self.residual_compliance_m_N[idx], kernel=self.kernel,
            span_tol_deg=self.span_tol_deg, subspace_tol_deg=self.subspace_tol_deg, hull_tol_deg=self.hull_tol_deg,
            reference_pose=0, mode_index=None if self.mode_index is None else self.mode_index[idx],
        )

    def leave_one_out(self) -> LOOResult:
        """Predict every pose from the others (modes as matched on all poses).

        A pose beyond the others along their span (a boundary pose) is marked ``extrapolated``:
        its prediction is the value held at the others' nearest span point.

        Returns
        -------
        LOOResult

        Raises
        ------
        ValueError
            Fewer than two poses.
        """
        n = self.n_poses
        if n < 2:
            raise ValueError(f"leave-one-out needs at least 2 poses, found {n}")
        shape = (n, self.n_modes)
        ef, ez, ek, mac = (np.empty(shape) for _ in range(4))
        extrap = np.empty(n, dtype=bool)
        dist = np.empty(n)
        for i in range(n):
            others = self.subset(np.delete(np.arange(n), i))
            f, zeta, k, u, _, _, beyond, d = others._evaluate_unique(self.joints_deg[i][None, :])
            ef[i] = f[0] / self.natural_frequency_hz[i] - 1.0
            ez[i] = zeta[0] / self.damping_ratio[i] - 1.0
            ek[i] = k[0] / self.stiffness_N_m[i] - 1.0
            mac[i] = np.einsum("mi,mi->m", u[0], self.directions[i]) ** 2
            extrap[i] = beyond[0]
            dist[i] = d[0]
        return LOOResult(self.joints_deg, self.natural_frequency_hz, ef, ez, ek, mac, extrap, dist)

    def to_dict(self) -> dict:
        """The identified poses, matched modes and options, as plain lists."""
        return {
            "joints_deg": self.joints_deg.tolist(),
            "natural_frequency_hz": self.natural_frequency_hz.tolist(),
            "damping_ratio": self.damping_ratio.tolist(),
            "stiffness_N_m": self.stiffness_N_m.tolist(),
            "directions": self.directions.tolist(),
            "residual_compliance_m_N": self.residual_compliance_m_N.tolist(),
            "reference_pose": self.reference_pose,
            "mode_index": None if self.mode_index is None else self.mode_index.tolist(),
            "dropped_modes": [list(x) for x in self.dropped_modes],
            "span_dimension": self.span_dimension,
            "kernel": self.kernel,
            "span_tol_deg": self.span_tol_deg,
            "subspace_tol_deg": self.subspace_tol_deg,
            "hull_tol_deg": self.hull_tol_deg,
        }
