"""Matching modes across robot poses: the modal assurance criterion and the assignment of every
pose's modes to the reference pose's (step 1 of :meth:`planner.poses.PoseModels.fit`, whose module
notes give the rule)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["mac_matrix", "match_modes"]

#: Cost of a forbidden pairing in the assignment (any allowed pairing costs < 2 + ln(1 + change)).
_FORBIDDEN = 1e6


def mac_matrix(a, b) -> np.ndarray:
    """Modal assurance criterion between two sets of real mode shapes.

    Parameters
    ----------
    a : array_like, shape (n_a, n_dof)
    b : array_like, shape (n_b, n_dof)

    Returns
    -------
    ndarray, shape (n_a, n_b)
        ``MAC_ij = (a_i . b_j)^2 / (|a_i|^2 |b_j|^2)``, in [0, 1]; insensitive to sign and scale
        (Allemang, Sound & Vibration 37(8), 2003).
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.atleast_2d(np.asarray(b, dtype=float))
    num = (a @ b.T) ** 2
    den = np.sum(a * a, axis=1)[:, None] * np.sum(b * b, axis=1)[None, :]
    return num / den



def match_modes(models, dist, reference, min_mac, max_log_ratio):
    """Assign every pose's modes to the reference modes (module doc).

    Returns ``assign`` (n_poses, n_ref) with the mode index at each pose or -1, and ``sign``
    (n_poses, n_ref), +-1, that aligns each matched direction with its template.
    """
    n = len(models)
    n_ref = models[reference].n_modes
    assign = np.full((n, n_ref), -1, dtype=int)
    sign = np.ones((n, n_ref))
    assign[reference] = np.arange(n_ref)
    done = [reference]
    todo = [p for p in range(n) if p != reference]
    while todo:
        near = dist[np.ix_(todo, done)].min(axis=1)
        p = todo.pop(int(np.argmin(near)))
        tf, tu, rows = [], [], []
        for r in range(n_ref):
            have = [s for s in done if assign[s, r] >= 0]
            if not have:
                continue
            s = have[int(np.argmin(dist[p, have]))]
            j = assign[s, r]
            rows.append(r)
            tf.append(models[s].natural_frequency_hz[j])
            tu.append(models[s].directions[j] * sign[s, r])
        done.append(p)
        if not rows:
            continue
        tf, tu = np.array(tf), np.array(tu)
        model = models[p]
        mac = mac_matrix(tu, model.directions)
        log_ratio = np.abs(np.log(model.natural_frequency_hz[None, :] / tf[:, None]))
        allowed = (mac >= min_mac) & (log_ratio <= max_log_ratio)
        cost = np.where(allowed, (1.0 - mac) + log_ratio, _FORBIDDEN)
        ri, ci = linear_sum_assignment(cost)
        for a, b in zip(ri, ci):
            if allowed[a, b]:
                r = rows[a]
                assign[p, r] = b
                sign[p, r] = 1.0 if tu[a] @ model.directions[b] >= 0 else -1.0
    return assign, sign
