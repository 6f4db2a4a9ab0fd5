"""Stability of every point of a checked toolpath (:func:`planner.check.check_toolpath`, item 3),
by structure group.

Distinct modal models (after rounding) x cut frames x radial engagement x milling mode form a
*structure group*. Its two ZOA eigenvalue branches are computed once on the chatter-frequency grid
of :func:`stability.zoa.default_chatter_frequencies` and continued in frequency (each follows one
eigenvalue through the swaps of their order, :meth:`stability.zoa.ZOACurves.continued`); every
spindle speed of the group is then solved on that grid exactly as :func:`stability.zoa.envelope`
solves one speed (candidate lobe intervals, the same 1.25 preselection, a bracketed Illinois solve
of the phase condition), in a loop compiled by numba (:mod:`stability.zoa_batch`; numpy over
10^4 frequencies costs about 5 ms per group, the compiled loop about 1.2 ms of CPU). The grid
does not depend on the speed, so a path at many speeds on one pose costs one grid and a cheap
solve per speed.

The nearest stable speed at a chatter point is exact on the same grid: the unstable speeds at the
planned depth are the images, under every lobe's speed map ``n_k(f) = 60 f / (N (eps / 2 pi + k))``,
of the frequency runs where a branch's critical depth is below the allowed one (run ends solved
for); the connected unstable set around the planned speed ends at the candidates, each verified by
the limit solve there (and moved outwards by up to 1e-4 of itself when the sampled images missed a
lobe's turning point between two grid frequencies).

``method='sdm'`` computes one semi-discretization limit per distinct (structure group, speed)
through :func:`stability.lobes.lobe_diagram` (seconds each) and finds the nearest stable speed on a
200-speed SDM lobe diagram refined by bisection.
"""

from __future__ import annotations

import sys

import numpy as np

from oma.cutting import Cut
from stability import zoa_batch as _zoa_batch

__all__ = ["stability_zoa", "stability_sdm"]

#: Structure groups per compiled-kernel call (granularity of the progress bar).
_CHUNK = 64
#: SDM nearest-speed search: speeds of the lobe diagram, bisection steps of the boundary.
_SDM_GRID, _SDM_BISECT = 200, 12


def _mode_weights(models, frames: np.ndarray, b0: np.ndarray, model_id, frame_id, b0_id):
    """Per structure group: ``W_r = v_r[:2] (B0^T v_r)^T`` and ``W_res = (R Res R^T)[:2] B0``."""
    rot = frames[frame_id]  # (G, 3, 3)
    v = np.einsum("gij,gmj->gmi", rot, models.dirs[model_id])  # mode directions in the cut frame
    bt = b0[b0_id]  # (G, 3, 2)
    w = np.einsum("gmi,gjl,gmj->gmil", v[:, :, :2], bt, v)
    res = np.einsum("gip,gpq,gjq->gij", rot, models.res[model_id], rot)
    wres = np.einsum("gij,gjl->gil", res[:, :2, :], bt)
    return np.ascontiguousarray(w), np.ascontiguousarray(wres)


