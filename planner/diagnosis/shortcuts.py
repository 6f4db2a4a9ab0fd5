"""What the paper's own identification gets wrong: two shortcuts of Nguyen & Melkote (2020), quantified.

1. **Harmonics left in.** The paper removes the milling harmonics before it estimates the
   background force variance (and robomill's OMA also leaves them out of the FRF). What happens
   without that step is measured by identifying the same records with the spindle speed withheld
   (:func:`oma.identify.identify` then removes no harmonic). An H1 estimate is not biased by the
   harmonics (at a harmonic line the response is ``G F`` too), so the modal parameters barely
   move; the background variance, however, then counts the harmonics' power (Parseval: ``sum_h
   |c_h|^2 / 2`` per axis), and the detectability verdict built on it is wrong.
2. **Force-sensor dynamics ignored.** The paper inverse-filters the flange sensor's resonance
   (its reference [21]). A variant of the example cut is simulated with a sensor resonance
   (default 200 Hz, 5 %: the measured force is ``H_s F`` with ``H_s = w^2 / (s^2 + 2 zeta w s +
   w^2)``) and identified twice: from the raw sensor force, and from the force inverse-filtered
   with the known resonance (``F = FFT^-1[FFT(F_meas) / H_s]``). Near the robot modes ``H_s`` is
   ``1 + (f / f_s)^2`` (0.3 % at 10 Hz for 200 Hz), so the modal parameters move little; the
   resonance amplifies the background force around ``f_s`` by up to ``1 / (2 zeta)^2``, and the
   background variance estimate with it.

:func:`paper_shortcuts` returns the numbers for the demo report (:meth:`ShortcutReport.rows`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from oma.modal import ModalModel
from oma.record import Record

__all__ = ["ShortcutEffect", "ShortcutReport", "paper_shortcuts", "inverse_filter_sensor", "modal_errors",
           "EXAMPLE_DIRECTORY"]

#: The bundled example cell.
EXAMPLE_DIRECTORY = Path(__file__).resolve().parents[2] / "examples" / "kr500_acetal"
AXES = ("X", "Y", "Z")


def inverse_filter_sensor(force_N, sample_rate_hz: float, frequency_hz: float, damping_ratio: float) -> np.ndarray:
    """Undo a force sensor's resonance: ``FFT^-1[FFT(F) / H_s]`` per row (the record taken as periodic)."""
    from .forcemodel import sensor_gain

    f = np.asarray(force_N, dtype=float)
    n = f.shape[-1]
    spec = np.fft.rfft(f, axis=-1)
    h = sensor_gain(np.fft.rfftfreq(n, 1.0 / sample_rate_hz), frequency_hz, damping_ratio)
    return np.fft.irfft(spec / h, n=n, axis=-1)


def modal_errors(identified: ModalModel, truth: ModalModel) -> list[dict]:
    """Relative errors of frequency, damping and stiffness, each true mode against the identified
    mode closest in direction (then frequency)."""
    out = []
    for f, z, k, u in zip(truth.natural_frequency_hz, truth.damping_ratio, truth.stiffness_N_m, truth.directions):
        if identified.n_modes == 0:
            out.append({"mode_hz": float(f), "frequency": math.nan, "damping": math.nan, "stiffness": math.nan})
            continue
        score = np.abs(identified.directions @ u) - 0.01 * np.abs(np.log(identified.natural_frequency_hz / f))
        j = int(np.argmax(score))
        out.append({"mode_hz": float(f),
                    "frequency": float(identified.natural_frequency_hz[j] / f - 1.0),
                    "damping": float(identified.damping_ratio[j] / z - 1.0),
                    "stiffness": float(identified.stiffness_N_m[j] / k - 1.0)})
    return out


def _frf_error(identified: ModalModel, truth: ModalModel, band_hz=(2.0, 60.0)) -> float:
    f = np.linspace(band_hz[0], band_hz[1], 400)
    gi, gt = identified.receptance(f), truth.receptance(f)
    d = np.array([gi[a, a] - gt[a, a] for a in range(3)])
    t = np.array([gt[a, a] for a in range(3)])
    return float(np.sqrt(np.sum(np.abs(d) ** 2) / np.sum(np.abs(t) ** 2)))


