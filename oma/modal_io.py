"""Read and write ``robomill-modal/1`` modal models (formats.md)::

    format: robomill-modal/1
    pose: {joints_deg: [88.44, -13.62, 72.42, 180.90, 59.55, -0.67]}   # optional
    modes:
      - {natural_frequency_hz: 10.5, damping_ratio: 0.05, stiffness_N_m: 1.5e6, direction: [1, 0, 0]}
    residual_compliance_m_N: [[0, 0, 0], [0, 0, 0], [0, 0, 0]]         # optional
    source: {method: oma-h1, records: [...], fit_error: 0.03}           # optional, free provenance

The same mapping is what ``robomill identify --json`` prints as ``model``, hence
:func:`modal_model_to_dict` / :func:`modal_model_from_dict` beside the file functions.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ._fields import Fields, describe, dump_yaml, load_yaml, plain, warn_user
from .errors import ModelError
from .io import atomic_write
from .modal import ModalModel

__all__ = ["read_modal_model", "write_modal_model", "modal_model_to_dict", "modal_model_from_dict",
           "FORMAT"]

FORMAT = "robomill-modal/1"


def read_modal_model(path) -> ModalModel:
    """Read a ``robomill-modal/1`` YAML file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    ModalModel
        Frequencies in Hz, stiffness in N/m, unit directions, residual compliance in m/N.

    Raises
    ------
    ModelError
        Missing/unreadable file, unsafe or invalid YAML, wrong ``format``, an unknown key, no
        modes, a frequency or stiffness <= 0, a damping ratio outside (0, 1), a mode direction
        that is not a non-zero 3-vector, a residual compliance that is not 3x3, a pose that is not
        6 joint angles.

    Warns
    -----
    oma._fields.FileWarning
        A mode direction whose length is off 1 by more than 1 % (it is normalised).
    """
    root = load_yaml(path, error=ModelError)
    return _parse(root)


def modal_model_from_dict(mapping: Mapping, file=None) -> ModalModel:
    """Build a model from a ``robomill-modal/1`` mapping (as :func:`modal_model_to_dict` makes).

    Parameters
    ----------
    mapping : Mapping
        The parsed mapping (lists or arrays for vectors).
    file : str or path-like, optional
        Named in error messages (``<input>`` when ``None``).

    Raises
    ------
    ModelError
        As :func:`read_modal_model`.
    """
    if not isinstance(mapping, Mapping):
        raise ModelError(file, "document", "a robomill-modal/1 mapping", describe(mapping))
    return _parse(Fields(mapping, file=file, error=ModelError))


def _parse(root: Fields) -> ModalModel:
    root.format(FORMAT)
    pose = root.mapping_at("pose")
    joints = None
    if pose is not None:
        joints = pose.vector("joints_deg", 6, required=False)
        pose.done()
    modes = root.sequence("modes", min_len=1)
    fn, zeta, k, u = [], [], [], []
    for i, item in enumerate(modes):
        where = root.where("modes") + f"[{i}]"
        if not isinstance(item, Mapping):
            raise ModelError(root.file, where, "a mode mapping {natural_frequency_hz, damping_ratio, "
                             "stiffness_N_m, direction}", describe(item))
        mode = root.child(item, where)
        fn.append(mode.positive("natural_frequency_hz"))
        zeta.append(mode.number("damping_ratio", gt=0))
        if zeta[-1] >= 1.0:
            # an overdamped mode is physical (a robot's joint damping can make one: robot model
            # writes it) and G(w) of formats.md holds for it; but 5 meant as 5 % is the likelier typo
            warn_user(f"{root.file or '<input>'}: {where}.damping_ratio: {zeta[-1]:g} >= 1, an overdamped mode "
                      "(a ratio: 5 % is 0.05)")
        k.append(mode.positive("stiffness_N_m"))
        u.append(mode.direction("direction"))
        mode.done()
    residual = root.matrix("residual_compliance_m_N", (3, 3), required=False)
    if residual is not None:
        r = np.asarray(residual, dtype=float)
        if not np.allclose(r, r.T, rtol=1e-9, atol=1e-12 * max(float(np.max(np.abs(r))), 1e-300)):
            raise ModelError(root.file, root.where("residual_compliance_m_N"), "a symmetric matrix (reciprocity: "
                             "G = X/F is symmetric)", f"{r.tolist()}")
    source_node = root.mapping_at("source")  # free provenance: its keys are not checked
    source = None if source_node is None else dict(source_node.mapping)
    root.done()
    kwargs: dict[str, Any] = {}
    if residual is not None:
        kwargs["residual_compliance_m_N"] = residual
    model = ModalModel(natural_frequency_hz=np.array(fn), damping_ratio=np.array(zeta),
                       stiffness_N_m=np.array(k), directions=np.array(u), joints_deg=joints,
                       source=source, **kwargs)
    static = model.receptance(np.zeros(1))[..., 0].real
    ev = np.linalg.eigvalsh(0.5 * (static + static.T))
    if ev[0] < -1e-9 * ev[-1]:
        warn_user(f"{root.file or '<input>'}: residual_compliance_m_N: the static compliance (modes plus "
                  f"residual) is negative along a direction ({ev[0]:.3g} m/N): not a passive structure "
                  "(formats.md: G has positive static compliance)")
    return model


def modal_model_to_dict(model: ModalModel) -> dict:
    """The ``robomill-modal/1`` mapping of a model: plain lists, floats and strings only.

    ``residual_compliance_m_N`` is left out when it is all zeros and ``pose`` when the model has
    no joints; ``source`` is copied (NumPy values made plain).
    """
    out: dict[str, Any] = {"format": FORMAT}
    if model.joints_deg is not None:
        out["pose"] = {"joints_deg": [float(q) for q in model.joints_deg]}
    out["modes"] = [
        {"natural_frequency_hz": float(f), "damping_ratio": float(z), "stiffness_N_m": float(k),
         "direction": [float(x) for x in d]}
        for f, z, k, d in zip(model.natural_frequency_hz, model.damping_ratio, model.stiffness_N_m,
                              model.directions)
    ]
    if np.any(model.residual_compliance_m_N != 0):
        out["residual_compliance_m_N"] = [[float(x) for x in row] for row in model.residual_compliance_m_N]
    if model.source is not None:
        out["source"] = plain(dict(model.source))
    return out


def write_modal_model(model: ModalModel, path) -> Path:
    """Write a model as a ``robomill-modal/1`` YAML file (atomically, floats in full precision).

    Returns
    -------
    pathlib.Path
        The file written.
    """
    target = Path(os.fspath(path))
    text = dump_yaml(modal_model_to_dict(model))
    with atomic_write(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return target
