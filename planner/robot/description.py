"""What the robot is (``robomill-robot/1`` plus its URDF): a frozen description, built once.

Like Pinocchio's ``Model`` (kept apart from the per-configuration ``Data``), a :class:`Robot` holds
only the pose-independent facts: the chain of six revolute joints from ``base_link`` to
``flange_link``, their limits, the rigid bodies they move (link masses, centres of mass and
inertias, with every link fixed to them lumped in), the tool body bolted to the flange, and the
joints' stiffness and damping when given. Pose-dependent quantities are free functions of a
``Robot`` and ``q`` (:mod:`planner.robot.kinematics`, :mod:`planner.robot.dynamics`).

Frames: body 0 is ``base_link`` (the machine frame, formats.md); body ``i`` (1..6) is the child
link of joint ``i`` with every link fixed to it. ``T_{i-1,i}(q_i) = joint_origin[i] @ Rot(axis_i,
q_i)`` with ``joint_origin[i]`` the fixed transform from body ``i-1``'s frame to joint ``i``'s frame
at ``q_i = 0`` (the fixed joints between the two revolute ones included). ``flange_origin`` maps
body 6's frame to the flange frame, in which the tool is described.

Units: m, kg, kg m^2, rad (``*_deg`` only in files), N m/rad, N m s/rad.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from oma._arrays import readonly as _ro
from oma._fields import dump_yaml, load_yaml, plain
from oma.errors import InputError
from oma.io import atomic_write

__all__ = ["Robot", "ToolBody", "RobotError", "read_robot", "write_robot", "robot_to_dict", "FORMAT",
           "KR500_JOINT_STIFFNESS_N_M_RAD"]

FORMAT = "robomill-robot/1"
N_JOINTS = 6
#: Joint stiffness of a KUKA KR500 used in a published robot-milling simulation (DOMAIN.md), N m/rad.
KR500_JOINT_STIFFNESS_N_M_RAD = (2.3e6, 8.6e6, 2.8e6, 3.0e6, 0.2e6, 0.9e6)


class RobotError(InputError):
    """A ``robomill-robot/1`` file or its URDF that cannot be used."""


@dataclass(frozen=True, eq=False)
class ToolBody:
    """The rigid body bolted to the flange (spindle + holder + tool), flange frame.

    Parameters
    ----------
    tip_m : array_like, shape (3,)
        Tool tip, m.
    axis : array_like, shape (3,)
        Tool axis ``a`` (unit), from the tool tip into the spindle.
    mass_kg : float
    center_of_mass_m : array_like, shape (3,)
    inertia_kg_m2 : array_like, shape (3, 3)
        About the centre of mass, flange axes.
    """

    tip_m: np.ndarray
    axis: np.ndarray
    mass_kg: float
    center_of_mass_m: np.ndarray
    inertia_kg_m2: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "tip_m", _ro(np.asarray(self.tip_m, float).reshape(3)))
        a = np.asarray(self.axis, float).reshape(3)
        object.__setattr__(self, "axis", _ro(a / np.linalg.norm(a)))
        object.__setattr__(self, "mass_kg", float(self.mass_kg))
        object.__setattr__(self, "center_of_mass_m", _ro(np.asarray(self.center_of_mass_m, float).reshape(3)))
        object.__setattr__(self, "inertia_kg_m2", _ro(np.asarray(self.inertia_kg_m2, float).reshape(3, 3)))

    @property
    def reference_axis(self) -> np.ndarray:
        """The flange x axis made perpendicular to the tool axis (unit, flange frame); the flange
        y axis instead when x is within 1 deg of the tool axis. Rotation about the tool axis is
        measured from it (formats.md: 0 = the flange x axis as close as possible to the feed)."""
        for e in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
            v = e - (e @ self.axis) * self.axis
            if np.linalg.norm(v) > math.sin(math.radians(1.0)):
                return v / np.linalg.norm(v)
        raise AssertionError("unreachable")  # pragma: no cover


@dataclass(frozen=True, eq=False)
class Robot:
    """A serial 6R robot with a tool body: what :func:`read_robot` reads.

    Attributes
    ----------
    joint_names : tuple of str, length 6
        URDF names of the revolute joints, base to flange.
    joint_origin : ndarray, shape (6, 4, 4)
        Fixed transform from body ``i-1`` to joint ``i``'s frame at ``q_i = 0``.
    joint_axis : ndarray, shape (6, 3)
        Unit joint axes in the joint frames.
    flange_origin : ndarray, shape (4, 4)
        Body 6 frame to flange frame.
    lower_rad, upper_rad : ndarray, shape (6,)
        Joint limits, rad.
    link_mass_kg : ndarray, shape (6,)
    link_com_m : ndarray, shape (6, 3)
        Centres of mass in the body frames, m.
    link_inertia_kg_m2 : ndarray, shape (6, 3, 3)
        Inertias about the centres of mass, body axes.
    tool : ToolBody
    joint_stiffness_N_m_rad : ndarray, shape (6,), or None
    damping_ratio : ndarray, shape (6,), or None
        Per joint; a mode's damping ratio is the strain-energy-weighted mean (see
        :mod:`planner.robot.dynamics`).
    damping_N_m_s_rad : ndarray, shape (6,), or None
        Viscous joint damping instead of ``damping_ratio`` (one of the two).
    joint_sign, joint_offset_deg : ndarray, shape (6,)
        Controller angle = sign * URDF angle + offset (degrees); kinematics use URDF angles.
    correction : dict or None
        The calibrated residual correction (see :mod:`planner.robot.calibrate`), file key
        ``x_correction``.
    """

    urdf: str
    base_link: str
    flange_link: str
    joint_names: tuple
    joint_origin: np.ndarray
    joint_axis: np.ndarray
    flange_origin: np.ndarray
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    link_mass_kg: np.ndarray
    link_com_m: np.ndarray
    link_inertia_kg_m2: np.ndarray
    tool: ToolBody
    name: str | None = None
    file: str | None = None
    joint_stiffness_N_m_rad: np.ndarray | None = None
    damping_ratio: np.ndarray | None = None
    damping_N_m_s_rad: np.ndarray | None = None
    joint_sign: np.ndarray = field(default_factory=lambda: np.ones(N_JOINTS))
    joint_offset_deg: np.ndarray = field(default_factory=lambda: np.zeros(N_JOINTS))
    calibration: dict | None = None
    correction: dict | None = None

    def __post_init__(self):
        shapes = {"joint_origin": (6, 4, 4), "joint_axis": (6, 3), "flange_origin": (4, 4), "lower_rad": (6,),
                  "upper_rad": (6,), "link_mass_kg": (6,), "link_com_m": (6, 3), "link_inertia_kg_m2": (6, 3, 3),
                  "joint_sign": (6,), "joint_offset_deg": (6,)}
        for name, shape in shapes.items():
            object.__setattr__(self, name, _ro(np.asarray(getattr(self, name), float).reshape(shape)))
        for name in ("joint_stiffness_N_m_rad", "damping_ratio", "damping_N_m_s_rad"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _ro(np.asarray(value, float).reshape(6)))
        object.__setattr__(self, "joint_names", tuple(self.joint_names))

    def with_joints(self, **changes) -> "Robot":
        """A copy with some fields replaced (e.g. ``joint_stiffness_N_m_rad``)."""
        return replace(self, **changes)

    @property
    def has_stiffness(self) -> bool:
        return self.joint_stiffness_N_m_rad is not None

    def check_joints(self, q, *, file=None, field: str = "joints_deg", tol_rad: float = 1e-9) -> np.ndarray:
        """``q`` (rad, shape (6,) or (n, 6)) as an array; :class:`RobotError` naming the first
        joint outside its limits (``file``/``field`` go into the message)."""
        q = np.asarray(q, float)
        if q.shape[-1:] != (6,) or not np.all(np.isfinite(q)):
            raise RobotError(file, field, "6 finite joint angles", f"shape {q.shape}")
        bad = (q < self.lower_rad - tol_rad) | (q > self.upper_rad + tol_rad)
        if np.any(bad):
            idx = np.argwhere(bad)[0]
            j = int(idx[-1])
            value = float(q[tuple(idx)])
            raise RobotError(file, field, f"joint {j + 1} ({self.joint_names[j]}) within "
                             f"[{math.degrees(self.lower_rad[j]):.6g}, {math.degrees(self.upper_rad[j]):.6g}] deg",
                             f"{math.degrees(value):.6g} deg")
        return q

    def to_controller_deg(self, q_rad) -> np.ndarray:
        """URDF joint values (rad) to the controller's angles (deg): ``sign * deg + offset``."""
        return np.degrees(np.asarray(q_rad, float)) * self.joint_sign + self.joint_offset_deg

    def from_controller_deg(self, angles_deg) -> np.ndarray:
        """Controller angles (deg) to URDF joint values (rad)."""
        return np.radians((np.asarray(angles_deg, float) - self.joint_offset_deg) * self.joint_sign)

    def to_dict(self) -> dict:
        return robot_to_dict(self)