@dataclass(frozen=True)
class ShortcutEffect:
    """One shortcut: the identification with and without it, against the truth.

    Attributes
    ----------
    name, description : str
    modal_errors_with, modal_errors_without : list of dict
        Relative errors per true mode (:func:`modal_errors`).
    frf_error_with, frf_error_without : float
        Relative error of the identified direct receptances over 2-60 Hz.
    noise_variance_with_N2, noise_variance_without_N2 : ndarray, shape (3,)
        Background force variance estimates, X, Y, Z.
    truth_noise_variance_N2 : ndarray, shape (3,)
        What the records were simulated with.
    extra : dict
    """

    name: str
    description: str
    modal_errors_with: list
    modal_errors_without: list
    frf_error_with: float
    frf_error_without: float
    noise_variance_with_N2: np.ndarray
    noise_variance_without_N2: np.ndarray
    truth_noise_variance_N2: np.ndarray
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        def lst(a):
            return [float(v) for v in np.asarray(a, dtype=float)]

        return {"name": self.name, "description": self.description,
                "modal_errors_with": self.modal_errors_with, "modal_errors_without": self.modal_errors_without,
                "frf_error_with": float(self.frf_error_with), "frf_error_without": float(self.frf_error_without),
                "noise_variance_with_N2": lst(self.noise_variance_with_N2),
                "noise_variance_without_N2": lst(self.noise_variance_without_N2),
                "truth_noise_variance_N2": lst(self.truth_noise_variance_N2), "extra": dict(self.extra)}


@dataclass(frozen=True)
class ShortcutReport:
    """Both shortcuts of :func:`paper_shortcuts`."""

    harmonics: ShortcutEffect
    sensor: ShortcutEffect
    method: str

    def to_dict(self) -> dict:
        return {"method": self.method, "harmonics_left_in": self.harmonics.to_dict(),
                "force_sensor_ignored": self.sensor.to_dict()}

    def rows(self) -> list[dict]:
        """One row per shortcut and quantity, for a report table."""
        out = []
        for eff in (self.harmonics, self.sensor):
            quantities = ("frequency", "damping", "stiffness")
            worst_with = max(max(abs(e[q]) for q in quantities) for e in eff.modal_errors_with)
            worst_without = max(max(abs(e[q]) for q in quantities) for e in eff.modal_errors_without)
            out.append({"shortcut": eff.name, "quantity": "largest modal-parameter error",
                        "with_shortcut": worst_with, "without_shortcut": worst_without})
            out.append({"shortcut": eff.name, "quantity": "FRF error 2-60 Hz",
                        "with_shortcut": eff.frf_error_with, "without_shortcut": eff.frf_error_without})
            for a, axis in enumerate(AXES):
                out.append({"shortcut": eff.name, "quantity": f"background variance {axis} [N^2]",
                            "with_shortcut": float(eff.noise_variance_with_N2[a]),
                            "without_shortcut": float(eff.noise_variance_without_N2[a]),
                            "truth": float(eff.truth_noise_variance_N2[a])})
        return out


def _example():
    from oma.modal_io import read_modal_model
    from oma.record_io import read_record

    rec = read_record(EXAMPLE_DIRECTORY / "records" / "cut_short")
    truth = read_modal_model(EXAMPLE_DIRECTORY / "truth" / "robot_at_cut.yaml")
    return [rec], truth


