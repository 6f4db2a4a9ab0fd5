"""Shared helpers of the robot tests and benchmark: where the real URDFs are, and a robot file.

The real KUKA URDFs live in the shared data directory beside the repository (``<repo>/../shared``;
CI clones the repository with ``shared/`` beside it). ``ROBOMILL_SHARED`` overrides the location
(e.g. for a git worktree elsewhere). A missing directory is an error with a clear message, never a
silent skip.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

ROBOT_YAML = """\
format: robomill-robot/1
name: KUKA KR500 R2800-2 with a 150 kg spindle
urdf: {urdf}
base_link: base_link
flange_link: tool0
tool:
  tip_m: [0.0, 0.0, 0.45]
  axis: [0.0, 0.0, -1.0]
  mass_kg: 150.0
  center_of_mass_m: [0.0, 0.0, 0.20]
  inertia_kg_m2: [[4.0, 0, 0], [0, 4.0, 0], [0, 0, 1.5]]
{joints}"""

JOINTS_YAML = """\
joints:
  stiffness_N_m_rad: [2.3e6, 8.6e6, 2.8e6, 3.0e6, 0.2e6, 0.9e6]
  damping_ratio: [0.05, 0.05, 0.05, 0.05, 0.05, 0.05]
"""


def shared_dir() -> Path:
    """The shared data directory (``$ROBOMILL_SHARED`` or ``<repo>/../shared``); raises with a
    clear message when it is missing."""
    env = os.environ.get("ROBOMILL_SHARED")
    path = Path(env) if env else REPO.parent / "shared"
    if not (path / "data" / "robots").is_dir():
        raise FileNotFoundError(
            f"the shared data directory {path} (with data/robots/*.urdf) is missing: clone the repository "
            "with shared/ beside it, or set ROBOMILL_SHARED to its location")
    return path


def urdf_path(name: str = "kr500_r2800_2") -> Path:
    return shared_dir() / "data" / "robots" / f"{name}.urdf"


def write_robot_file(directory, *, urdf: str = "kr500_r2800_2", stiffness: bool = True, name="robot.yaml") -> Path:
    """A ``robomill-robot/1`` file of the KR 500 R2800-2 with a 150 kg spindle (tip 0.45 m from
    the flange), joint stiffness of DOMAIN.md when ``stiffness``; returns its path."""
    path = Path(directory) / name
    path.write_text(ROBOT_YAML.format(urdf=urdf_path(urdf), joints=JOINTS_YAML if stiffness else ""))
    return path