# --------------------------------------------------------------------------------------- URDF
def _rpy_matrix(rpy) -> np.ndarray:
    """URDF ``rpy``: fixed-axis roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _floats(text, n: int, file, where: str) -> np.ndarray:
    try:
        values = [float(x) for x in (text or "").split()]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise RobotError(file, where, f"{n} finite numbers", repr(text))
    return np.array(values)


def _origin(element, file, where: str) -> np.ndarray:
    t = np.eye(4)
    node = element.find("origin")
    if node is not None:
        t[:3, :3] = _rpy_matrix(_floats(node.get("rpy", "0 0 0"), 3, file, where + "/origin@rpy"))
        t[:3, 3] = _floats(node.get("xyz", "0 0 0"), 3, file, where + "/origin@xyz")
    return t


def _inertial(link, file) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Mass, centre of mass (link frame) and inertia about it (link axes) of a URDF link."""
    node = link.find("inertial")
    where = f"link[@name='{link.get('name')}']/inertial"
    if node is None:
        return None
    t = _origin(node, file, where)
    mass_node, inertia_node = node.find("mass"), node.find("inertia")
    if mass_node is None or inertia_node is None:
        raise RobotError(file, where, "<mass> and <inertia>", "one of them missing")
    mass = _floats(mass_node.get("value"), 1, file, where + "/mass@value")[0]
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    vals = [_floats(inertia_node.get(k, "0"), 1, file, where + f"/inertia@{k}")[0] for k in keys]
    ixx, ixy, ixz, iyy, iyz, izz = vals
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if mass < 0 or np.linalg.eigvalsh(inertia).min() < -1e-9 * max(1.0, abs(inertia).max()):
        raise RobotError(file, where, "mass >= 0 and a positive semi-definite inertia", f"mass {mass:g}")
    rot = t[:3, :3]
    return mass, t[:3, 3], rot @ inertia @ rot.T