def paper_shortcuts(records: Sequence[Record] | None = None, truth: ModalModel | None = None, *,
                    method: str = "default", background_variance_N2=(232.0, 278.0, 251.0),
                    background_bandwidth_hz: float = 400.0, sensor_frequency_hz: float = 200.0,
                    sensor_damping_ratio: float = 0.05, sensor_duration_s: float = 4.0, seed: int = 0
                    ) -> ShortcutReport:
    """Quantify the two shortcuts (module notes) on the example cell.

    Parameters
    ----------
    records, truth : optional
        Records of the example cut and the model they were simulated with (default: the bundled
        ``examples/kr500_acetal`` ``cut_short`` record and ``truth/robot_at_cut.yaml``).
    method : {'default', 'h1'}
        Identification method (:func:`oma.identify.identify`).
    background_variance_N2, background_bandwidth_hz
        The background force of the example (and of the simulated sensor variant).
    sensor_frequency_hz, sensor_damping_ratio : float
        The sensor resonance of the variant.
    sensor_duration_s : float
        Length of the simulated variant, s (after a 2 s lead-in).
    seed : int

    Returns
    -------
    ShortcutReport
    """
    from oma.identify import identify
    from stability.simulate import BackgroundForce, Effects, ForceSensorDynamics, SensorModel, simulate

    if records is None or truth is None:
        ex_records, ex_truth = _example()
        records = ex_records if records is None else records
        truth = ex_truth if truth is None else truth
    records = list(records)
    bg = np.asarray(background_variance_N2, dtype=float)

    # 1. harmonics left in: withhold the spindle speed, so that no harmonic is removed
    full = identify(records, method=method)
    bare = identify([replace(r, cut=replace(r.cut, spindle_rpm=None)) for r in records], method=method)
    harmonic_power = []
    from .spectral import harmonic_coefficients

    for r in records:
        from oma.signals import prepare_record

        sig = prepare_record(r)
        f0 = float(r.cut.spindle_rpm) / 60.0
        n_h = int(0.5 * r.sample_rate_hz / f0)
        c, _ = harmonic_coefficients(sig.force_N, r.sample_rate_hz, f0, n_h)
        harmonic_power.append(np.sum(np.abs(c[:, 1:]) ** 2 / 2.0, axis=1))
    harmonics = ShortcutEffect(
        name="harmonics left in",
        description="background variance and FRF identified without removing the milling harmonics",
        modal_errors_with=modal_errors(bare.model, truth), modal_errors_without=modal_errors(full.model, truth),
        frf_error_with=_frf_error(bare.model, truth), frf_error_without=_frf_error(full.model, truth),
        noise_variance_with_N2=np.asarray(bare.noise_variance_N2), noise_variance_without_N2=np.asarray(
            full.noise_variance_N2), truth_noise_variance_N2=bg,
        extra={"harmonic_power_N2": [float(v) for v in np.mean(harmonic_power, axis=0)],
               "excitation_sufficient_with": [bool(v) for v in bare.excitation_sufficient],
               "excitation_sufficient_without": [bool(v) for v in full.excitation_sufficient]})

    # 2. force-sensor dynamics ignored: a simulated variant with a sensor resonance
    r0 = records[0]
    lead = 2.0
    sensors = r0.sensors
    noise = (sensors.force_noise_variance_N2 or 0.0) if sensors else 0.0
    resolution = (sensors.displacement_resolution_m or 0.0) if sensors else 0.0
    sim = simulate(truth, r0.tool, r0.cut, r0.material, duration_s=lead + sensor_duration_s,
                   sample_rate_hz=r0.sample_rate_hz,
                   effects=Effects(force_sensor=ForceSensorDynamics(sensor_frequency_hz, sensor_damping_ratio)),
                   background=BackgroundForce(tuple(bg), background_bandwidth_hz),
                   sensors=SensorModel(force_noise_variance_N2=noise, displacement_resolution_m=resolution),
                   seed=seed)
    rec = sim.to_record(r0.tool, r0.cut, material=r0.material, name="sensor-variant")
    n0 = int(round(lead * r0.sample_rate_hz))
    rec = replace(rec, data=rec.data[:, n0:], time_s=None, sensors=r0.sensors)
    force_rows = [i for i, c in enumerate(rec.channels) if c.quantity == "force"]
    data = np.array(rec.data)
    data[force_rows] = inverse_filter_sensor(data[force_rows], rec.sample_rate_hz, sensor_frequency_hz,
                                             sensor_damping_ratio)
    filtered = replace(rec, data=data)
    raw_id = identify([rec], method=method)
    inv_id = identify([filtered], method=method)
    sensor = ShortcutEffect(
        name="force-sensor dynamics ignored",
        description=(f"a {sensor_frequency_hz:g} Hz, {100 * sensor_damping_ratio:g} % sensor resonance: raw sensor "
                     "force against the inverse-filtered force"),
        modal_errors_with=modal_errors(raw_id.model, truth), modal_errors_without=modal_errors(inv_id.model, truth),
        frf_error_with=_frf_error(raw_id.model, truth), frf_error_without=_frf_error(inv_id.model, truth),
        noise_variance_with_N2=np.asarray(raw_id.noise_variance_N2),
        noise_variance_without_N2=np.asarray(inv_id.noise_variance_N2), truth_noise_variance_N2=bg,
        extra={"sensor_frequency_hz": float(sensor_frequency_hz), "sensor_damping_ratio": float(sensor_damping_ratio),
               "duration_s": float(sensor_duration_s)})
    return ShortcutReport(harmonics=harmonics, sensor=sensor, method=method)