def stability_zoa(tool, models, frames, b0, sg_model, sg_frame, sg_b0, q_group, q_rpm, q_thr, q_lo, q_hi,
                   q_near, n_freq, progress, counts):
    """ZOA limits (and nearest stable speeds) of every query, grouped by structure group."""
    order = np.argsort(q_group, kind="stable")
    n_groups = sg_model.size
    ptr = np.searchsorted(q_group[order], np.arange(n_groups + 1))
    w, wres = _mode_weights(models, frames, b0, sg_model, sg_frame, sg_b0)
    fn = np.ascontiguousarray(models.fn[sg_model])
    f_lo, f_hi = fn.min(axis=1) / 3.0, fn.max(axis=1) * 3.0
    args = [np.ascontiguousarray(a[order]) for a in (q_rpm, q_thr, q_lo, q_hi)]
    near = np.ascontiguousarray(q_near[order])
    depth, freq, nearest = (np.empty(order.size) for _ in range(3))
    scan = _zoa_batch.scan_kernel()
    from tqdm import tqdm

    with tqdm(total=n_groups, desc="check: stability", unit="group", file=sys.stderr, disable=not progress) as bar:
        for g0 in range(0, n_groups, _CHUNK):
            g1 = min(n_groups, g0 + _CHUNK)
            q0, q1 = ptr[g0], ptr[g1]
            sel = slice(g0, g1)
            # modes that do not act in the plane of any of these cuts (W_r = 0: e.g. along the tool
            # axis) add nothing to G_or B0 and are left out of the loop (they still set the grid)
            act = np.flatnonzero(np.any(w[sel] != 0, axis=(0, 2, 3)))
            pick = lambda a: np.ascontiguousarray(a[sg_model[sel]][:, act])  # noqa: E731
            scan(np.ascontiguousarray(fn[sel][:, act]), pick(models.zeta), pick(models.stiff),
                 np.ascontiguousarray(w[sel][:, act]), wres[sel], f_lo[sel], f_hi[sel],
                 float(tool.teeth), int(n_freq), (ptr[g0:g1 + 1] - q0).astype(np.int64),
                 *(a[q0:q1] for a in args), near[q0:q1], depth[q0:q1], freq[q0:q1], nearest[q0:q1])
            counts["structure_groups"] += g1 - g0
            bar.update(g1 - g0)
    out = [np.empty(order.size) for _ in range(3)]
    for dst, src in zip(out, (depth, freq, nearest)):
        dst[order] = src
    counts["limits"] += int(order.size)
    counts["nearest_stable"] += int(np.count_nonzero(q_near & (out[0] < q_thr)))
    return out


def _sdm_limit(model, tool, cut, coefficients, rpm):
    from stability.lobes import lobe_diagram

    d = lobe_diagram(model, tool, cut, coefficients, rpm_range=(rpm, 2.0 * rpm), rpm=[rpm], method="sdm")
    return float(d.depth_limit_m[0]), float(d.chatter_frequency_hz[0])


def _sdm_nearest(model, tool, cut, coefficients, rpm0, thr, lo, hi):
    """Nearest stable speed by SDM: the nearest stable speed of a 200-speed lobe diagram over
    ``[lo, hi]``, its boundary towards ``rpm0`` refined by bisection (a stable window narrower
    than the diagram's spacing can be missed)."""
    from stability.lobes import lobe_diagram

    target = min(max(rpm0, lo), hi)
    if target != rpm0 and _sdm_limit(model, tool, cut, coefficients, target)[0] >= thr:
        return float(target)
    diagram = lobe_diagram(model, tool, cut, coefficients, rpm_range=(lo, hi), n_rpm=_SDM_GRID, method="sdm")
    rpm, ok = np.asarray(diagram.rpm), np.asarray(diagram.depth_limit_m) >= thr
    if not ok.any():
        return np.nan
    j = int(np.flatnonzero(ok)[np.argmin(np.abs(rpm[ok] - target))])
    good = rpm[j]
    nb = j - 1 if good > target else j + 1  # the grid neighbour towards the planned speed: unstable
    bad = rpm[nb] if 0 <= nb < rpm.size and (rpm[nb] - target) * (good - target) > 0 else target
    for _ in range(_SDM_BISECT):
        mid = 0.5 * (good + bad)
        if _sdm_limit(model, tool, cut, coefficients, mid)[0] >= thr:
            good = mid
        else:
            bad = mid
    return float(good)


def stability_sdm(tool, coefficients, models, frames, sg_model, sg_frame, sg_cut, q_group, q_rpm, q_thr, q_lo,
                   q_hi, q_near, progress, counts):
    from tqdm import tqdm

    n = q_group.size
    depth, freq, nearest = np.empty(n), np.empty(n), np.full(n, np.nan)
    for q in tqdm(range(n), desc="check: SDM", file=sys.stderr, disable=not progress):
        g = q_group[q]
        model = models.model(sg_model[g])
        rot = frames[sg_frame[g]]
        cut = Cut(sg_cut[g][0], sg_cut[g][1], sg_cut[g][2], rot[0], rot[1])
        depth[q], freq[q] = _sdm_limit(model, tool, cut, coefficients, q_rpm[q])
        if q_near[q] and depth[q] < q_thr[q]:
            nearest[q] = _sdm_nearest(model, tool, cut, coefficients, q_rpm[q], q_thr[q], q_lo[q], q_hi[q])
            counts["nearest_stable"] += 1
    counts["structure_groups"] += int(np.unique(q_group).size)
    counts["limits"] += n
    return depth, freq, nearest