def _lump(bodies: list[tuple[float, np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """Combine rigid bodies given in one frame: total mass, centre of mass, inertia about it
    (parallel-axis theorem)."""
    mass = sum(b[0] for b in bodies)
    if mass <= 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(b[0] * b[1] for b in bodies) / mass
    inertia = np.zeros((3, 3))
    for m, c, i in bodies:
        d = c - com
        inertia += i + m * ((d @ d) * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


def parse_urdf(path, base_link: str, flange_link: str, *, robot_file=None) -> dict:
    """The serial chain ``base_link -> flange_link`` of a URDF, as :class:`Robot` fields.

    Raises
    ------
    RobotError
        Unreadable XML; a link or joint missing; a path that is not a chain of exactly six
        revolute joints (fixed joints between them are allowed); a moving joint off the chain
        (the URDF is then not a serial chain); a moving link without ``<inertial>``.
    """
    file = os.fspath(path)
    try:
        root = ET.parse(file).getroot()
    except FileNotFoundError:
        raise RobotError(robot_file, "urdf", "an existing URDF file", f"no such file {file}") from None
    except (ET.ParseError, OSError) as exc:
        raise RobotError(file, "document", "URDF (XML)", str(exc)[:100]) from None
    if root.tag != "robot":
        raise RobotError(file, "document", "a <robot> element", f"<{root.tag}>")
    links = {link.get("name"): link for link in root.findall("link")}
    joints = root.findall("joint")
    by_child = {}
    for joint in joints:
        where = f"joint[@name='{joint.get('name')}']"
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise RobotError(file, where, "<parent link=...> and <child link=...>", "one missing")
        by_child[child.get("link")] = joint
    for name in (base_link, flange_link):
        if name not in links:
            raise RobotError(file, f"link[@name='{name}']", "the link named in the robot file", "no such link")
    path_joints = []
    link = flange_link
    while link != base_link:
        joint = by_child.get(link)
        if joint is None:
            raise RobotError(file, f"link[@name='{link}']",
                             f"a serial chain from '{base_link}' to '{flange_link}'", f"'{link}' has no parent joint")
        path_joints.append(joint)
        link = joint.find("parent").get("link")
        if len(path_joints) > len(joints):
            raise RobotError(file, "joint", "a tree (no loops)", "a loop of joints")
    path_joints.reverse()
    on_path = {j.get("name") for j in path_joints}
    chain_links = {base_link} | {j.find("child").get("link") for j in path_joints}
    for joint in joints:
        kind = joint.get("type")
        where = f"joint[@name='{joint.get('name')}']"
        if joint.get("name") in on_path:
            if kind not in ("revolute", "fixed"):
                raise RobotError(file, where, "a revolute (or fixed) joint", f"type '{kind}'")
        elif kind != "fixed" and joint.find("parent").get("link") in chain_links:
            raise RobotError(file, where, f"a serial chain from '{base_link}' to '{flange_link}' "
                             "(moving joints only on it)", f"a '{kind}' joint branching off it")
    revolute = [j for j in path_joints if j.get("type") == "revolute"]
    if len(revolute) != N_JOINTS:
        raise RobotError(file, f"chain {base_link} -> {flange_link}", "6 revolute joints",
                         f"{len(revolute)}")
    # walk the chain: accumulate fixed transforms, lump fixed links into their moving body
    children_fixed: dict[str, list] = {}
    for joint in joints:
        if joint.get("type") == "fixed" and joint.get("name") not in on_path:
            children_fixed.setdefault(joint.find("parent").get("link"), []).append(joint)

    def fixed_subtree(link_name, t):
        """Inertial bodies of ``link_name`` and links fixed to it off the chain, in the frame ``t``."""
        out = []
        inertial = _inertial(links[link_name], file) if link_name in links else None
        if inertial is not None:
            m, c, i = inertial
            out.append((m, t[:3, :3] @ c + t[:3, 3], t[:3, :3] @ i @ t[:3, :3].T))
        for joint in children_fixed.get(link_name, []):
            child = joint.find("child").get("link")
            out += fixed_subtree(child, t @ _origin(joint, file, f"joint[@name='{joint.get('name')}']"))
        return out

    origins, axes, lower, upper, names, masses, coms, inertias = [], [], [], [], [], [], [], []
    t = np.eye(4)  # current link frame relative to the current body frame
    body: list = []
    for joint in path_joints:
        name = joint.get("name")
        where = f"joint[@name='{name}']"
        t = t @ _origin(joint, file, where)
        child = joint.find("child").get("link")
        if joint.get("type") == "revolute":
            if origins:  # close the previous body
                masses_i = _lump(body)
                masses.append(masses_i[0]), coms.append(masses_i[1]), inertias.append(masses_i[2])
            origins.append(t)
            axis_node = joint.find("axis")
            axis = _floats(axis_node.get("xyz"), 3, file, where + "/axis@xyz") if axis_node is not None else np.array([1.0, 0, 0])
            if np.linalg.norm(axis) == 0:
                raise RobotError(file, where + "/axis@xyz", "a non-zero axis", "0 0 0")
            axes.append(axis / np.linalg.norm(axis))
            limit = joint.find("limit")
            if limit is None or limit.get("lower") is None or limit.get("upper") is None:
                raise RobotError(file, where + "/limit", "lower and upper limits (rad)", "none")
            lo = _floats(limit.get("lower"), 1, file, where + "/limit@lower")[0]
            hi = _floats(limit.get("upper"), 1, file, where + "/limit@upper")[0]
            if not lo < hi:
                raise RobotError(file, where + "/limit", "lower < upper", f"{lo:g} {hi:g}")
            lower.append(lo), upper.append(hi), names.append(name)
            if links.get(child) is None or links[child].find("inertial") is None:
                raise RobotError(file, f"link[@name='{child}']/inertial", "the mass and inertia of a moving link",
                                 "none")
            t = np.eye(4)
            body = fixed_subtree(child, t)
        else:
            body += [b for b in fixed_subtree(child, t)]
    m, c, i = _lump(body)
    masses.append(m), coms.append(c), inertias.append(i)
    return {"joint_names": tuple(names), "joint_origin": np.array(origins), "joint_axis": np.array(axes),
            "flange_origin": t, "lower_rad": np.array(lower), "upper_rad": np.array(upper),
            "link_mass_kg": np.array(masses), "link_com_m": np.array(coms),
            "link_inertia_kg_m2": np.array(inertias)}


# --------------------------------------------------------------------------------- robot.yaml
def read_robot(path) -> Robot:
    """Read a ``robomill-robot/1`` file and its URDF (formats.md "Robot").

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    Robot

    Raises
    ------
    RobotError
        Invalid YAML or field, or a URDF that is not a serial chain of six revolute joints from
        ``base_link`` to ``flange_link`` with inertias (see :func:`parse_urdf`); one line naming
        the file and the element.
    """
    root = load_yaml(path, error=RobotError)
    root.format(FORMAT)
    name = root.text("name")
    urdf_name = root.text("urdf", required=True)
    urdf = (Path(root.file).parent / urdf_name)
    base = root.text("base_link", required=True)
    flange = root.text("flange_link", required=True)
    tool_node = root.mapping_at("tool", required=True)
    tool = ToolBody(tip_m=tool_node.vector("tip_m", 3), axis=tool_node.direction("axis"),
                    mass_kg=tool_node.number("mass_kg", ge=0),
                    center_of_mass_m=tool_node.vector("center_of_mass_m", 3),
                    inertia_kg_m2=tool_node.matrix("inertia_kg_m2", (3, 3)))
    tool_node.done()
    inertia = tool.inertia_kg_m2
    if not np.allclose(inertia, inertia.T) or np.linalg.eigvalsh(inertia).min() < 0:
        tool_node.fail("inertia_kg_m2", "a symmetric positive semi-definite matrix", str(inertia.tolist()))
    kwargs: dict[str, Any] = {}
    joints = root.mapping_at("joints")
    if joints is not None:
        kwargs["joint_stiffness_N_m_rad"] = _positive6(joints, "stiffness_N_m_rad")
        zeta = joints.vector("damping_ratio", 6, required=False)
        c = joints.vector("damping_N_m_s_rad", 6, required=False)
        if zeta is not None and c is not None:
            joints.fail("damping_ratio", "one of damping_ratio and damping_N_m_s_rad", "both")
        if zeta is not None and not np.all((zeta >= 0) & (zeta < 1)):
            joints.fail("damping_ratio", "six ratios in [0, 1)", str(zeta.tolist()))
        if c is not None and not np.all(c >= 0):
            joints.fail("damping_N_m_s_rad", "six values >= 0", str(c.tolist()))
        kwargs["damping_ratio"], kwargs["damping_N_m_s_rad"] = zeta, c
        joints.done()
    sign = root.vector("joint_sign", 6, required=False)
    if sign is not None:
        if not np.all(np.abs(sign) == 1):
            root.fail("joint_sign", "six values +1 or -1", str(sign.tolist()))
        kwargs["joint_sign"] = sign
    offset = root.vector("joint_offset_deg", 6, required=False)
    if offset is not None:
        kwargs["joint_offset_deg"] = offset
    calibration = root.mapping_at("calibration")
    if calibration is not None:
        kwargs["calibration"] = dict(calibration.mapping)
    correction = root.raw("x_correction", required=False)
    if isinstance(correction, dict):
        kwargs["correction"] = _parse_correction(correction, root)
    root.done()
    chain = parse_urdf(urdf, base, flange, robot_file=root.file)
    return Robot(urdf=str(urdf), base_link=base, flange_link=flange, tool=tool, name=name, file=root.file,
                 **chain, **kwargs)


def _positive6(node, key):
    value = node.vector(key, 6, required=False)
    if value is not None and not np.all(value > 0):
        node.fail(key, "six stiffnesses > 0", str(value.tolist()))
    return value


def _parse_correction(mapping: dict, root) -> dict:
    """The residual correction written by ``robot calibrate`` (see :mod:`.calibrate`)."""
    from .calibrate import parse_correction

    return parse_correction(mapping, root)


def robot_to_dict(robot: Robot, *, urdf: str | None = None) -> dict:
    """The ``robomill-robot/1`` mapping (``urdf`` as given, default the URDF path as read)."""
    out: dict[str, Any] = {"format": FORMAT}
    if robot.name:
        out["name"] = robot.name
    out["urdf"] = urdf if urdf is not None else robot.urdf
    out["base_link"], out["flange_link"] = robot.base_link, robot.flange_link
    t = robot.tool
    out["tool"] = {"tip_m": t.tip_m.tolist(), "axis": t.axis.tolist(), "mass_kg": t.mass_kg,
                   "center_of_mass_m": t.center_of_mass_m.tolist(), "inertia_kg_m2": t.inertia_kg_m2.tolist()}
    if robot.joint_stiffness_N_m_rad is not None:
        joints: dict[str, Any] = {"stiffness_N_m_rad": robot.joint_stiffness_N_m_rad.tolist()}
        if robot.damping_ratio is not None:
            joints["damping_ratio"] = robot.damping_ratio.tolist()
        if robot.damping_N_m_s_rad is not None:
            joints["damping_N_m_s_rad"] = robot.damping_N_m_s_rad.tolist()
        out["joints"] = joints
    if np.any(robot.joint_sign != 1):
        out["joint_sign"] = robot.joint_sign.tolist()
    if np.any(robot.joint_offset_deg != 0):
        out["joint_offset_deg"] = robot.joint_offset_deg.tolist()
    if robot.calibration is not None:
        out["calibration"] = plain(dict(robot.calibration))
    if robot.correction is not None:
        out["x_correction"] = plain(dict(robot.correction))
    return out


def write_robot(robot: Robot, path) -> Path:
    """Write ``robot`` as a ``robomill-robot/1`` file, atomically; the URDF path and the
    calibration's model files are written relative to the new file's directory when possible.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    target = Path(os.fspath(path))

    def relative(file) -> str:  # formats.md: paths in a robot file are relative to it
        try:
            return os.path.relpath(Path(file).resolve(), target.resolve().parent)
        except ValueError:  # another drive (Windows)
            return str(Path(file).resolve())

    doc = robot_to_dict(robot, urdf=relative(robot.urdf))
    calibration = doc.get("calibration") or {}
    if isinstance(calibration.get("models"), list):
        # the models named as the calibration was given them (relative to the working directory)
        calibration["models"] = [relative(m) if isinstance(m, str) and Path(m).is_file() else m
                                 for m in calibration["models"]]
    text = dump_yaml(doc)
    with atomic_write(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return target

