"""A planned toolpath: ``robomill-toolpath/1`` in memory (formats.md)."""

from __future__ import annotations

from dataclasses import dataclass, replace

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
    joints_deg : ndarray, shape (n_points, 6), or None
        Robot pose of each point, degrees (NaN rows: not given). ``None`` only with a robot: then
        inverse kinematics gives the joints (formats.md "Toolpath with a robot").
    spindle_rpm, feed_per_tooth_m, radial_depth_m, axial_depth_m : ndarray, shape (n_points,)
    milling : ndarray of str, shape (n_points,)
        ``'up'`` or ``'down'``.
    limits : Limits
    points_file : str
        File name of the point table, used when writing.
    robot_file : str, optional
        The ``robomill-robot/1`` file of the cell (absolute or relative to the working directory).
    workpiece_origin_m, workpiece_rpy_deg : ndarray, shape (3,), optional
        The part's frame in the machine frame (origin, m; fixed-axis roll-pitch-yaw X-Y-Z, deg):
        with it, ``positions_m`` and ``tool_axis`` are in the part frame.
    tool_rotation_deg : ndarray, shape (n_points,), optional
        Rotation of the flange about the tool axis, deg (0: the flange x axis as close as possible
        to the feed direction); NaN or ``None``: free (``robomill posture`` chooses it).
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
    robot_file: str | None = None
    workpiece_origin_m: np.ndarray | None = None
    workpiece_rpy_deg: np.ndarray | None = None
    tool_rotation_deg: np.ndarray | None = None

    def __post_init__(self):
        for name in ("tool_axis", "positions_m", "joints_deg", "spindle_rpm", "feed_per_tooth_m",
                     "radial_depth_m", "axial_depth_m", "workpiece_origin_m", "workpiece_rpy_deg",
                     "tool_rotation_deg"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _ro(value))
        if (self.workpiece_origin_m is None) != (self.workpiece_rpy_deg is None):
            raise ValueError("workpiece_origin_m and workpiece_rpy_deg go together")
        object.__setattr__(self, "milling", _ro(self.milling, dtype=str))

    @property
    def n_points(self) -> int:
        return int(self.positions_m.shape[0])

    @property
    def has_joints(self) -> bool:
        """Every point has its joint angles."""
        return self.joints_deg is not None and bool(np.all(np.isfinite(self.joints_deg)))

    def workpiece_rotation(self) -> np.ndarray:
        """Rotation of the part frame in the machine frame, (3, 3): ``Rz(yaw) Ry(pitch) Rx(roll)``
        (fixed axes X-Y-Z, as URDF's ``rpy``); the identity without a workpiece frame."""
        if self.workpiece_rpy_deg is None:
            return np.eye(3)
        r, p, y = np.radians(self.workpiece_rpy_deg)
        cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                         [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                         [-sp, cp * sr, cp * cr]])

    def in_machine_frame(self) -> "Toolpath":
        """The same path with positions and tool axis in the machine frame (no workpiece frame)."""
        if self.workpiece_origin_m is None:
            return self
        rot = self.workpiece_rotation()
        return replace(self, positions_m=self.positions_m @ rot.T + self.workpiece_origin_m,
                       tool_axis=np.asarray(self.tool_axis) @ rot.T, workpiece_origin_m=None,
                       workpiece_rpy_deg=None)

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
