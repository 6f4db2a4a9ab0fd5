"""The ``tool``, ``cut``, ``material``, ``sensors`` and ``limits`` sections of robomill files.

Read (SI out) and dumped (file units out) the same way wherever they occur: in a record, a setup
and a toolpath (formats.md), with the :class:`~oma._fields.Fields` cursor of :mod:`oma._fields`.
Limits are returned as a plain dict of keyword arguments so that this module (package ``oma``)
does not import ``stability``; ``stability.setup_io`` builds the ``Limits`` object.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._fields import DEG_TO_RAD, PERPENDICULAR_TOLERANCE, Fields, UnitScale, describe, plain
from .cutting import Cut, CuttingCoefficients, Material, Sensors, Tool

__all__ = [
    "parse_tool",
    "parse_cut",
    "parse_material",
    "parse_sensors",
    "parse_limits",
    "dump_tool",
    "dump_cut",
    "dump_material",
    "dump_sensors",
    "dump_limits",
    "LIMIT_RANGES",
    "LIMIT_VALUES",
]


# ------------------------------------------------------------------- shared sections: reading
def parse_tool(node: Fields) -> Tool:
    """``tool: {teeth, diameter_m, helix_deg}`` -> :class:`~oma.cutting.Tool` (helix in rad)."""
    teeth = node.integer("teeth", ge=1)
    diameter = node.positive("diameter_m")
    helix_deg = node.number("helix_deg", required=False, default=0.0, ge=0, lt=90)
    node.done()
    return Tool(teeth=teeth, diameter_m=diameter, helix_rad=helix_deg * DEG_TO_RAD)


def parse_cut(node: Fields, *, tool: Tool | None, speed_and_depth_required: bool) -> Cut:
    """``cut:`` -> :class:`~oma.cutting.Cut`.

    Parameters
    ----------
    node : Fields
        Cursor over the ``cut`` mapping.
    tool : Tool or None
        The tool of the same file; when given, ``radial_depth_m`` may not exceed its diameter.
    speed_and_depth_required : bool
        ``True`` in a record; ``False`` in a setup, where ``spindle_rpm`` and ``axial_depth_m``
        may be left out (they are what is being chosen).
    """
    spindle = node.positive("spindle_rpm", required=speed_and_depth_required)
    fz = node.positive("feed_per_tooth_m")
    ae = node.positive("radial_depth_m")
    if tool is not None and ae > tool.diameter_m:
        node.fail("radial_depth_m", f"a radial depth <= the tool diameter {tool.diameter_m!r} m",
                  repr(ae))
    ap = node.positive("axial_depth_m", required=speed_and_depth_required)
    milling = node.choice("milling", ("up", "down"))
    f = node.direction("feed_direction")
    n = node.direction("normal_direction")
    dot = float(np.dot(f, n))
    if abs(dot) > PERPENDICULAR_TOLERANCE:
        node.fail("normal_direction",
                  f"a direction perpendicular to feed_direction (|f.n| <= {PERPENDICULAR_TOLERANCE:g})",
                  f"f.n = {dot:.6g}")
    window = node.vector("window_s", 2, required=False)
    if window is not None and not 0.0 <= window[0] < window[1]:
        node.fail("window_s", "[start, end] with 0 <= start < end, s", describe(window.tolist()))
    node.done()
    return Cut(feed_per_tooth_m=fz, radial_depth_m=ae, milling=milling, feed_direction=f,
               normal_direction=n, spindle_rpm=spindle, axial_depth_m=ap,
               window_s=None if window is None else (float(window[0]), float(window[1])))


_COEFFICIENTS = ("Ktc_N_m2", "Krc_N_m2", "Kac_N_m2", "Kte_N_m", "Kre_N_m", "Kae_N_m")


def parse_material(node: Fields, *, coefficients_required: bool = False) -> Material:
    """``material: {name, cutting_coefficients}`` -> :class:`~oma.cutting.Material`.

    ``Ktc_N_m2`` must be > 0 and is required with ``Krc_N_m2`` (>= 0); the others default to 0
    and must be >= 0.
    """
    name = node.text("name")
    cc_node = node.mapping_at("cutting_coefficients", required=coefficients_required)
    coefficients = None
    if cc_node is not None:
        values = {"Ktc_N_m2": cc_node.positive("Ktc_N_m2"),
                  "Krc_N_m2": cc_node.number("Krc_N_m2", ge=0)}
        for key in _COEFFICIENTS[2:]:
            values[key] = cc_node.number(key, required=False, default=0.0, ge=0)
        cc_node.done()
        coefficients = CuttingCoefficients(**values)
    node.done()
    return Material(name=name, cutting_coefficients=coefficients)


def parse_sensors(node: Fields) -> Sensors:
    """``sensors: {force: {noise_variance_N2, resolution_N}, displacement: {resolution_m}}``."""
    force = node.mapping_at("force")
    disp = node.mapping_at("displacement")
    values = {}
    if force is not None:
        values["force_noise_variance_N2"] = force.positive("noise_variance_N2", required=False)
        values["force_resolution_N"] = force.positive("resolution_N", required=False)
        force.done()
    if disp is not None:
        values["displacement_resolution_m"] = disp.positive("resolution_m", required=False)
        disp.done()
    node.done()
    return Sensors(**values)


#: Range limits ``[low, high]`` of a setup, all > 0.
LIMIT_RANGES = ("spindle_rpm", "axial_depth_m", "feed_per_tooth_m")
#: Scalar limits of a setup, all > 0 (``stability_margin`` also <= 1).
LIMIT_VALUES = ("spindle_power_W", "spindle_torque_N_m", "max_force_N", "surface_location_error_m",
                "stability_margin")


def parse_limits(node: Fields) -> dict[str, Any]:
    """``limits:`` -> keyword arguments of ``stability.setup.Limits`` (SI; absent keys left out).

    Ranges are ``(low, high)`` with ``0 < low <= high``; scalars are > 0; ``stability_margin`` is
    in ``(0, 1]``.
    """
    out: dict[str, Any] = {}
    for key in LIMIT_RANGES:
        span = node.span(key, gt=0)
        if span is not None:
            out[key] = span
    for key in LIMIT_VALUES:
        value = node.number(key, required=False, gt=0, le=1 if key == "stability_margin" else None)
        if value is not None:
            out[key] = value
    node.done()
    return out


# ------------------------------------------------------------------- shared sections: writing
def _drop_none(d: dict) -> dict:
    return {k: v for k, v in d.items() if v is not None}


def dump_tool(tool: Tool) -> dict:
    """The ``tool`` mapping of a :class:`~oma.cutting.Tool` (helix back in degrees)."""
    helix_deg = float(UnitScale(multiplier=DEG_TO_RAD).from_si(tool.helix_rad))
    return {"teeth": int(tool.teeth), "diameter_m": float(tool.diameter_m), "helix_deg": helix_deg}


def dump_cut(cut: Cut) -> dict:
    """The ``cut`` mapping of a :class:`~oma.cutting.Cut` (``None`` fields left out)."""
    return _drop_none({
        "spindle_rpm": None if cut.spindle_rpm is None else float(cut.spindle_rpm),
        "feed_per_tooth_m": float(cut.feed_per_tooth_m),
        "radial_depth_m": float(cut.radial_depth_m),
        "axial_depth_m": None if cut.axial_depth_m is None else float(cut.axial_depth_m),
        "milling": str(cut.milling),
        "feed_direction": [float(x) for x in cut.feed_direction],
        "normal_direction": [float(x) for x in cut.normal_direction],
        "window_s": None if cut.window_s is None else [float(x) for x in cut.window_s],
    })


def dump_material(material: Material) -> dict:
    """The ``material`` mapping of a :class:`~oma.cutting.Material`."""
    out: dict[str, Any] = {}
    if material.name is not None:
        out["name"] = str(material.name)
    cc = material.cutting_coefficients
    if cc is not None:
        out["cutting_coefficients"] = {k: float(getattr(cc, k)) for k in _COEFFICIENTS}
    return out


def dump_sensors(sensors: Sensors) -> dict:
    """The ``sensors`` mapping of a :class:`~oma.cutting.Sensors`."""
    force = _drop_none({"noise_variance_N2": sensors.force_noise_variance_N2,
                        "resolution_N": sensors.force_resolution_N})
    disp = _drop_none({"resolution_m": sensors.displacement_resolution_m})
    return _drop_none({"force": plain(force) or None, "displacement": plain(disp) or None})


def dump_limits(limits) -> dict:
    """The ``limits`` mapping of a ``Limits`` (any object with its attributes)."""
    out: dict[str, Any] = {}
    for key in LIMIT_RANGES:
        value = getattr(limits, key, None)
        if value is not None:
            out[key] = [float(value[0]), float(value[1])]
    for key in LIMIT_VALUES:
        value = getattr(limits, key, None)
        if value is not None:
            out[key] = float(value)
    return out
