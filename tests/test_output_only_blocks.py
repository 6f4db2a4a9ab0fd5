"""Adjacent bins pooled into blocks (issue 14, session 24; :mod:`oma.output_only.blocks`): where the
model spectrum is the same at a block's bins, the pooled Whittle likelihood is theirs exactly;
where it varies, the difference shrinks as the blocks narrow; and a refinement on pooled bins ends
where the refinement on the bins does. Ground truth: closed forms (a flat spectrum) and
lightly damped modes synthesised in the frequency domain (modal superposition, nothing of
robomill's simulator)."""

from __future__ import annotations

import numpy as np
import pytest
from frequency_domain_records import modal_superposition

import oma.output_only._ml_fit as ml_fit
import oma.output_only.blocks as blocks
import oma.output_only.ml as ml
from oma.output_only.blocks import block_bins, pool
from oma.output_only.whittle import _fisher, _Model, _nll, _spectrum

FS, DURATION = 2000.0, 15.0
#: Three overlapping modes of 0.8-2 % at 350-365 Hz (the Hurco files' kind) and a sharp one at 530 Hz:
#: frequency (Hz), damping ratio, direction.
MODES = [(350.0, 0.008, [1, 0.3, 0.1]), (357.0, 0.010, [0.2, 1, 0.3]), (365.0, 0.02, [0.3, 0.2, 1]),
         (530.0, 0.002, [1, 1, 0.2])]


def _bins(rng, k=3000, l=3, lo=300.0, hi=420.0):
    f = np.linspace(lo, hi, k)
    return 2 * np.pi * f, (rng.standard_normal((k, l)) + 1j * rng.standard_normal((k, l))) / np.sqrt(2)


