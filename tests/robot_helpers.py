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
#: Where the shared data directory is expected (``$ROBOMILL_SHARED`` or ``<repo>/../shared``); it
#: may be missing (:func:`shared_dir` says so).
SHARED = Path(os.environ.get("ROBOMILL_SHARED") or REPO.parent / "shared")

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

#: Columns of a part-frame toolpath CSV (formats.md), without joint angles.
TOOLPATH_HEADER = "x_m,y_m,z_m,spindle_rpm,feed_per_tooth_m,radial_depth_m,axial_depth_m,milling"

_TOOLPATH_YAML = """\
format: robomill-toolpath/1
robot: {robot}
workpiece_frame: {{origin_m: {origin}, rpy_deg: {rpy}}}
tool: {{teeth: 2, diameter_m: 0.0254, helix_deg: 30.0}}
material:
  name: acetal
  cutting_coefficients: {{Ktc_N_m2: 1.2e8, Krc_N_m2: 4.5e7, Kac_N_m2: 2.0e7, Kte_N_m: 2000.0, Kre_N_m: 3000.0,
    Kae_N_m: 500.0}}
tool_axis: [0.0, 0.0, 1.0]
limits: {limits}
points: path.csv
"""


def toolpath_yaml(robot: str, *, origin_m, rpy_deg, limits: str) -> str:
    """A part-frame toolpath file (acetal, the 2-flute 25.4 mm tool) on ``robot``, its points in
    ``path.csv``; ``limits`` is the YAML flow mapping of its limits."""
    return _TOOLPATH_YAML.format(robot=robot, origin=list(origin_m), rpy=list(rpy_deg), limits=limits)


def shared_dir() -> Path:
    """The shared data directory (``$ROBOMILL_SHARED`` or ``<repo>/../shared``); raises with a
    clear message when it is missing."""
    path = SHARED
    if not (path / "data").is_dir():
        raise FileNotFoundError(
            f"the shared data directory {path} (with data/, the real robots and recordings) is missing: clone "
            "the repository with shared/ beside it, or set ROBOMILL_SHARED to its location")
    return path


def urdf_path(name: str = "kr500_r2800_2") -> Path:
    return shared_dir() / "data" / "robots" / f"{name}.urdf"


def write_robot_file(directory, *, urdf: str = "kr500_r2800_2", stiffness: bool = True, name="robot.yaml") -> Path:
    """A ``robomill-robot/1`` file of the KR 500 R2800-2 with a 150 kg spindle (tip 0.45 m from
    the flange), joint stiffness of DOMAIN.md when ``stiffness``; returns its path."""
    path = Path(directory) / name
    path.write_text(ROBOT_YAML.format(urdf=urdf_path(urdf), joints=JOINTS_YAML if stiffness else ""))
    return path


# ------------------------------------------------------------------ synthetic identified poses
#: A milling pose of the KR 500 (deg): tool pointing down in front of the robot, and the spread of
#: the working region around it.
NOMINAL_POSE_DEG = (0.0, -60.0, 100.0, 0.0, 50.0, 0.0)
REGION_SPREAD_DEG = (30.0, 20.0, 20.0, 45.0, 25.0, 60.0)


def region_poses(robot, n, rng, *, scale=1.0):
    """Poses (rad, (n, 6)) drawn uniformly in the nominal pose +- ``scale`` * spread, within limits."""
    import numpy as np

    lo = np.radians(np.array(NOMINAL_POSE_DEG) - scale * np.array(REGION_SPREAD_DEG))
    hi = np.radians(np.array(NOMINAL_POSE_DEG) + scale * np.array(REGION_SPREAD_DEG))
    q = rng.uniform(lo, hi, (n, 6))
    return np.clip(q, robot.lower_rad, robot.upper_rad)


def identified_models(robot, q, rng, *, n_modes=3, noise=(0.01, 0.10, 0.05, 2.0), stiffness=None):
    """What identification at poses ``q`` (rad) would give: the ``n_modes`` most compliant tool-tip
    modes of ``robot`` (or of ``stiffness`` per pose, (n, 6)), with relative noise on frequency,
    damping and stiffness and a random tilt (deg, one-sigma) of each direction."""
    import numpy as np
    from oma.modal import ModalModel
    from planner.robot.dynamics import robot_modes

    sf, sz, sk, su = noise
    modes = robot_modes(robot, q, stiffness=stiffness)
    out = []
    for i in range(len(q)):
        order = np.sort(np.argsort(-modes.compliance_m_N[i])[:n_modes])
        u = modes.directions[i, order]
        tilt = rng.normal(size=u.shape)
        tilt -= np.sum(tilt * u, axis=1, keepdims=True) * u
        tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
        angle = np.radians(su) * np.abs(rng.normal(size=(len(order), 1)))
        u = np.cos(angle) * u + np.sin(angle) * tilt
        out.append(ModalModel(modes.frequency_hz[i, order] * (1 + sf * rng.normal(size=len(order))),
                              modes.damping_ratio[i, order] * (1 + sz * rng.normal(size=len(order))),
                              modes.stiffness_N_m[i, order] * (1 + sk * rng.normal(size=len(order))), u,
                              joints_deg=np.degrees(q[i])))
    return out
