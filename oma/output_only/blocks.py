"""Adjacent periodogram bins pooled into blocks where the model spectrum is flat across them: the
Whittle likelihood of a wide band at a fraction of its cost (:mod:`oma.output_only.ml` uses it
for groups of many bins).

Where the spectral matrix ``S`` is the same at ``n`` adjacent bins, their Whittle terms add to

    sum_k log det S + x_k^H S^-1 x_k  =  n log det S + tr(S^-1 P),    P = sum_k x_k x_k^H,

the likelihood of the pooled periodogram ``P / n`` (complex Wishart with ``n`` degrees of
freedom): the block is one term evaluated once, at its bins' mean frequency. ``P`` enters as
a root ``X`` (l, l) with ``X X^H = P``, so the likelihood's loops take a block as they take a bin
(``x`` is the root's single column there), each term weighted by ``n`` in its ``log det S`` and,
through it, in the information. The approximation is ``S``'s variation inside a block; evaluated
at the bins' mean, the first order cancels and what is left is ``S''`` times the block's width
squared over 24. Near a mode's peak ``S`` varies on the scale of its half-power half-width
``zeta f``, away from it on the scale of the distance ``|f - f_r|``: a block spans at most
1 / :data:`BLOCK_RESOLUTION` of the larger of the two (a peak's height is then off by at most
``1 / (12 R^2)``, 0.08 %), with ``zeta`` taken at most :data:`BLOCK_PEAK_DAMPING` (a start's
damping from SSI may be several times the true one: the peak's region is resolved as if the
mode were that sharp) and the width at most :data:`BLOCK_MAX_RELATIVE` of the frequency (the
derivative gain ``w^(2d)``, the input's slope and the tails change on the scale of ``f``). So the
blocks are single bins around each mode's start and grow in proportion to the distance from
it: their number grows with the logarithm of the band's width, not with the band.

Why: on the real Hurco accelerations (15 s at 0.067 Hz per bin, modes of 0.1-2 % damping at
300-600 Hz) a group's band of +-6 half-power widths holds 2 000-2 300 bins, and its fits
(likelihood, gradient and information per bin) took 3.2 of the 5.3 s of the slowest file
(session 24, docs/output_only.md).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Blocks", "block_bins", "pool"]

#: A group's bins are pooled only from this many (under it a group's likelihood costs about a
#: millisecond per evaluation, and the bins are kept as they are).
BLOCK_MIN_BINS = 1000
#: A block spans at most this fraction of the local scale of the spectrum (the larger of the
#: nearest mode's half-power half-width and the distance to it).
BLOCK_RESOLUTION = 10.0
#: The damping ratio at most assumed for a mode's peak when the blocks are laid out.
BLOCK_PEAK_DAMPING = 1e-3
#: A block spans at most this fraction of its frequency.
BLOCK_MAX_RELATIVE = 5e-3


class Blocks(NamedTuple):
    """A partition of a group's bins: ``order`` sorts them by frequency, ``starts`` indexes the
    first of each block in that order, ``n`` (B,) counts each block's bins and ``w`` (B,) is their
    mean angular frequency."""

    order: np.ndarray
    starts: np.ndarray
    n: np.ndarray
    w: np.ndarray


def block_bins(w, freq_hz, damping, *, min_bins: int = BLOCK_MIN_BINS) -> Blocks | None:
    """The blocks of the bins at angular frequencies ``w`` (K,) for a spectrum whose modes start at
    ``freq_hz``, ``damping`` (the rule in the module's docstring); None when the group has fewer
    than ``min_bins`` bins or pooling would not halve their number."""
    w = np.asarray(w, dtype=float)
    if w.size < max(int(min_bins), 2):
        return None
    order = np.argsort(w, kind="stable")
    f = w[order] / (2 * np.pi)
    fr = np.asarray(freq_hz, dtype=float).ravel()
    zr = np.minimum(np.asarray(damping, dtype=float).ravel(), BLOCK_PEAK_DAMPING)
    if fr.size:
        scale = np.min(np.maximum(np.abs(f[:, None] - fr[None, :]), (zr * fr)[None, :]), axis=1)
    else:
        scale = np.full(f.size, np.inf)
    span = np.minimum(scale / BLOCK_RESOLUTION, BLOCK_MAX_RELATIVE * f)
    starts = []
    i = 0
    while i < f.size:
        starts.append(i)
        # the block's span may not exceed the allowance at either of its ends (a peak inside a
        # block makes both ends' distances at most the span: then its half-width bounds it)
        j = int(np.searchsorted(f, f[i] + span[i], side="right"))
        while j - 1 > i and f[j - 1] - f[i] > span[j - 1]:
            j -= 1
        i = max(j, i + 1)
    starts = np.asarray(starts)
    if 2 * starts.size > f.size:
        return None
    n = np.diff(np.append(starts, f.size))
    return Blocks(order, starts, n.astype(float), np.add.reduceat(w[order], starts) / n)


def pool(blocks: Blocks, x) -> np.ndarray:
    """The roots ``X`` (B, l, l) of the blocks' summed periodogram matrices, ``X X^H = sum_k x_k
    x_k^H`` over each block's bins, of the DFT vectors ``x`` (K, l) taken at the bins
    :func:`block_bins` laid out."""
    x = np.asarray(x)[blocks.order]
    outer = x[:, :, None] * np.conj(x[:, None, :])
    p = np.add.reduceat(outer, blocks.starts, axis=0)
    ev, vec = np.linalg.eigh(0.5 * (p + np.conj(np.swapaxes(p, 1, 2))))
    return vec * np.sqrt(np.maximum(ev, 0.0))[:, None, :]
