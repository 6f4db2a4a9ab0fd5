"""The three parts of the comparison of records with the model: (a) the force (coefficients and
the force model), (b) the structure (the displacement response to the measured force), (c) the
stability (chatter or not, and at which frequency); :mod:`planner.diagnosis.compare` gives the
rules."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import special

from oma.cutting import CuttingCoefficients
from oma.modal import ModalModel
from oma.spectra import equivalent_averages

from .closedloop import closed_loop_force_psd
from .evaluation import HARMONIC_FRACTION, PartEvaluation, RecordView, _concat
from .forcemodel import analytic_harmonics, simulated_harmonics
from .response import free_response_basis, modal_response
from .spectral import (expected_welch, fold_frequency, harmonic_coefficients, harmonic_noise_variance, welch_kernel,
                       welch_psd)

__all__ = ["ForcePart", "StructurePart", "StabilityPart", "align_angle", "rotate"]

#: A displacement line is in the band of part (b) when its density exceeds this many noise densities.
BAND_SNR = 4.0
#: Number of grid offsets averaged in the quantisation-noise simulation.
N_OFFSETS = 6
#: Welch segment of part (c) as a fraction of the part (50 % overlap).
STABILITY_SEGMENT_FRACTION = 0.25


# ----------------------------------------------------------------------------- (a) force part
def align_angle(measured, predicted, weights=None) -> float:
    """Angle ``theta`` maximising the match of ``predicted * exp(-i h theta)`` to ``measured``.

    Parameters
    ----------
    measured, predicted : ndarray, complex, shape (3, H + 1)
    weights : ndarray, shape (3, H + 1), optional
        Inverse noise variances.
    """
    wts = np.ones(measured.shape) if weights is None else weights
    s = np.sum(wts * np.conj(measured) * predicted, axis=0)  # (H+1,)
    m = 2048
    # score(theta_k) = Re sum_h s_h exp(-i h theta_k) on theta_k = 2 pi k / m: one FFT
    score = np.real(np.fft.fft(s, n=max(m, s.size)))[:m] if s.size <= m else None
    if score is None:  # pragma: no cover - more than 2048 harmonics
        grid = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
        score = np.real(np.exp(-1j * np.outer(grid, np.arange(s.size))) @ s)
    step = 2.0 * np.pi / m
    i = int(np.argmax(score))
    # parabolic refinement on the grid
    a, b, c = score[i - 1], score[i], score[(i + 1) % m]
    den = a - 2 * b + c
    return float(i * step + (0.5 * (a - c) / den * step if den != 0 else 0.0))


def rotate(coefficients, theta) -> np.ndarray:
    """``c_h exp(-i h theta)``."""
    h = np.arange(coefficients.shape[-1])
    return coefficients * np.exp(-1j * h * theta)


class ForcePart:
    """Part (a): harmonic coefficients of the force, measured against predicted (module notes)."""

    name = "force"

    def __init__(self, views: Sequence[RecordView], model: ModalModel):
        self.views = list(views)
        self.model = model
        self.measured = {"fit": [], "val": []}
        self.noise = {"fit": [], "val": []}
        for v in self.views:
            for half in ("fit", "val"):
                x = v.force[:, v.half(half)]
                c, fitted = harmonic_coefficients(x, v.sample_rate_hz, v.spindle_hz, v.n_harm, t0=v.t0(half))
                self.measured[half].append(c)
                self.noise[half].append(harmonic_noise_variance(x - fitted, v.sample_rate_hz, v.spindle_hz, v.n_harm))
        self.baseline = [self.simulate(v) for v in self.views]
        # the vibration feedback the analytic (rigid-tool) force leaves out, added to its fits
        self.correction = [b - analytic_harmonics(v.tool, v.cut, v.coefficients, v.n_harm, spindle_hz=v.spindle_hz,
                                                  sample_rate_hz=v.sample_rate_hz)
                           for b, v in zip(self.baseline, self.views)]

    def simulate(self, view: RecordView, effects=None, model: ModalModel | None = None) -> np.ndarray:
        from stability.simulate import Effects

        return simulated_harmonics(self.model if model is None else model, view.tool, view.cut, view.coefficients,
                                   view.n_harm, spindle_hz=view.spindle_hz, sample_rate_hz=view.sample_rate_hz,
                                   effects=Effects() if effects is None else effects)

    def analytic(self, view_index: int, *, coefficients: CuttingCoefficients | None = None, **kwargs) -> np.ndarray:
        """Rigid-tool harmonics with ``kwargs`` of :func:`analytic_harmonics` (and ``coefficients``
        instead of the view's), plus the baseline's vibration feedback."""
        v = self.views[view_index]
        coef = v.coefficients if coefficients is None else coefficients
        c = analytic_harmonics(v.tool, v.cut, coef, v.n_harm, spindle_hz=v.spindle_hz,
                               sample_rate_hz=v.sample_rate_hz, **kwargs)
        return c + self.correction[view_index]

    def evaluate(self, half: str, predictions, *, views=None) -> PartEvaluation:
        """Error elements of ``predictions`` (one (3, H + 1) array per view, phase reference t = 0)."""
        idx = range(len(self.views)) if views is None else views
        items, den = [], 0.0
        for i in idx:
            y, s, p = self.measured[half][i], self.noise[half][i], predictions[i]
            theta = align_angle(y, p, 1.0 / np.maximum(s, 1e-30))
            items.append((y, rotate(p, theta), s, np.ones(y.shape)))
            den += float(np.sum(np.abs(y) ** 2) - np.sum(s))
        return _concat(self.name, items, den)


# ------------------------------------------------------------------------- (b) structure part
def _grid_noise_lines(pred, resolution, rng, n_offsets=N_OFFSETS):
    """E|N_k|^2 of the quantisation error of ``pred`` (rfft lines), averaged over grid offsets."""
    n = pred.shape[-1]
    acc = np.zeros((pred.shape[0], n // 2 + 1))
    for _ in range(n_offsets):
        off = rng.uniform(0.0, resolution)
        e = np.round((pred + off) / resolution) * resolution - (pred + off)
        acc += np.abs(np.fft.rfft(e, axis=-1)) ** 2
    acc /= n_offsets
    # smooth over +-3 lines: the expectation is smooth, one realisation is not
    kern = np.ones(7) / 7.0
    return np.stack([np.convolve(row, kern, mode="same") for row in acc])


class StructurePart:
    """Part (b): displacement from the measured force through the model (module notes)."""

    name = "structure"

    def __init__(self, views: Sequence[RecordView], model: ModalModel, *, seed: int = 0):
        self.views = [v for v in views if np.any(v.displacement_axes)]
        self.model = model
        rng = np.random.default_rng(seed)
        self.baseline, self.band, self.noise_lines, self.axes = [], [], [], []
        self._basis_cache = {}
        for v in self.views:
            axes = np.flatnonzero(v.displacement_axes)
            self.axes.append(axes)
            pred = modal_response(model, v.force, v.sample_rate_hz)
            self.baseline.append(pred)
            fs = v.sample_rate_hz
            sl_fit, sl_val = v.half("fit"), v.half("val")
            n_val = sl_val.stop - sl_val.start
            freq_val = np.fft.rfftfreq(n_val, 1.0 / fs)
            # noise on the validation lines
            noise = np.zeros((axes.size, freq_val.size))
            if v.resolution_m:
                noise += _grid_noise_lines(pred[axes, sl_val], v.resolution_m, rng)
            if v.force_noise_variance_N2 > 0:
                g = model.receptance(freq_val)[axes]  # (na, 3, nf)
                noise += n_val * v.force_noise_variance_N2 * np.sum(np.abs(g) ** 2, axis=1)
            if not v.resolution_m:
                # unknown sensor: white noise at the level of the residual's upper band
                r = np.fft.rfft(v.displacement[axes, sl_val] - pred[axes, sl_val], axis=-1)
                upper = freq_val > 0.3 * fs
                noise += np.median(np.abs(r[:, upper]) ** 2, axis=1)[:, None] / math.log(2.0)
            self.noise_lines.append(noise)
            # band from the fit half: measured density above BAND_SNR noise densities
            n_fit = sl_fit.stop - sl_fit.start
            nper = int(min(n_fit, 2 ** round(math.log2(max(n_fit / 4, 64)))))
            f_w, p_meas = welch_psd(v.displacement[axes, sl_fit], fs, nper)
            noise_fit = np.zeros_like(p_meas)
            if v.resolution_m:
                q = v.resolution_m
                for _ in range(N_OFFSETS):
                    off = rng.uniform(0.0, q)
                    e = np.round((pred[axes, sl_fit] + off) / q) * q - (pred[axes, sl_fit] + off)
                    noise_fit += welch_psd(e, fs, nper)[1] / N_OFFSETS
            if v.force_noise_variance_N2 > 0:
                g = model.receptance(f_w)[axes]
                noise_fit += 2.0 * v.force_noise_variance_N2 / fs * np.sum(np.abs(g) ** 2, axis=1)
            if not v.resolution_m:
                noise_fit += np.median(noise[:, freq_val > 0.3 * fs], axis=1)[:, None] * 2.0 / (fs * n_val)
            good = p_meas > BAND_SNR * np.maximum(noise_fit, 1e-300)
            band = np.zeros((axes.size, freq_val.size), dtype=bool)
            for j in range(axes.size):
                band[j] = np.interp(freq_val, f_w, good[j].astype(float)) > 0.5
            band[:, 0] = v.has_static
            self.band.append(band)

    def response(self, view_index: int, model: ModalModel | None = None, **kwargs) -> np.ndarray:
        """Predicted displacement of a view (whole window) for ``model`` (default the baseline)."""
        v = self.views[view_index]
        return modal_response(self.model if model is None else model, v.force, v.sample_rate_hz, **kwargs)

    def fit_residual(self, view_index: int, prediction, *, basis_model: ModalModel | None = None) -> np.ndarray:
        """Residual on the fit half with the structure's unknown initial state projected out.

        Returns the flattened residual (measured axes) orthogonal to the free responses of
        ``basis_model`` (default the baseline model).
        """
        v = self.views[view_index]
        axes = self.axes[view_index]
        sl = v.half("fit")
        r = (v.displacement[axes, sl] - prediction[axes, sl]).ravel()
        q = self._basis(view_index, basis_model)
        return r - q @ (q.T @ r)

    def _basis(self, view_index, basis_model):
        m = self.model if basis_model is None else basis_model
        key = (view_index, id(m))
        if key not in self._basis_cache:
            v = self.views[view_index]
            axes = self.axes[view_index]
            n = v.split
            b = free_response_basis(m, n, v.sample_rate_hz)[axes]  # (na, n, 2m)
            b = b.reshape(axes.size * n, -1)
            q, _ = np.linalg.qr(b) if b.shape[1] else (np.zeros((b.shape[0], 0)), None)
            if len(self._basis_cache) > 64:
                self._basis_cache.clear()
            self._basis_cache[key] = (q, m)  # keep m alive so its id is not reused
        return self._basis_cache[key][0]

    def evaluate(self, predictions, *, views=None) -> PartEvaluation:
        """Error elements on the validation half (one (3, n) whole-window prediction per view)."""
        idx = range(len(self.views)) if views is None else views
        items, den = [], 0.0
        for i in idx:
            v = self.views[i]
            axes = self.axes[i]
            sl = v.half("val")
            n = sl.stop - sl.start
            xm = np.fft.rfft(v.displacement[axes, sl], axis=-1)
            xp = np.fft.rfft(predictions[i][axes, sl], axis=-1)
            w = np.full(xm.shape, 2.0 / n)
            w[:, 0] = 1.0 / n
            if n % 2 == 0:
                w[:, -1] = 1.0 / n
            band = self.band[i]
            items.append((xm[band], xp[band], self.noise_lines[i][band], w[band]))
            den += float(np.sum(w[band] * np.abs(xm[band]) ** 2) - np.sum(w[band] * self.noise_lines[i][band]))
        return _concat(self.name, items, den)


# ------------------------------------------------------------------------- (c) stability part
class StabilityPart:
    """Part (c): closed-loop force spectrum, chatter and the predicted limit (module notes)."""

    name = "stability"

    def __init__(self, views: Sequence[RecordView], model: ModalModel):
        self.views = list(views)
        self.model = model
        fn = model.natural_frequency_hz
        self.data = []
        for v in self.views:
            fs = v.sample_rate_hz
            n_harm = max(int(math.floor(0.5 * fs / v.spindle_hz)), 1)
            entry = {}
            for half in ("fit", "val"):
                x = v.force[:, v.half(half)]
                _, fitted = harmonic_coefficients(x, fs, v.spindle_hz, n_harm, t0=v.t0(half))
                n = x.shape[1]
                nper = int(max(64, round(n * STABILITY_SEGMENT_FRACTION)))
                f, p = welch_psd(x - fitted, fs, nper)
                df = f[1] - f[0]
                lo = max(0.5 * float(np.min(fn)), 3 * df) if fn.size else 3 * df
                hi = min(2.5 * float(np.max(fn)), HARMONIC_FRACTION * fs) if fn.size else HARMONIC_FRACTION * fs
                harm = fold_frequency(np.arange(1, n_harm + 1) * v.spindle_hz, fs)
                near = np.any(np.abs(f[:, None] - harm[None, :]) <= 2.5 * df, axis=1)
                lines = (f >= lo) & (f <= hi) & ~near
                n_seg = 1 + (n - nper) // (nper // 2)
                nu = 2.0 * equivalent_averages(n_seg, nper, nper // 2)
                bg = np.median(p[:, lines], axis=1) if np.any(lines) else np.ones(3)
                step = df / 8.0
                fine = np.arange(max(lo - 5 * df, step), hi + 5 * df, step)
                entry[half] = dict(freq=f[lines], y=np.log(np.maximum(p[:, lines], 1e-300)), nu=nu, nper=nper,
                                   fine=fine, background=bg, lo=lo, hi=hi, kernel=welch_kernel(nper, fs, step))
            self.data.append(entry)

    def predicted_log(self, view_index: int, half: str, *, model: ModalModel | None = None,
                      process_damping_N_m: float = 0.0) -> np.ndarray:
        """Log of the expected Welch density of the closed-loop force, shape (3, n_lines)."""
        v = self.views[view_index]
        d = self.data[view_index][half]
        m = self.model if model is None else model
        p = closed_loop_force_psd(m, v.tool, v.cut, v.coefficients, d["fine"], background_psd=d["background"],
                                  process_damping_N_m=process_damping_N_m)
        e = expected_welch(d["fine"], p, d["freq"], d["nper"], v.sample_rate_hz, kernel=d["kernel"])
        return np.log(np.maximum(e, 1e-300))

    def _nuisance_fit(self, d, y, lp):
        u = (d["freq"] - 0.5 * (d["lo"] + d["hi"])) / max(0.5 * (d["hi"] - d["lo"]), 1e-12)
        a = np.column_stack([np.ones_like(u), u])
        r = y - lp
        coef, *_ = np.linalg.lstsq(a, r.T, rcond=None)
        return lp + (a @ coef).T

    def evaluate(self, half: str, predicted_logs, *, views=None) -> PartEvaluation:
        """Error elements for ``predicted_logs`` (one (3, n_lines) array per view)."""
        idx = range(len(self.views)) if views is None else views
        items, n_total = [], 0
        for i in idx:
            d = self.data[i][half]
            p = self._nuisance_fit(d, d["y"], predicted_logs[i])
            n_lines = d["y"].shape[1]
            # variance of ln of a Welch estimate with nu degrees of freedom, less the two nuisance
            # parameters per axis
            var = float(special.polygamma(1, d["nu"] / 2.0)) * max(1.0 - 2.0 / max(n_lines, 1), 0.0)
            items.append((d["y"], p, np.full(d["y"].shape, var), np.ones(d["y"].shape)))
            n_total += d["y"].size
        # adjacent lines of a Hann-window periodogram are correlated (|rho|^2 = 1/4 between
        # neighbours): a smooth sum over lines has 1 + 2/4 = 1.5 times the independent variance
        return _concat(self.name, items, max(n_total, 1), real=True, correlation=1.5)

    def baseline_logs(self, half: str) -> list:
        return [self.predicted_log(i, half) for i in range(len(self.views))]
