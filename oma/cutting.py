"""Tool, cut and material: the description of one milling operation (formats.md).

Everything here is SI (m, s, N, rad). The cutting frame of a cut is ``f`` (feed), ``n`` (normal)
and ``a = f x n`` (tool axis, from the tip into the spindle); a tooth at immersion angle ``phi``
sits at ``sin(phi) f + cos(phi) n`` from the tool axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "Tool",
    "Cut",
    "CuttingCoefficients",
    "Material",
    "Sensors",
    "engagement_angles",
]

Milling = Literal["up", "down"]


def _frozen_vector(v) -> np.ndarray:
    a = np.array(v, dtype=float).reshape(3)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Tool:
    """An end mill.

    Parameters
    ----------
    teeth : int
        Number of flutes.
    diameter_m : float
        Tool diameter D, m.
    helix_rad : float
        Helix angle, rad (0 for straight flutes).
    """

    teeth: int
    diameter_m: float
    helix_rad: float = 0.0


@dataclass(frozen=True)
class Cut:
    """Cutting conditions and the cutting frame, machine-frame unit vectors.

    ``spindle_rpm`` and ``axial_depth_m`` may be ``None`` in a setup, where they are what is being
    chosen. ``window_s`` is the span of a record where the tool is fully engaged.
    """

    feed_per_tooth_m: float
    radial_depth_m: float
    milling: Milling
    feed_direction: np.ndarray
    normal_direction: np.ndarray
    spindle_rpm: float | None = None
    axial_depth_m: float | None = None
    window_s: tuple[float, float] | None = None

    def __post_init__(self):
        object.__setattr__(self, "feed_direction", _frozen_vector(self.feed_direction))
        object.__setattr__(self, "normal_direction", _frozen_vector(self.normal_direction))

    @property
    def tool_axis(self) -> np.ndarray:
        """``a = f x n``, from the tool tip into the spindle."""
        return np.cross(self.feed_direction, self.normal_direction)

    @property
    def frame(self) -> np.ndarray:
        """Rows ``f, n, a``: the (3, 3) rotation from machine to cutting frame."""
        return np.vstack([self.feed_direction, self.normal_direction, self.tool_axis])


@dataclass(frozen=True)
class CuttingCoefficients:
    """Linear-plus-edge force model (formats.md), per unit chip width.

    ``dFt = (Ktc h + Kte) dz``, ``dFr = (Krc h + Kre) dz``, ``dFa = (Kac h + Kae) dz``.
    Cutting coefficients in N/m^2, edge coefficients in N/m.
    """

    Ktc_N_m2: float
    Krc_N_m2: float
    Kac_N_m2: float = 0.0
    Kte_N_m: float = 0.0
    Kre_N_m: float = 0.0
    Kae_N_m: float = 0.0


@dataclass(frozen=True)
class Material:
    """A workpiece material: a name and, optionally, its cutting coefficients."""

    name: str | None = None
    cutting_coefficients: CuttingCoefficients | None = None


@dataclass(frozen=True)
class Sensors:
    """Sensor figures used by the excitation and detectability checks (all optional)."""

    force_noise_variance_N2: float | None = None
    force_resolution_N: float | None = None
    displacement_resolution_m: float | None = None


def engagement_angles(tool: Tool, cut: Cut) -> tuple[float, float]:
    """Entry and exit immersion angles ``(phi_st, phi_ex)``, rad (formats.md).

    Up milling engages ``0 .. arccos(1 - 2 ae/D)``, down milling ``arccos(2 ae/D - 1) .. pi``.
    """
    ratio = cut.radial_depth_m / tool.diameter_m
    ratio = min(max(ratio, 0.0), 1.0)
    if cut.milling == "up":
        return 0.0, float(np.arccos(1.0 - 2.0 * ratio))
    return float(np.arccos(2.0 * ratio - 1.0)), float(np.pi)
