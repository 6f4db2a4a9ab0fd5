"""A measured (or simulated) cut: ``robomill-record/1`` in memory.

Signals are stored ``(n_channels, n_samples)``, time last, in SI units (N, m, m/s, m/s^2, rad),
whatever unit the file used; each channel remembers its name, quantity, axis and file unit so that a
record written back reproduces the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .cutting import Cut, Material, Sensors, Tool

__all__ = ["Channel", "Record", "QUANTITIES", "AXES"]

Quantity = Literal["force", "displacement", "velocity", "acceleration", "joint_angle"]
QUANTITIES: tuple[str, ...] = ("force", "displacement", "velocity", "acceleration", "joint_angle")
AXES: tuple[str, ...] = ("X", "Y", "Z")


@dataclass(frozen=True)
class Channel:
    """One signal column: its name in the file, what it measures, and the unit the file used."""

    name: str
    quantity: Quantity
    axis: str | None
    unit: str


@dataclass(frozen=True)
class Record:
    """One cut's signals and its metadata.

    Parameters
    ----------
    sample_rate_hz : float
        Sampling rate, Hz.
    channels : tuple of Channel
        The signal columns (the time column is not a channel).
    data : ndarray, shape (n_channels, n_samples)
        Signals in SI units, in the order of ``channels``.
    tool, cut : Tool, Cut
    material, sensors : optional
    name : str, optional
    robot_model : str, optional
    joints_deg : ndarray, shape (6,), optional
        The pose of the cut (``robot.joints_deg``), degrees.
    time_s : ndarray, shape (n_samples,), optional
        The file's time column, s, when it had one.
    signal_file : str
        File name of the signals (``signals.csv`` or ``signals.npz``), used when writing.
    path : str, optional
        Where the record was read from (set by :func:`oma.record_io.read_record`); named in the
        messages of errors found later (a record too short to diagnose, say). Not compared.
    """

    sample_rate_hz: float
    channels: tuple[Channel, ...]
    data: np.ndarray
    tool: Tool
    cut: Cut
    material: Material | None = None
    sensors: Sensors | None = None
    name: str | None = None
    robot_model: str | None = None
    joints_deg: np.ndarray | None = None
    time_s: np.ndarray | None = None
    signal_file: str = "signals.csv"
    path: str | None = field(default=None, compare=False)

    def __post_init__(self):
        data = np.array(self.data, dtype=float, ndmin=2)
        data.setflags(write=False)
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "channels", tuple(self.channels))
        if data.shape[0] != len(self.channels):
            raise ValueError(f"{len(self.channels)} channels but data has {data.shape[0]} rows")
        if self.time_s is not None:
            t = np.array(self.time_s, dtype=float)
            t.setflags(write=False)
            object.__setattr__(self, "time_s", t)
        if self.joints_deg is not None:
            q = np.array(self.joints_deg, dtype=float)
            q.setflags(write=False)
            object.__setattr__(self, "joints_deg", q)

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[1])

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.sample_rate_hz

    @property
    def time(self) -> np.ndarray:
        """Sample times, s: the file's time column if it had one, else ``arange(n) / fs``."""
        if self.time_s is not None:
            return self.time_s
        return np.arange(self.n_samples) / self.sample_rate_hz

    def has(self, quantity: str, axis: str | None = None) -> bool:
        return any(c.quantity == quantity and (axis is None or c.axis == axis) for c in self.channels)

    def signal(self, quantity: str, axis: str) -> np.ndarray:
        """The SI signal of one quantity along one machine axis, shape (n_samples,)."""
        for i, c in enumerate(self.channels):
            if c.quantity == quantity and c.axis == axis:
                return self.data[i]
        raise KeyError(f"record {self.name or ''} has no {quantity} channel along {axis}")

    def vector(self, quantity: str) -> np.ndarray:
        """The quantity along X, Y, Z, shape (3, n_samples); an axis not recorded is NaN."""
        out = np.full((3, self.n_samples), np.nan)
        for i, c in enumerate(self.channels):
            if c.quantity == quantity and c.axis in AXES:
                out[AXES.index(c.axis)] = self.data[i]
        return out

    @property
    def force(self) -> np.ndarray:
        """Force on the tool, (3, n_samples), N (NaN rows for axes not recorded)."""
        return self.vector("force")

    @property
    def displacement(self) -> np.ndarray:
        """Tool-tip displacement, (3, n_samples), m (NaN rows for axes not recorded)."""
        return self.vector("displacement")
