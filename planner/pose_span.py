"""The span of the identified poses: which poses :class:`planner.poses.PoseModels` answers for, and
where a pose lies in it (the weights of its piecewise-linear interpolation).

Let ``q_i`` be the identified poses (degrees), ``c`` their mean and ``V_d`` the first ``d``
right-singular vectors of the centred matrix ``[q_i - c]``, ``d`` the smallest number such that
every ``q_i`` lies within ``subspace_tol_deg`` of the affine subspace ``c + span(V_d)`` (the
joint directions the poses *actually* vary in). A pose ``q`` has span coordinates
``z = V_d^T (q - c)``. It is **in the span** when both hold:

- *(along)* ``z`` lies in the convex hull of the ``z_i``, up to ``hull_tol_deg`` (Euclidean
  distance in the span coordinates; for ``d = 1`` this is the range ``[min z_i, max z_i]``);
- *(across)* its distance to the identified span, ``distance_deg``, is at most ``span_tol_deg``.
  ``distance_deg`` is the Euclidean distance in joint space (degrees) to: the single pose
  (``d = 0``); the polyline through the poses in the order of ``z`` (``d = 1``, so poses along a
  gently curved joint path count as 1-D as long as they stay within ``subspace_tol_deg`` of a
  line); the hull of the ``z_i`` combined with the distance to the subspace,
  ``sqrt(|(q - c) - V_d z|^2 + dist(z, hull)^2)`` (``d >= 2``).

So going past the first or last identified pose along the span is flagged (beyond rounding),
while a joint that never varied may deviate by up to ``span_tol_deg``. Values are never
extrapolated: they are evaluated at the point of the hull nearest to ``z`` (the clipped range for
``d = 1``), which is ``z`` itself for a pose inside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import Delaunay, QhullError

from oma.errors import ModelError

__all__ = ["PoseOutOfSpanError", "Span"]

#: Weight of the sum-to-one row in the non-negative least squares of the nearest hull point, in
#: units of the hull's extent: the weights then sum to one within ~1e-9.
_NNLS_WEIGHT = 1e5


class PoseOutOfSpanError(ValueError):
    """A pose outside the span of the identified poses was asked for.

    Attributes
    ----------
    joints_deg : ndarray
        The pose, degrees.
    distance_deg : float
        Its distance to the identified span, degrees.
    beyond_range : bool
        Whether it lies beyond the identified poses along the span.
    """

    def __init__(self, joints_deg, distance_deg: float, beyond_range: bool, span_tol_deg: float):
        self.joints_deg = np.asarray(joints_deg, dtype=float)
        self.distance_deg = float(distance_deg)
        self.beyond_range = bool(beyond_range)
        why = "beyond the identified poses along the span" if beyond_range else (
            f"{self.distance_deg:.3g} deg from the span (tolerance {span_tol_deg:g} deg)")
        pose = ", ".join(f"{q:.6g}" for q in self.joints_deg)
        super().__init__(f"pose [{pose}] deg is outside the span of the identified poses: {why}")



@dataclass(frozen=True)
class Span:
    """The identified poses' span: principal subspace, coordinates and hull (see module doc)."""

    poses: np.ndarray  # (n, nj)
    center: np.ndarray  # (nj,)
    basis: np.ndarray  # (nj, d)
    coords: np.ndarray  # (n, d)
    order: np.ndarray | None = None  # d == 1: poses sorted along the span
    triangulation: Delaunay | None = None  # d >= 2

    @property
    def dimension(self) -> int:
        return int(self.basis.shape[1])

    @classmethod
    def build(cls, poses: np.ndarray, subspace_tol_deg: float) -> "Span":
        n, nj = poses.shape
        center = poses.mean(axis=0)
        x = poses - center
        _, _, vt = np.linalg.svd(x, full_matrices=True)
        d = 0
        for d in range(0, min(n - 1, nj) + 1):
            basis = vt[:d].T
            off = x - (x @ basis) @ basis.T
            if np.max(np.linalg.norm(off, axis=1)) <= subspace_tol_deg:
                break
        basis = vt[:d].T
        coords = x @ basis
        if n > 1:
            gap = np.linalg.norm(coords[:, None, :] - coords[None, :, :], axis=-1)
            gap[np.diag_indices(n)] = np.inf
            i, j = np.unravel_index(np.argmin(gap), gap.shape)
            if gap[i, j] <= subspace_tol_deg:
                raise ModelError(None, f"models[{max(i, j)}].pose.joints_deg",
                                 f"a pose apart from models[{min(i, j)}]'s (more than {subspace_tol_deg:g} deg "
                                 "along the span of the poses)",
                                 f"{gap[i, j]:.3g} deg apart: merge the two models or leave one out")
        order = tri = None
        if d == 1:
            order = np.argsort(coords[:, 0], kind="stable")
        elif d >= 2:
            try:
                tri = Delaunay(coords)
            except QhullError as exc:  # degenerate even though the SVD says d-dimensional
                raise ValueError(f"the poses' span could not be triangulated in {d} dimensions: {exc}") from exc
        return cls(poses=poses, center=center, basis=basis, coords=coords, order=order, triangulation=tri)

    def locate(self, q: np.ndarray, hull_tol_deg: float):
        """Span coordinates of the nearest point of the hull, pose weights there, and the tests.

        Parameters
        ----------
        q : ndarray, shape (m, nj)

        Returns
        -------
        z_near : ndarray, shape (m, d)
            The point of the hull nearest to each pose's span coordinates.
        weights : ndarray, shape (m, n)
            Piecewise-linear (barycentric) weights of the identified poses at ``z_near``;
            non-negative, summing to one.
        beyond : ndarray of bool, shape (m,)
            Span coordinates outside the hull by more than ``hull_tol_deg``.
        distance : ndarray, shape (m,)
            Distance to the identified span, degrees (module doc).
        """
        m = q.shape[0]
        n = self.poses.shape[0]
        d = self.dimension
        x = q - self.center
        z = x @ self.basis
        weights = np.zeros((m, n))
        if d == 0:
            weights[:] = 1.0
            distance = np.linalg.norm(x, axis=1)
            return z, weights, np.zeros(m, dtype=bool), distance
        if d == 1:
            return self._locate_1d(q, z, hull_tol_deg)
        off = np.linalg.norm(x - z @ self.basis.T, axis=1)
        tri = self.triangulation
        simplex = tri.find_simplex(z)
        inside = simplex >= 0
        z_near = z.copy()
        gap = np.zeros(m)
        if np.any(inside):
            s = simplex[inside]
            t = tri.transform[s]
            b = np.einsum("ijk,ik->ij", t[:, :d], z[inside] - t[:, d])
            bary = np.column_stack([b, 1.0 - b.sum(axis=1)])
            bary = np.clip(bary, 0.0, None)
            bary /= bary.sum(axis=1, keepdims=True)
            rows = np.flatnonzero(inside)
            np.add.at(weights, (rows[:, None], tri.simplices[s]), bary)
        for i in np.flatnonzero(~inside):
            w = self._hull_weights(z[i])
            weights[i] = w
            z_near[i] = w @ self.coords
            gap[i] = np.linalg.norm(z[i] - z_near[i])
        distance = np.hypot(off, gap)
        return z_near, weights, gap > hull_tol_deg, distance

    def _locate_1d(self, q, z, hull_tol_deg):
        m = q.shape[0]
        n = self.poses.shape[0]
        t_sorted = self.coords[self.order, 0]
        p_sorted = self.poses[self.order]
        t = z[:, 0]
        beyond = (t < t_sorted[0] - hull_tol_deg) | (t > t_sorted[-1] + hull_tol_deg)
        tc = np.clip(t, t_sorted[0], t_sorted[-1])
        seg = np.clip(np.searchsorted(t_sorted, tc, side="right") - 1, 0, n - 2)
        frac = (tc - t_sorted[seg]) / (t_sorted[seg + 1] - t_sorted[seg])
        weights = np.zeros((m, n))
        rows = np.arange(m)
        weights[rows, self.order[seg]] = 1.0 - frac
        weights[rows, self.order[seg + 1]] += frac
        # distance to the polyline through the poses (in joint space)
        distance = np.full(m, np.inf)
        for k in range(n - 1):
            a = p_sorted[k]
            v = p_sorted[k + 1] - a
            s = np.clip(((q - a) @ v) / (v @ v), 0.0, 1.0)
            distance = np.minimum(distance, np.linalg.norm(q - a - s[:, None] * v, axis=1))
        return tc[:, None], weights, beyond, distance

    def _hull_weights(self, z: np.ndarray) -> np.ndarray:
        """Convex weights of the hull point nearest to ``z`` (non-negative least squares with a
        heavily weighted sum-to-one row, in coordinates scaled to the hull's extent)."""
        zc = self.coords
        mid = zc.mean(axis=0)
        scale = max(float(np.max(np.ptp(zc, axis=0))), 1e-300)
        a = np.vstack([((zc - mid) / scale).T, np.full(zc.shape[0], _NNLS_WEIGHT)])
        b = np.append((z - mid) / scale, _NNLS_WEIGHT)
        w, _ = nnls(a, b)
        return w / w.sum()
