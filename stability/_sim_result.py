"""Result type of the milling simulator: the signals of one simulated cut, the numbers derived
from them (chatter growth, steady-state means) and their conversion to a ``robomill-record/1``.

Private module: :class:`SimulationResult` is imported from :mod:`stability.simulate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from oma._arrays import readonly
from oma.cutting import Cut, CuttingCoefficients, Material, Tool
from oma.errors import InputError
from oma.record import Channel, Record

from ._sim_settings import BackgroundForce, Effects, SensorModel

__all__ = ["SimulationResult"]


@dataclass(frozen=True)
class SimulationResult:
    """Signals of one simulated cut.

    Attributes
    ----------
    time_s : ndarray, shape (n,)
        Internal time grid, s (``k * T / steps_per_tooth``).
    force_N : ndarray, shape (3, n)
        True force on the structure (cutting plus background), machine frame, N.
    displacement_m : ndarray, shape (3, n)
        True tool-tip displacement, machine frame, m.
    record_time_s : ndarray, shape (n_rec,)
        Record sample times ``i / sample_rate_hz``, s.
    measured_force_N, measured_displacement_m : ndarray, shape (3, n_rec)
        What the sensors record (effects on measurement, filter, noise, resolution applied).
    sample_rate_hz : float
        Record rate, Hz.
    steps_per_tooth : int
        Internal steps per tooth period.
    axial_slices : int
    tool, cut : Tool, Cut
        The cut has the simulated spindle speed and axial depth filled in.
    coefficients : CuttingCoefficients
    effects : Effects
    sensors : SensorModel
    background : BackgroundForce or None
    regeneration : bool
    """

    time_s: np.ndarray
    force_N: np.ndarray
    displacement_m: np.ndarray
    record_time_s: np.ndarray
    measured_force_N: np.ndarray
    measured_displacement_m: np.ndarray
    sample_rate_hz: float
    steps_per_tooth: int
    axial_slices: int
    tool: Tool
    cut: Cut
    coefficients: CuttingCoefficients
    effects: Effects = Effects()
    sensors: SensorModel = SensorModel()
    background: BackgroundForce | None = None
    regeneration: bool = True

    def __post_init__(self):
        for name in ("time_s", "force_N", "displacement_m", "record_time_s", "measured_force_N",
                     "measured_displacement_m"):
            object.__setattr__(self, name, readonly(getattr(self, name)))

    # ------------------------------------------------------------------------- derived numbers
    @property
    def tooth_period_s(self) -> float:
        """``T = 60 / (N n)``, s."""
        return 60.0 / (self.tool.teeth * self.cut.spindle_rpm)

    @property
    def internal_rate_hz(self) -> float:
        """Internal integration rate, Hz."""
        return self.steps_per_tooth / self.tooth_period_s

    def _tooth_period_indices(self, start_fraction: float) -> np.ndarray:
        if not 0.0 <= start_fraction < 1.0:
            raise InputError(None, "start_fraction", "a number in [0, 1)", repr(start_fraction))
        n = self.time_s.size
        first = int(math.ceil(start_fraction * (n - 1) / self.steps_per_tooth)) * self.steps_per_tooth
        idx = np.arange(first, n, self.steps_per_tooth)
        if idx.size < 5:
            raise InputError(None, "duration_s", "at least 4 tooth periods after start_fraction",
                             f"{max(idx.size - 1, 0)}")
        return idx

    def chatter_growth(self, *, start_fraction: float = 0.5) -> float:
        """Exponential growth rate of the non-periodic vibration, 1/s (> 0: chatter grows).

        The displacement is sampled once per tooth period (exact on the internal grid); stable
        forced vibration is periodic with the tooth period, so the difference ``d_k = q(t_k + T) -
        q(t_k)`` holds only the free and chatter motion. The rate is ``ln(rms_2 / rms_1) / dt``
        between the RMS of ``|d_k|`` over the two halves of the window that starts at
        ``start_fraction`` of the record. With background noise the free motion never dies out
        and the rate of a stable cut is near zero, not negative.

        Parameters
        ----------
        start_fraction : float
            Where the analysed window starts, fraction of the duration (skips the entry transient).

        Returns
        -------
        float
            Growth rate, 1/s.
        """
        idx = self._tooth_period_indices(start_fraction)
        d = np.diff(self.displacement_m[:, idx], axis=1)
        amp = np.linalg.norm(d, axis=0)
        t = self.time_s[idx[1:]]
        half = amp.size // 2
        rms1 = float(np.sqrt(np.mean(amp[:half] ** 2)))
        rms2 = float(np.sqrt(np.mean(amp[half:] ** 2)))
        if rms1 == 0.0 or rms2 == 0.0:
            return 0.0 if rms1 == rms2 else (math.inf if rms1 == 0.0 else -math.inf)
        return math.log(rms2 / rms1) / float(np.mean(t[half:]) - np.mean(t[:half]))

    def steady_state_mean(self, *, start_fraction: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Mean force (N) and mean displacement (m), each shape (3,), over whole tooth periods.

        The window runs from the first tooth-period boundary after ``start_fraction`` of the record
        to the last boundary, so the means of periodic signals are exact.
        """
        idx = self._tooth_period_indices(start_fraction)
        sl = slice(idx[0], idx[-1])  # whole periods: first sample in, last one out
        return self.force_N[:, sl].mean(axis=1), self.displacement_m[:, sl].mean(axis=1)

    def to_dict(self) -> dict:
        """Scalar summary (no signals), JSON-friendly."""
        return {
            "spindle_rpm": float(self.cut.spindle_rpm),
            "axial_depth_m": float(self.cut.axial_depth_m),
            "duration_s": float(self.time_s[-1]),
            "sample_rate_hz": float(self.sample_rate_hz),
            "internal_rate_hz": float(self.internal_rate_hz),
            "steps_per_tooth": int(self.steps_per_tooth),
            "axial_slices": int(self.axial_slices),
            "regeneration": bool(self.regeneration),
            "n_samples": int(self.record_time_s.size),
        }

    # --------------------------------------------------------------------------------- record
    def to_record(self, tool: Tool | None = None, cut: Cut | None = None, *, material: Material | None = None,
                  name: str | None = None, joints_deg=None, robot_model: str | None = None) -> Record:
        """The measured signals as a ``robomill-record/1`` :class:`oma.record.Record`.

        Channels ``Fx, Fy, Fz`` (N) and ``x, y, z`` (file unit um, data in m); the record's time
        column is :attr:`record_time_s`.

        Parameters
        ----------
        tool, cut : optional
            Default: the simulated ones. A given cut gets the simulated spindle speed and axial
            depth.
        material : Material, optional
            Default: unnamed, with the simulated cutting coefficients.
        name, joints_deg, robot_model : optional
            Record metadata.
        """
        tool = self.tool if tool is None else tool
        cut = self.cut if cut is None else replace(cut, spindle_rpm=self.cut.spindle_rpm,
                                                   axial_depth_m=self.cut.axial_depth_m)
        if material is None:
            material = Material(cutting_coefficients=self.coefficients)
        channels = (
            Channel("Fx", "force", "X", "N"),
            Channel("Fy", "force", "Y", "N"),
            Channel("Fz", "force", "Z", "N"),
            Channel("x", "displacement", "X", "um"),
            Channel("y", "displacement", "Y", "um"),
            Channel("z", "displacement", "Z", "um"),
        )
        data = np.vstack([self.measured_force_N, self.measured_displacement_m])
        return Record(
            sample_rate_hz=float(self.sample_rate_hz),
            channels=channels,
            data=data,
            tool=tool,
            cut=cut,
            material=material,
            sensors=self.sensors.to_sensors(),
            name=name,
            robot_model=robot_model,
            joints_deg=joints_deg,
            time_s=self.record_time_s,
        )

    def plot(self, ax=None):
        """Measured force and displacement against time (matplotlib imported here only).

        Returns
        -------
        fig, axes
        """
        import matplotlib.pyplot as plt

        if ax is None:
            fig, axes = plt.subplots(2, 1, sharex=True)
        else:
            axes = np.ravel(ax)
            fig = axes[0].figure
        for i, axis in enumerate("XYZ"):
            axes[0].plot(self.record_time_s, self.measured_force_N[i], label=f"F{axis.lower()}")
            axes[1].plot(self.record_time_s, self.measured_displacement_m[i] * 1e6, label=axis.lower())
        axes[0].set_ylabel("force (N)")
        axes[1].set_ylabel("displacement (um)")
        axes[1].set_xlabel("time (s)")
        for a in axes[:2]:
            a.legend(loc="upper right")
        return fig, axes
