"""A planned toolpath: ``robomill-toolpath/1`` in memory (formats.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma._arrays import readonly as _ro
from oma.cutting import Material, Tool
from stability.setup import Limits

__all__ = ["Toolpath"]


@dataclass(frozen=True)
class Toolpath:
    """Points of a toolpath with the robot pose and cutting conditions at each, SI units.

    Parameters
    ----------
    tool, material : Tool, Material
    tool_axis : ndarray, shape (3,) or (n_points, 3)
        Unit tool axis ``a`` in the machine frame (one for the path, or one per point).
    positions_m : ndarray, shape (n_points, 3)
    joints_deg : ndarray, shape (n_points, 6)
    spindle_rpm, feed_per_tooth_m, radial_depth_m, axial_depth_m : ndarray, shape (n_points,)
    milling : ndarray of str, shape (n_points,)
        ``'up'`` or ``'down'``.
    limits : Limits
    points_file : str
        File name of the point table, used when writing.
    """

    tool: Tool
    material: Material
    tool_axis: np.ndarray
    positions_m: np.ndarray
    joints_deg: np.ndarray
    spindle_rpm: np.ndarray
    feed_per_tooth_m: np.ndarray
    radial_depth_m: np.ndarray
    axial_depth_m: np.ndarray
    milling: np.ndarray
    limits: Limits = Limits()
    points_file: str = "toolpath.csv"

    def __post_init__(self):
        for name in ("tool_axis", "positions_m", "joints_deg", "spindle_rpm", "feed_per_tooth_m",
                     "radial_depth_m", "axial_depth_m"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "milling", _ro(self.milling, dtype=str))

    @property
    def n_points(self) -> int:
        return int(self.positions_m.shape[0])

    def feed_directions(self) -> np.ndarray:
        """Unit feed direction of each point, (n_points, 3): towards the next point; the last point
        keeps the direction of the segment before it (formats.md)."""
        d = np.diff(self.positions_m, axis=0)
        d = np.vstack([d, d[-1:]]) if len(d) else np.zeros((1, 3))
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return d / norm

    def normal_directions(self) -> np.ndarray:
        """``n = a x f`` at each point, (n_points, 3)."""
        a = np.broadcast_to(self.tool_axis, self.positions_m.shape)
        return np.cross(a, self.feed_directions())
