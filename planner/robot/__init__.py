"""The robot as a physical model (DOMAIN.md "The robot as a physical model", formats.md "Robot").

Layers, one idea per module: :mod:`.description` (what the robot is: ``robomill-robot/1`` + URDF,
frozen), :mod:`.kinematics` (forward kinematics, tool-tip Jacobian), :mod:`.dynamics` (mass matrix,
eigenproblem, tool-tip modal model), :mod:`.ik` (closed-form inverse kinematics, every branch),
:mod:`.correction` (the reach correction of the rigid-link model), :mod:`.calibrate` (joint
stiffness and damping from identified poses, trust), :mod:`.plots`, :mod:`.cli` (``robomill robot
...``). All functions are vectorised over poses: ``q`` in rad, shape ``(n, 6)`` or ``(6,)``.

The names below are imported lazily (on first use), so that ``robomill --help``, which builds
the ``--robot`` options, does not pay for numba and scipy.
"""

from __future__ import annotations

import importlib

_NAMES = {
    "description": ("Robot", "RobotError", "ToolBody", "read_robot", "write_robot"),
    "kinematics": ("forward_kinematics", "tip_jacobian", "tool_axis"),
    "dynamics": ("mass_matrix", "robot_modes", "RobotModes", "robot_modal_model"),
    "ik": ("inverse_kinematics", "IKSolutions", "PathIK", "continuous_branch", "singularity_measure",
           "joint_limit_distance", "tool_rotation"),
    "calibrate": ("calibrate", "Calibration", "trust", "trust_poses", "Trust"),
}
_MODULE_OF = {name: module for module, names in _NAMES.items() for name in names}

__all__ = [name for names in _NAMES.values() for name in names]


def __getattr__(name):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'planner.robot' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
