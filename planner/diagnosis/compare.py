"""Compare measured cuts with robomill's own prediction, in three parts that separate the causes.

Every record (its cut window) is split in two halves: a cause is fitted on the first half (the
*fit* part) and scored on the second (the *validation* part), so a gain is a prediction gain. The
errors below are those of the validation part unless said otherwise; with several records the
sums run over all of them.

(a) Force model -- ``e_force``
    Measured: least-squares coefficients ``c^m_{a,h}`` of the force along axis ``a`` at the
    multiples ``h = 0 .. H`` of the spindle frequency (refined from the force spectrum), ``H =
    floor(0.3 fs / f_s)`` (below 0.3 fs the record's anti-alias filter is flat to 1 %). Predicted:
    the same coefficients of the simulated cut (:func:`~planner.diagnosis.forcemodel.
    simulated_harmonics`; no background force), turned by the one angle ``theta`` that best aligns
    them (the spindle angle at the start of a record is unknown): ``c^p_{a,h} exp(-i h theta)``.
    ``v_{a,h} = E|noise|^2`` of each measured coefficient follows from the force density around
    the line (``2 S(f_h) / T``; :func:`~planner.diagnosis.spectral.harmonic_noise_variance`). Then::

        e_force = max(0, sum |c^m - c^p|^2 - sum v) / (sum |c^m|^2 - sum v)

    the squared error of the mean force and harmonic amplitudes and phases relative to their
    squared size, in excess of what the background force alone explains.

(b) Structure model -- ``e_structure``
    The displacement predicted from the MEASURED force through the model (:func:`~planner.
    diagnosis.response.modal_response`, started in static equilibrium at the record start and run
    through the whole record) against the measured displacement, both as DFT lines ``X_{a,k}`` of
    the validation part, over a band ``B_a`` per axis: the line 0 (static deflection) and every
    line where the fit part's measured displacement density exceeds 4 times the sensor noise
    density. The noise is that of the displacement sensor's quantisation, simulated on the
    predicted displacement with random grid offsets (a tracker's rounding of a slow signal is not
    white: it follows the signal), plus the force sensor's noise through the model (or, for a
    sensor of unknown resolution, a white level from the residual above 0.3 fs). With ``w_k = 1``
    for line 0 and 2 otherwise (``1/N`` Parseval weights), ``R = X^m - X^p``::

        e_structure = max(0, sum w |R|^2 / N - noise) / (sum w |X^m|^2 / N - noise)

    the squared error of the band-limited displacement (static deflection, spectra and phases
    together) relative to its squared size, in excess of the expected sensor noise.

(c) Stability -- ``e_stability``
    The cut is a closed loop: regeneration and process damping shape the spectrum of the measured
    force at the robot's modes (:mod:`~planner.diagnosis.closedloop`), and chatter adds a line. The
    force with its harmonics removed gives Welch densities ``P^m_{a,k}`` (Hann, segments of a
    quarter of the part, 50 % overlap) at lines ``k`` of the band ``[0.5 min f_n, min(2.5 max f_n,
    0.3 fs)]`` more than 2.5 lines away from a harmonic; the prediction is the closed-loop density
    for an independent background, as a Welch estimate of that resolution would see it,
    ``P^p_{a,k}``. With ``l = ln P^m - ln P^p - alpha_a - beta_a u_k`` (a level and a slope per axis
    fitted by least squares: the background's own spectrum is unknown; ``u`` the line's position in
    the band from -1 to 1) over all ``n`` lines (``n_a`` per axis)::

        e_stability = max(0, sum l^2 - sum_a (n_a - 2) psi1(nu/2)) / n

    the mean squared logarithmic error of the force spectrum in excess of the Welch estimate's own
    (``psi1`` the trigamma function, ``nu`` twice the equivalent number of averages). Alongside it,
    :func:`~planner.diagnosis.chatter.detect_chatter` on the measured force says whether the cut
    chattered, and the zero-order approximation (:func:`stability.lobes.predict_point`) whether the
    model predicts it should have.

Significance. For any of the three, a change ``delta`` of the prediction (an extension of the
model) lowers the validation error sum ``E = sum w |y - p|^2`` by ``dE``; if the extension is
spurious, the noise part of ``dE`` has the standard deviation ``sqrt(sum c w^2 |delta|^2 s)`` with
``s`` the noise variance of each element (``c = 2`` for complex elements, 4 for real ones), and
``E[dE] = -sum w |delta|^2 < 0``. ``z = dE / std`` is the significance of the extension. The
disagreement of a part itself is ``(E - noise) / sqrt(sum c' w^2 s^2)`` (``c' = 1`` complex, 2 real):
the excess over the noise in standard deviations of the noise power.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy import special

from oma.cutting import CuttingCoefficients, Cut, Tool
from oma.errors import InputError
from oma.modal import ModalModel
from oma.record import Record
from oma.signals import prepare_record
from oma.spectra import equivalent_averages

from .chatter import ChatterResult, detect_chatter, refine_spindle_frequency_aliased
from .closedloop import closed_loop_force_psd
from .forcemodel import analytic_harmonics, simulated_harmonics
from .response import free_response_basis, modal_response
from .spectral import (expected_welch, fold_frequency, harmonic_coefficients, harmonic_noise_variance,
                       welch_kernel, welch_psd)

__all__ = [
    "RecordView",
    "PartEvaluation",
    "ForcePart",
    "StructurePart",
    "StabilityPart",
    "RecordComparison",
    "Comparison",
    "prepare_views",
    "compare_records",
    "significance",
    "PARTS",
]

PARTS = ("force", "structure", "stability")
#: Highest harmonic compared in part (a), as a fraction of the sample rate.
HARMONIC_FRACTION = 0.3
#: A displacement line is in the band of part (b) when its density exceeds this many noise densities.
BAND_SNR = 4.0
#: Number of grid offsets averaged in the quantisation-noise simulation.
N_OFFSETS = 6
#: Welch segment of part (c) as a fraction of the part (50 % overlap).
STABILITY_SEGMENT_FRACTION = 0.25


# ------------------------------------------------------------------------------------------ views
@dataclass(frozen=True)
class RecordView:
    """One record prepared for the comparison: signals of its cut window, SI.

    Attributes
    ----------
    index : int
    name : str
    tool, cut, coefficients
        ``cut`` has the spindle speed refined from the force (``60 spindle_hz``).
    force : ndarray, shape (3, n)
        N.
    displacement : ndarray, shape (3, n)
        m (NaN rows for axes not recorded).
    sample_rate_hz, spindle_hz : float
    split : int
        First sample of the validation half.
    resolution_m : float or None
        Displacement quantisation step (from the record's sensors or the samples' grid).
    force_noise_variance_N2 : float
    has_static : bool
        Whether the displacement carries the static deflection (False when integrated from velocity
        or acceleration).
    """

    index: int
    name: str
    tool: Tool
    cut: Cut
    coefficients: CuttingCoefficients
    force: np.ndarray = field(repr=False)
    displacement: np.ndarray = field(repr=False)
    sample_rate_hz: float
    spindle_hz: float
    split: int
    resolution_m: float | None
    force_noise_variance_N2: float
    has_static: bool = True

    @property
    def n_samples(self) -> int:
        return int(self.force.shape[1])

    def half(self, which: str) -> slice:
        """``'fit'`` (first half) or ``'val'`` (second half)."""
        return slice(0, self.split) if which == "fit" else slice(self.split, self.n_samples)

    def t0(self, which: str) -> float:
        """Start time of a half relative to the window start, s."""
        return (0 if which == "fit" else self.split) / self.sample_rate_hz

    @property
    def displacement_axes(self) -> np.ndarray:
        return ~np.all(np.isnan(self.displacement), axis=1)

    @property
    def n_harm(self) -> int:
        return max(int(math.floor(HARMONIC_FRACTION * self.sample_rate_hz / self.spindle_hz)), 1)


def prepare_views(records: Sequence[Record], *, coefficients: CuttingCoefficients | None = None,
                  min_duration_s: float = 2.0) -> list[RecordView]:
    """Prepare records for :func:`compare` and :func:`~planner.diagnosis.diagnose`.

    Raises
    ------
    InputError
        A record without spindle speed, axial depth or cutting coefficients, or shorter than
        ``min_duration_s`` in its cut window.
    """
    views = []
    for i, rec in enumerate(records):
        name = rec.name or f"record {i}"
        # a record read from a file is named by its path; one made in memory by its name
        src, pre = (rec.path, "") if rec.path is not None else (None, f"{name}: ")
        if rec.cut.spindle_rpm is None or not rec.cut.spindle_rpm > 0:
            raise InputError(src, f"{pre}cut.spindle_rpm", "a positive spindle speed", repr(rec.cut.spindle_rpm))
        if rec.cut.axial_depth_m is None or not rec.cut.axial_depth_m > 0:
            raise InputError(src, f"{pre}cut.axial_depth_m", "a positive axial depth", repr(rec.cut.axial_depth_m))
        coef = coefficients
        if coef is None:
            coef = rec.material.cutting_coefficients if rec.material is not None else None
        if coef is None:
            raise InputError(src, f"{pre}material.cutting_coefficients", "cutting coefficients", "none")
        sig = prepare_record(rec)
        fs = float(sig.sample_rate_hz)
        if sig.duration_s < min_duration_s:
            raise InputError(src, f"{pre}signals", f"a cut window of at least {min_duration_s:g} s",
                             f"{sig.duration_s:.3g} s")
        force = np.asarray(sig.force_N, dtype=float)
        if np.any(np.all(np.isnan(force), axis=1)):
            raise InputError(src, f"{pre}signals", "force along X, Y and Z", "a missing force axis")
        f_nom = float(rec.cut.spindle_rpm) / 60.0
        f_sp = refine_spindle_frequency_aliased(force, fs, f_nom, teeth=rec.tool.teeth, search=0.05)
        cut = replace(rec.cut, spindle_rpm=60.0 * f_sp)
        resolution = None
        if rec.sensors is not None and rec.sensors.displacement_resolution_m:
            resolution = float(rec.sensors.displacement_resolution_m)
        elif sig.quantisation_step_m is not None:
            resolution = float(sig.quantisation_step_m)
        noise = 0.0
        if rec.sensors is not None and rec.sensors.force_noise_variance_N2:
            noise = float(rec.sensors.force_noise_variance_N2)
        views.append(RecordView(
            index=i, name=name, tool=rec.tool, cut=cut, coefficients=coef, force=force,
            displacement=np.asarray(sig.displacement_m, dtype=float), sample_rate_hz=fs, spindle_hz=f_sp,
            split=force.shape[1] // 2, resolution_m=resolution, force_noise_variance_N2=noise,
            has_static=sig.motion_quantity == "displacement"))
    return views


# -------------------------------------------------------------------------------- evaluations
@dataclass(frozen=True)
class PartEvaluation:
    """The elements of one part's error on one half: measured ``y``, predicted ``p``, noise ``s``.

    ``E = sum w |y - p|^2``, ``noise = sum w s``; ``error = max(0, E - noise) / denominator``.
    Elements are flattened over records, axes and lines. ``correlation`` multiplies the variance of
    a sum over neighbouring elements (1.5 for adjacent lines of a Hann-window Welch estimate).
    """

    part: str
    y: np.ndarray
    p: np.ndarray
    s: np.ndarray
    w: np.ndarray
    denominator: float
    real: bool = False
    correlation: float = 1.0

    @property
    def residual_power(self) -> float:
        return float(np.sum(self.w * np.abs(self.y - self.p) ** 2))

    @property
    def noise_power(self) -> float:
        return float(np.sum(self.w * self.s))

    @property
    def error(self) -> float:
        if not self.denominator > 0:
            return float("nan")
        return max(self.residual_power - self.noise_power, 0.0) / self.denominator

    @property
    def n_elements(self) -> int:
        return int(self.y.size)

    @property
    def disagreement(self) -> float:
        """``z`` of the excess ``E - noise``: how far the prediction misses beyond the noise, in
        standard deviations of the noise power (``Var |n|^2 = s^2`` for a complex element, ``2 s^2``
        for a real one)."""
        c = (2.0 if self.real else 1.0) * self.correlation
        std = math.sqrt(float(np.sum(c * self.w**2 * self.s**2)))
        if std <= 0.0:
            return 0.0
        return (self.residual_power - self.noise_power) / std


def significance(before: PartEvaluation, after: PartEvaluation) -> float:
    """``z`` of the reduction of the residual power from ``before`` to ``after`` (module notes)."""
    d_e = before.residual_power - after.residual_power
    delta = after.p - before.p
    c = (4.0 if before.real else 2.0) * before.correlation
    var = float(np.sum(c * before.w**2 * np.abs(delta) ** 2 * before.s))
    if var <= 0.0:
        return 0.0 if d_e <= 0 else float("inf")
    return float(d_e / math.sqrt(var))


def _concat(part: str, items, denominator, real=False, correlation=1.0) -> PartEvaluation:
    ys, ps, ss, ws = zip(*items) if items else ((), (), (), ())
    cat = (lambda xs: np.concatenate([np.ravel(x) for x in xs])) if items else (lambda xs: np.zeros(0))
    return PartEvaluation(part, cat(ys), cat(ps), cat(ss), cat(ws), float(denominator), real, correlation)


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


# ---------------------------------------------------------------------------------- comparison
@dataclass(frozen=True)
class RecordComparison:
    """Per-record comparison: part errors on the validation half, chatter and predicted stability.

    Attributes
    ----------
    name : str
    spindle_hz : float
        Refined from the force spectrum, Hz.
    errors : dict
        ``force``, ``structure``, ``stability`` (module notes; NaN where a part has no data).
    chatter : ChatterResult
        Chatter detection on the measured force of the whole window.
    predicted_stable : bool
    depth_limit_m : float
        Zero-order-approximation limit at the record's speed, m.
    axial_depth_m : float
    predicted_chatter_hz : float
    """

    name: str
    spindle_hz: float
    errors: dict
    chatter: ChatterResult
    predicted_stable: bool
    depth_limit_m: float
    axial_depth_m: float
    predicted_chatter_hz: float

    def to_dict(self) -> dict:
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {"name": self.name, "spindle_hz": float(self.spindle_hz),
                "errors": {k: num(v) for k, v in self.errors.items()},
                "chatter": self.chatter.to_dict(), "predicted_stable": bool(self.predicted_stable),
                "depth_limit_m": num(self.depth_limit_m), "axial_depth_m": float(self.axial_depth_m),
                "predicted_chatter_hz": num(self.predicted_chatter_hz)}


@dataclass(frozen=True)
class Comparison:
    """What the current model gets right and wrong (validation halves; module notes).

    Attributes
    ----------
    errors : dict
        ``force``, ``structure``, ``stability`` over all records.
    records : tuple of RecordComparison
    """

    errors: dict
    records: tuple

    def to_dict(self) -> dict:
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {"errors": {k: num(v) for k, v in self.errors.items()},
                "records": [r.to_dict() for r in self.records]}


class Parts:
    """The three parts of one set of views, built once (the expensive baseline simulations)."""

    def __init__(self, views: Sequence[RecordView], model: ModalModel, *, structure: "StructurePart | None" = None):
        self.views = list(views)
        self.model = model
        self.force = ForcePart(views, model)
        # the structure part does not depend on the cutting coefficients (it is driven by the
        # measured force): a re-fit of the coefficients may share it
        self.structure = StructurePart(views, model) if structure is None else structure
        self.stability = StabilityPart(views, model)
        self.base_force = {h: self.force.evaluate(h, self.force.baseline) for h in ("fit", "val")}
        self.base_structure = self.structure.evaluate(self.structure.baseline) if self.structure.views else None
        self.base_logs = {h: self.stability.baseline_logs(h) for h in ("fit", "val")}
        self.base_stability = {h: self.stability.evaluate(h, self.base_logs[h]) for h in ("fit", "val")}

    def errors(self) -> dict:
        return {
            "force": self.base_force["val"].error,
            "structure": self.base_structure.error if self.base_structure is not None else float("nan"),
            "stability": self.base_stability["val"].error,
        }

    def record_errors(self, i: int) -> dict:
        out = {"force": self.force.evaluate("val", self.force.baseline, views=[i]).error}
        j = next((k for k, v in enumerate(self.structure.views) if v.index == self.views[i].index), None)
        out["structure"] = (self.structure.evaluate(self.structure.baseline, views=[j]).error
                            if j is not None else float("nan"))
        out["stability"] = self.stability.evaluate("val", self.base_logs["val"], views=[i]).error
        return out


def record_comparisons(parts: Parts) -> tuple:
    """Per-record comparison (errors, chatter, predicted limit) of prepared parts."""
    from stability.lobes import predict_point

    out = []
    for i, v in enumerate(parts.views):
        # records are filtered before sampling (formats.md; the simulator's anti-alias filter):
        # no harmonic above the Nyquist frequency folds into them
        chat = detect_chatter(v.force, v.sample_rate_hz, v.spindle_hz, v.tool.teeth, refine=False,
                              max_harmonic_hz=0.5 * v.sample_rate_hz)
        try:
            op = predict_point(parts.model, v.tool, v.cut, v.coefficients, spindle_rpm=60.0 * v.spindle_hz,
                               axial_depth_m=float(v.cut.axial_depth_m), method="zoa", n_freq=4000)
            stable, limit, fc = bool(op.stable), float(op.depth_limit_m), float(op.chatter_frequency_hz)
        except (ValueError, ArithmeticError):  # pragma: no cover - a model the ZOA cannot handle
            stable, limit, fc = True, float("nan"), float("nan")
        out.append(RecordComparison(name=v.name, spindle_hz=v.spindle_hz, errors=parts.record_errors(i), chatter=chat,
                                    predicted_stable=stable, depth_limit_m=limit,
                                    axial_depth_m=float(v.cut.axial_depth_m), predicted_chatter_hz=fc))
    return tuple(out)


def compare_records(records: Sequence[Record], model: ModalModel, *, coefficients: CuttingCoefficients | None = None
            ) -> Comparison:
    """Compare measured records with the simulation of the same cuts by ``model`` (module notes).

    Parameters
    ----------
    records : sequence of Record
        Cuts with force (X, Y, Z) and tool-tip displacement, spindle speed and axial depth.
    model : ModalModel
        The current model of the tool-tip dynamics.
    coefficients : CuttingCoefficients, optional
        Default: each record's material coefficients.

    Returns
    -------
    Comparison
    """
    views = prepare_views(records, coefficients=coefficients)
    parts = Parts(views, model)
    return Comparison(errors=parts.errors(), records=record_comparisons(parts))
