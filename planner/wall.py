"""The surface location error on the whole finished wall, and where on the wall it is largest.

formats.md bounds ``|SLE|`` on the finished wall, not at the tool tip alone. With a helix, the
slice at height ``z`` above the tip reaches the finishing angle ``kappa z / Omega`` after the tip
(``kappa``: :func:`stability.oriented.helix_lag_per_m`), so the wall at ``z`` is the steady
displacement along the wall's normal at that later instant: harmonic ``h`` of the tooth-passing
frequency turns by ``exp(i h N kappa z)`` (the profile of :func:`stability.forced.forced_response`,
``surface_location_error_profile`` of :func:`stability.lobes.predict_point`, which samples it at
21 heights). The largest ``|SLE|`` can sit between those samples: :func:`largest_abs` searches a
grid that resolves the highest harmonic summed (:func:`wall_points`), zoomed in on its peaks.

* :func:`wall_error`: the largest ``|SLE|`` on the wall of a predicted cut and its height, from the
  forced response's displacement harmonics (the planner's re-check and its report);
* :func:`largest_abs`, :func:`local_maxima`, :func:`wall_points`: the search, shared with the
  planner's own wall model (:meth:`planner.cut_model.CutModel.wall_profile`).
"""

from __future__ import annotations

import numpy as np

from stability.lobes import OperatingPoint
from stability.oriented import helix_lag_per_m

__all__ = ["wall_error", "largest_abs", "local_maxima", "wall_points"]

TWO_PI = 2.0 * np.pi

# The dense search for the largest |SLE| on the wall: grid points per turn of the highest
# harmonic over the depth (then zoomed in, :func:`largest_abs`).
_WALL_POINTS_PER_TURN = 8
# Complex values per block of the dense evaluations (heights x harmonics): 16 MB.
_CHUNK = 2**20


def local_maxima(v) -> np.ndarray:
    """Indices of the local maxima of ``v`` (the ends included), largest first."""
    pad = np.concatenate([[-np.inf], v, [-np.inf]])
    peaks = np.flatnonzero((pad[1:-1] >= pad[:-2]) & (pad[1:-1] >= pad[2:]))
    return peaks[np.argsort(v[peaks])[::-1]]


def largest_abs(fn, lo: float, hi: float, n: int, *, keep: int = 3, zooms: int = 3) -> tuple[float, float]:
    """Largest ``|fn(z)|`` over ``[lo, hi]`` and where (``fn`` vectorised): a grid of ``n`` points,
    then ``zooms`` grids of 33 points between the neighbours of each of the ``keep`` best local
    maxima (each zoom shrinks the bracket 16 times)."""
    z = np.linspace(lo, hi, max(int(n), 3))
    v = np.abs(fn(z))
    best_v, best_z = float(v.max()), float(z[np.argmax(v)])
    for k in local_maxima(v)[:keep]:
        a, b = z[max(k - 1, 0)], z[min(k + 1, z.size - 1)]
        for _ in range(zooms):
            zz = np.linspace(a, b, 33)
            vv = np.abs(fn(zz))
            j = int(np.argmax(vv))
            if vv[j] > best_v:
                best_v, best_z = float(vv[j]), float(zz[j])
            a, b = zz[max(j - 1, 0)], zz[min(j + 1, zz.size - 1)]
    return best_v, best_z


def wall_points(n_harm: int, theta_1: float, ap: float) -> int:
    """Grid points for the dense search of ``|SLE|`` on a wall of height ``ap`` (m), harmonic 1
    turning by ``theta_1`` rad/m along it (``N kappa``): ``_WALL_POINTS_PER_TURN`` per turn of the
    highest harmonic over the depth, 17 to 8193."""
    turns = n_harm * theta_1 * ap / TWO_PI
    return int(np.clip(np.ceil(_WALL_POINTS_PER_TURN * turns) + 1, 17, 8193))


def wall_error(point: OperatingPoint, tool, cut) -> tuple[float, float]:
    """Largest ``|SLE|`` on the finished wall of a predicted cut, m, and its height above the
    tip, m: the steady displacement of :func:`stability.lobes.predict_point`'s forced response
    along the wall's normal at the instant each height is finished (the instant of the tip plus
    ``kappa z / Omega``; ``surface_location_error_profile`` samples the same function), on a grid
    that resolves every harmonic summed, zoomed in on its peaks."""
    fr = point.forced
    kappa = helix_lag_per_m(tool)
    omega = TWO_PI * fr.spindle_rpm / 60.0
    sign = 1.0 if cut.milling == "down" else -1.0
    normal = np.asarray(cut.normal_direction, dtype=float)

    def sle(z):
        t = fr.finishing_time_s + kappa * np.asarray(z) / omega
        step = max(1, _CHUNK // (fr.harmonics + 1))  # displacement_at holds (3, len(t), harmonics)
        return sign * np.concatenate([normal @ fr.displacement_at(t[i:i + step]) for i in range(0, t.size, step)])

    n = wall_points(fr.harmonics, tool.teeth * kappa, fr.axial_depth_m)
    return largest_abs(sle, 0.0, fr.axial_depth_m, n)
