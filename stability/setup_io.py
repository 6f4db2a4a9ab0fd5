"""Read and write ``robomill-setup/1`` files: a planned operation without signals (formats.md).

Tool, cut and material read as in a record (:mod:`oma._fields`); the cut may leave out
``spindle_rpm`` and ``axial_depth_m`` (they are what ``lobes``/``plan`` choose). The material must
carry its cutting coefficients, since every command that reads a setup computes cutting forces.
"""

from __future__ import annotations

import os
from pathlib import Path

from oma._fields import dump_yaml, load_yaml
from oma._sections import dump_cut, dump_limits, dump_material, dump_tool, parse_cut, parse_limits, parse_material
from oma._sections import parse_tool
from oma.errors import SetupError
from oma.io import atomic_write

from .setup import Limits, Setup

__all__ = ["read_setup", "write_setup", "FORMAT"]

FORMAT = "robomill-setup/1"


def read_setup(path) -> Setup:
    """Read a ``robomill-setup/1`` YAML file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    Setup
        SI units (helix in rad); ``limits`` all ``None`` when the file has none.

    Raises
    ------
    SetupError
        Missing/unreadable file, unsafe or invalid YAML, wrong ``format``, an unknown key (other
        than ``x_...``), a wrong type, a physical value <= 0, ``milling`` other than up/down,
        zero or non-perpendicular feed/normal directions, no cutting coefficients, a limit range
        that is not ``[low, high]`` with ``0 < low <= high``, a stability margin outside (0, 1].

    Warns
    -----
    oma._fields.FileWarning
        A direction whose length is off 1 by more than 1 % (it is normalised).
    """
    root = load_yaml(path, error=SetupError)
    root.format(FORMAT)
    name = root.text("name")
    tool = parse_tool(root.mapping_at("tool", required=True))
    cut = parse_cut(root.mapping_at("cut", required=True), tool=tool, speed_and_depth_required=False)
    material = parse_material(root.mapping_at("material", required=True), coefficients_required=True)
    limits_node = root.mapping_at("limits")
    limits = Limits(**parse_limits(limits_node)) if limits_node is not None else Limits()
    root.done()
    return Setup(tool=tool, cut=cut, material=material, limits=limits, name=name)


def write_setup(setup: Setup, path) -> Path:
    """Write a setup as a ``robomill-setup/1`` YAML file (atomically, floats in full precision).

    ``name`` is written when set; ``limits`` when any limit is set.

    Returns
    -------
    pathlib.Path
    """
    doc: dict = {"format": FORMAT}
    if setup.name is not None:
        doc["name"] = setup.name
    doc["tool"] = dump_tool(setup.tool)
    doc["cut"] = dump_cut(setup.cut)
    doc["material"] = dump_material(setup.material)
    limits = dump_limits(setup.limits)
    if limits:
        doc["limits"] = limits
    target = Path(os.fspath(path))
    text = dump_yaml(doc)
    with atomic_write(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return target
