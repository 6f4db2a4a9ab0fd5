"""The region of an atlas: a box (or a plane) of tool-tip positions, a grid step, tool rotations.

Positions are given in the workpiece frame (``formats.md``: the part's frame in the machine frame,
``origin_m`` and fixed-axis roll-pitch-yaw ``rpy_deg``; the machine frame when no frame is given).
An axis whose lower and upper bounds are equal is not sampled, so a box with one flat side is a
plane. The grid points are ``lower + step * i`` up to ``upper`` (inclusive to 1e-9 of a step), in
C order over (x, y, z): ``z`` varies fastest. Rotations about the tool axis are in degrees in the
interface (``rotations_deg``) and radians inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from oma._arrays import readonly as _ro
from oma.errors import InputError

__all__ = ["Region", "RegionError", "rpy_matrix", "default_rotations_deg"]

#: Largest grid an atlas builds (points, before rotations): a guard against a unit slip (step in mm).
MAX_POINTS = 50_000_000


class RegionError(InputError):
    """A region (command-line options, no file) that cannot be used: ``option: expected ..., found ...``."""

    def __init__(self, option: str, expected: str, found: str):
        super().__init__(None, option, expected, found)

    def __str__(self) -> str:
        return f"{self.field}: expected {self.expected}, found {self.found}"


def rpy_matrix(rpy_deg) -> np.ndarray:
    """Rotation of fixed-axis roll-pitch-yaw angles (X, then Y, then Z), ``Rz Ry Rx``."""
    r, p, y = np.radians(np.asarray(rpy_deg, float).reshape(3))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def default_rotations_deg(step_deg: float = 30.0) -> np.ndarray:
    """Rotations ``-180 <= r < 180`` every ``step_deg`` (12 for 30 deg)."""
    if not (math.isfinite(step_deg) and 0 < step_deg <= 360):
        raise RegionError("--rotation-step-deg", "a step in (0, 360] deg", repr(step_deg))
    n = int(round(360.0 / step_deg))
    return -180.0 + step_deg * np.arange(n)


@dataclass(frozen=True)
class Region:
    """A box of tool-tip positions in the workpiece frame, sampled every ``step_m``.

    Parameters
    ----------
    lower_m, upper_m : array_like, shape (3,)
        Corners, m (``lower <= upper``; equal on an axis: a plane).
    step_m : float
        Grid step, m.
    rotations_deg : array_like
        Rotations of the flange about the tool axis to evaluate at every position, deg (0: the
        flange's reference axis as close as possible to the feed direction, formats.md).
    origin_m : array_like, shape (3,), optional
        The workpiece frame's origin in the machine frame, m.
    rpy_deg : array_like, shape (3,), optional
        Its orientation, fixed-axis roll-pitch-yaw, deg.
    """

    lower_m: np.ndarray
    upper_m: np.ndarray
    step_m: float
    rotations_deg: np.ndarray
    origin_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        for name in ("lower_m", "upper_m", "origin_m", "rpy_deg"):
            value = np.asarray(getattr(self, name), float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise RegionError(_option(name), "3 finite numbers", repr(getattr(self, name)))
            object.__setattr__(self, name, _ro(value))
        if np.any(self.lower_m > self.upper_m):
            raise RegionError("--box-m", "lower corner <= upper corner on every axis",
                             f"{self.lower_m.tolist()} .. {self.upper_m.tolist()}")
        step = float(self.step_m)
        if not (math.isfinite(step) and step > 0):
            raise RegionError("--step-m", "a grid step > 0 m", repr(self.step_m))
        object.__setattr__(self, "step_m", step)
        rot = np.atleast_1d(np.asarray(self.rotations_deg, float))
        if rot.ndim != 1 or rot.size == 0 or not np.all(np.isfinite(rot)):
            raise RegionError("--rotations-deg", "one or more finite angles", repr(self.rotations_deg))
        object.__setattr__(self, "rotations_deg", _ro(rot))
        n = int(np.prod(self.shape))
        if n > MAX_POINTS:
            raise RegionError("--step-m", f"at most {MAX_POINTS} grid points (is the step in m?)",
                             f"{n} points at {step:g} m")

    @property
    def axes_m(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grid coordinates along x, y, z (workpiece frame), m."""
        out = []
        for lo, hi in zip(self.lower_m, self.upper_m):
            count = int(math.floor((hi - lo) / self.step_m + 1e-9)) + 1
            out.append(lo + self.step_m * np.arange(count))
        return tuple(out)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(a.size for a in self.axes_m)

    @property
    def n_points(self) -> int:
        return int(np.prod(self.shape))

    @property
    def rotation(self) -> np.ndarray:
        """Workpiece frame to machine frame rotation, (3, 3)."""
        return rpy_matrix(self.rpy_deg)

    def positions_m(self) -> np.ndarray:
        """Grid positions in the workpiece frame, (n_points, 3), z fastest."""
        x, y, z = np.meshgrid(*self.axes_m, indexing="ij")
        return np.column_stack([x.ravel(), y.ravel(), z.ravel()])

    def to_machine(self, points_m) -> np.ndarray:
        """Workpiece-frame points (n, 3) in the machine frame."""
        return np.asarray(points_m, float) @ self.rotation.T + self.origin_m

    def direction_to_machine(self, v) -> np.ndarray:
        return np.asarray(v, float) @ self.rotation.T

    def to_dict(self) -> dict:
        return {"lower_m": self.lower_m.tolist(), "upper_m": self.upper_m.tolist(), "step_m": self.step_m,
                "shape": list(self.shape), "rotations_deg": self.rotations_deg.tolist(),
                "workpiece_frame": {"origin_m": self.origin_m.tolist(), "rpy_deg": self.rpy_deg.tolist()}}


def _option(name: str) -> str:
    return {"lower_m": "--box-m", "upper_m": "--box-m", "origin_m": "--origin-m", "rpy_deg": "--rpy-deg"}[name]