def test_blocks_follow_the_rule_and_pool_the_periodogram():
    """Every block spans at most a tenth of the local scale (single bins at a mode's start), the
    blocks' roots give the summed periodogram matrices, and their number is a fraction of the bins."""
    rng = np.random.default_rng(0)
    w, x = _bins(rng)
    fr, zr = np.array([350.0, 365.0]), np.array([0.01, 0.02])
    b = block_bins(w, fr, zr)
    assert b is not None and 5 * b.n.size < w.size
    f = w[b.order] / (2 * np.pi)
    ends = np.append(b.starts[1:], f.size) - 1
    span = f[ends] - f[b.starts]
    for fe in (f[b.starts], f[ends]):
        scale = np.min(np.maximum(np.abs(fe[:, None] - fr), np.minimum(zr, blocks.BLOCK_PEAK_DAMPING) * fr), axis=1)
        assert np.all(span <= np.minimum(scale / blocks.BLOCK_RESOLUTION, blocks.BLOCK_MAX_RELATIVE * fe) + 1e-12)
    assert np.all(b.n[np.abs(b.w / (2 * np.pi) - 350.0) < 0.2] == 1)
    roots = pool(b, x)
    xs = x[b.order]
    for j in (0, b.n.size // 2, b.n.size - 1):
        sl = slice(b.starts[j], b.starts[j] + int(b.n[j]))
        np.testing.assert_allclose(roots[j] @ roots[j].conj().T, xs[sl].T @ xs[sl].conj(), atol=1e-12)
    assert block_bins(w[:900], fr, zr) is None   # under BLOCK_MIN_BINS: the bins as they are


def _model(w, m, weight=None):
    gain = w ** 4
    return _Model(m, 3, w, gain / gain.mean(), np.zeros((w.size, 3, 0), dtype=complex), True,
                  (np.array([350.0, 365.0][:m]), np.array([0.01, 0.02][:m])), slope=True, weight=weight)


def _params(m, rng):
    lc = np.tril(rng.standard_normal((m, m))) + 2 * np.eye(m)
    ln = np.tril(0.3 * rng.standard_normal((3, 3))) + np.eye(3)
    return np.concatenate([0.3 * rng.standard_normal(m), np.log([0.01, 0.02][:m]), rng.standard_normal(3 * m),
                           lc[np.tril_indices(m)], ln[np.tril_indices(3)], [0.4]])


def test_a_flat_spectrum_pooled_is_the_bins_exactly():
    """No mode: ``S = N`` at every bin, so the blocks' likelihood, gradient and information are the
    bins' to rounding (the closed form ``n log det N + tr(N^-1 sum x x^H)``)."""
    rng = np.random.default_rng(1)
    w, x = _bins(rng)
    b = block_bins(w, [350.0, 365.0], [0.01, 0.02])
    exact = _model(w[b.order], 0)
    pooled = _model(b.w, 0, weight=b.n)
    ln = np.tril(0.3 * rng.standard_normal((3, 3))) + np.eye(3)
    p = np.concatenate([ln[np.tril_indices(3)], [0.4]])
    v0, g0 = _nll(p, exact, x[b.order])
    v1, g1 = _nll(p, pooled, pool(b, x))
    assert v1 == pytest.approx(v0, rel=1e-11)
    np.testing.assert_allclose(g1, g0, rtol=1e-9, atol=1e-9 * np.abs(g0).max())
    # the slope multiplies no mode here: its information is the prior's alone either way
    np.testing.assert_allclose(_fisher(p, pooled), _fisher(p, exact), rtol=1e-9)
    per_block = _nll(p, pooled, pool(b, x), per_bin=True)[1]
    np.testing.assert_allclose(per_block.sum(axis=0)[:-1], g0[:-1], rtol=1e-9, atol=1e-9 * np.abs(g0).max())


def test_with_modes_the_pooled_likelihood_converges_to_the_bins_as_blocks_narrow(monkeypatch):
    """Two modes in the band: the pooled likelihood's error against the bins' falls with the
    blocks' width (about as its square), and so does its gradient's."""
    rng = np.random.default_rng(2)
    w, _ = _bins(rng)
    p = _params(2, rng)
    exact = _model(w, 2)
    # data drawn from the model itself (the Whittle likelihood's own distribution)
    s = _spectrum(p, exact)[-1]
    chol = np.linalg.cholesky(s)
    x = (chol @ ((rng.standard_normal((w.size, 3)) + 1j * rng.standard_normal((w.size, 3))) / np.sqrt(2))[..., None])[..., 0]
    v0, g0 = _nll(p, exact, x)
    errors = []
    for r in (10.0, 30.0, 100.0):
        monkeypatch.setattr(blocks, "BLOCK_RESOLUTION", r)
        b = block_bins(w, [350.0, 365.0], [0.01, 0.02])
        gain = b.w ** 4
        pooled = exact._replace(w=b.w, gain=gain / np.mean(w ** 4), fx=np.zeros((b.w.size, 3, 0), dtype=complex),
                                weight=b.n)
        # the same parametrisation: the gain normalised by the bins' mean, the slope's centre theirs
        monkeypatch.setattr(_Model, "w_c", property(lambda self: float(np.sqrt(w.min() * w.max()))))
        v1, g1 = _nll(p, pooled, pool(b, x))
        monkeypatch.undo()
        errors.append((abs(v1 - v0), np.abs(g1 - g0).max()))
    # a tenth of the scale: ``S`` off by about 6 / 24 / 10^2 of itself off the peaks, where it falls
    # as the distance squared (measured 1.1e-3 per bin); 3.4 and 10 times narrower: 6 and 13 times less
    assert errors[0][0] < 2e-3 * w.size
    for coarse, fine in zip(errors, errors[1:]):
        assert fine[0] < coarse[0] / 4 and fine[1] < coarse[1] / 2.5


def test_a_refinement_on_pooled_bins_ends_where_the_bins_do(monkeypatch):
    """The 350-365 Hz group (about 2 000 bins, pooled) refined both ways and each carried to its
    optimum: frequencies and damping within a tenth of their standard errors of each other, the
    errors themselves within 15 %; the sharp 530 Hz mode's small band is not pooled."""
    monkeypatch.setattr(ml_fit, "FINISH_MIN_GAIN", 0.0)
    monkeypatch.setattr(ml_fit, "FINISH_DECREMENT", 0.0)
    finish = ml_fit._finish
    monkeypatch.setattr(ml, "_finish", lambda p, mod, x, **kw: finish(p, mod, x, max_iter=300))
    x = modal_superposition(MODES, FS, DURATION, 0)
    rng = np.random.default_rng(1000)
    f0 = np.array([m[0] for m in MODES]) * (1 + 0.001 * rng.standard_normal(len(MODES)))
    z0 = np.array([m[1] for m in MODES]) * np.exp(0.3 * rng.standard_normal(len(MODES)))
    u0 = np.array([np.asarray(m[2], dtype=float) / np.linalg.norm(m[2]) for m in MODES]).T
    pooled = ml.refine_modes_ml([x], FS, f0, z0, u0, derivative=2, band_hz=(20.0, 900.0))
    monkeypatch.setattr(ml, "block_bins", lambda *a, **k: None)
    bins = ml.refine_modes_ml([x], FS, f0, z0, u0, derivative=2, band_hz=(20.0, 900.0))
    assert pooled.fitted.all() and bins.fitted.all()
    fb, zb, seb = bins.freq_hz, bins.damping, bins.standard_errors
    fp, zp, sep = pooled.freq_hz, pooled.damping, pooled.standard_errors
    assert np.all(np.abs(fp - fb) < 0.1 * seb[0])
    assert np.all(np.abs(np.log(zp / zb)) < 0.1 * seb[1])
    assert np.all(np.abs(sep[:2] / seb[:2] - 1) < 0.15)
    assert fp[3] == fb[3] and zp[3] == zb[3]
    # and both near the truth (within 3 of their standard errors)
    ft, zt = np.array([m[0] for m in MODES]), np.array([m[1] for m in MODES])
    assert np.all(np.abs(fp - ft) < 3 * sep[0]) and np.all(np.abs(np.log(zp / zt)) < 3 * sep[1])


def test_the_physical_generator_is_the_modal_one_for_proportional_damping_and_complex_otherwise():
    """``physical_superposition`` (the receptance of ``M x'' + C x' + K x`` solved per bin) gives
    ``modal_superposition``'s record for a diagonal system of unit masses (the same draws; to
    rounding), and ``physical_modes`` its frequencies and damping with real modes. A damper
    between two axes makes the close pair's modes complex; each pole ``s`` it reports is a root of
    ``det(K + s C + s^2 M) = 0``."""
    from frequency_domain_records import modal_superposition, physical_modes, physical_superposition

    f = np.array([10.5, 24.8, 10.0])
    zeta = np.array([0.05, 0.04, 0.05])
    w = 2 * np.pi * f
    m, c, k = np.eye(3), np.diag(2 * zeta * w), np.diag(w ** 2)
    modes = [(f[i], zeta[i], np.eye(3)[i]) for i in range(3)]
    y_modal = modal_superposition(modes, 1000.0, 4.0, 7)
    y_phys = physical_superposition(m, c, k, 1000.0, 4.0, 7)
    assert np.max(np.abs(y_phys - y_modal)) < 1e-12 * np.max(np.abs(y_modal))
    fr, zr, cx = physical_modes(m, c, k)
    np.testing.assert_allclose(fr, np.sort(f), rtol=1e-12)
    np.testing.assert_allclose(zr, zeta[np.argsort(f)], rtol=1e-12)
    assert np.all(cx < 1e-12)
    coupled = c + 2.0 * np.array([[1.0, 0, -1], [0, 0, 0], [-1, 0, 1]])
    fr, zr, cx = physical_modes(m, coupled, k)
    assert np.all(cx[:2] > 0.1) and cx[2] < 1e-12
    for fk, zk in zip(fr, zr):
        s = 2 * np.pi * fk * (-zk + 1j * np.sqrt(1 - zk ** 2))
        assert abs(np.linalg.det(k + s * coupled + s ** 2 * m)) < 1e-9 * np.linalg.det(k)
