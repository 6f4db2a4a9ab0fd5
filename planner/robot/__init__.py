"""The robot as a physical model (DOMAIN.md "The robot as a physical model", formats.md "Robot").

Layers, one idea per module: :mod:`.description` (what the robot is: ``robomill-robot/1`` + URDF,
frozen), :mod:`.kinematics` (forward kinematics, tool-tip Jacobian), :mod:`.dynamics` (mass matrix,
eigenproblem, tool-tip modal model), :mod:`.ik` (closed-form inverse kinematics, every branch),
:mod:`.correction` (the reach correction of the rigid-link model), :mod:`.calibrate` (joint
stiffness and damping from identified poses, trust), :mod:`.cli` (``robomill robot ...``).
All functions are vectorised over poses: ``q`` in rad, shape ``(n, 6)`` or ``(6,)``.
"""

from .calibrate import Calibration, Trust, calibrate, trust
from .description import Robot, RobotError, ToolBody, read_robot, write_robot
from .dynamics import RobotModes, mass_matrix, robot_modal_model, robot_modes
from .ik import (IKSolutions, PathIK, continuous_branch, inverse_kinematics, joint_limit_distance, singularity_measure,
                 tool_rotation)
from .kinematics import forward_kinematics, tip_jacobian, tool_axis

__all__ = ["Robot", "RobotError", "ToolBody", "read_robot", "write_robot", "forward_kinematics", "tip_jacobian",
           "tool_axis", "mass_matrix", "robot_modes", "RobotModes", "robot_modal_model", "inverse_kinematics",
           "IKSolutions", "PathIK", "continuous_branch", "singularity_measure", "joint_limit_distance", "tool_rotation",
           "calibrate", "Calibration", "trust", "Trust"]
