"""A planned operation without signals: ``robomill-setup/1`` in memory (formats.md)."""

from __future__ import annotations

from dataclasses import dataclass

from oma.cutting import Cut, Material, Tool

__all__ = ["Limits", "Setup"]


@dataclass(frozen=True)
class Limits:
    """Bounds and limits used by ``plan`` and ``check``; every field optional, SI units.

    Ranges are ``(low, high)`` tuples. ``stability_margin`` is the fraction of the predicted
    limit depth that may be planned.
    """

    spindle_rpm: tuple[float, float] | None = None
    axial_depth_m: tuple[float, float] | None = None
    feed_per_tooth_m: tuple[float, float] | None = None
    spindle_power_W: float | None = None
    spindle_torque_N_m: float | None = None
    max_force_N: float | None = None
    surface_location_error_m: float | None = None
    stability_margin: float | None = None


@dataclass(frozen=True)
class Setup:
    """Tool, cut, material and limits of a planned operation."""

    tool: Tool
    cut: Cut
    material: Material
    limits: Limits = Limits()
    name: str | None = None
