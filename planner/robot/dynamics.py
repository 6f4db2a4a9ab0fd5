"""Dynamics at a pose: the joint-space mass matrix, the eigenproblem of the compliant-joint arm,
and the tool-tip modal model (formats.md "Robot"), vectorised over many poses.

Model (Dumas et al., RCIM 27, 2011; Mousavi et al., CIRP JMST 2018): rigid links, compliant joints,
``M(q) q'' + C q' + K q = J(q)^T F``, ``K = diag(k_j)`` N m/rad. The tool-tip receptance is
``G(w) = J_v (K - w^2 M + i w C)^-1 J_v^T``. With ``B = K^-1/2 M K^-1/2 = Y diag(mu) Y^T`` the
mass-normalised mode shapes are ``phi_r = K^-1/2 y_r / sqrt(mu_r)`` and ``w_r^2 = 1 / mu_r``
(no Cholesky needed as ``K`` is diagonal; one batched ``eigh`` of 6x6 matrices). A mode of the
tool tip has ``direction = J_v phi / |J_v phi|`` and ``stiffness_N_m = w_r^2 / |J_v phi|^2``.

Damping. ``damping_ratio`` is given per joint (the loss of each joint's drive and bearing); a
mode's damping ratio is the strain-energy-weighted mean of the joints', ``zeta_r = sum_j zeta_j
k_j phi_jr^2 / w_r^2`` (the modal strain energy method, Johnson & Kienholz, AIAA J. 20(9), 1982),
and ``C = M Phi diag(2 zeta_r w_r) Phi^T M`` is the classically damped matrix with exactly those
modes. ``damping_N_m_s_rad`` gives ``C = diag(c_j)`` instead; its modes then carry
``zeta_r = phi_r^T C phi_r / (2 w_r)`` (the diagonal of the modal damping matrix; exact for light
damping with well-separated modes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma._arrays import readonly as _ro
from oma.modal import ModalModel, in_series

from .description import Robot, RobotError
from .kinematics import _cross, as_poses, link_frames

__all__ = ["body_inertias", "mass_matrix", "RobotModes", "robot_modes", "damping_matrix", "robot_modal_model",
           "direct_receptance"]


def body_inertias(robot: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass (6,), centre of mass (6, 3) and inertia about it (6, 3, 3) of the six moving bodies in
    their own frames, the tool body lumped into body 6 (parallel-axis theorem)."""
    from .description import _lump

    mass = robot.link_mass_kg.copy()
    com = robot.link_com_m.copy()
    inertia = robot.link_inertia_kg_m2.copy()
    t = robot.flange_origin
    tool = robot.tool
    tool_body = (tool.mass_kg, t[:3, :3] @ tool.center_of_mass_m + t[:3, 3],
                 t[:3, :3] @ tool.inertia_kg_m2 @ t[:3, :3].T)
    mass[5], com[5], inertia[5] = _lump([(mass[5], com[5], inertia[5]), tool_body])
    return mass, com, inertia


def mass_matrix(robot: Robot, q) -> np.ndarray:
    """Joint-space mass matrix of the links and the tool body.

    ``M = sum_b m_b Jc_b^T Jc_b + Jw_b^T (R_b I_b R_b^T) Jw_b`` over the six bodies, ``Jc_b`` the
    Jacobian of body ``b``'s centre of mass, ``Jw_b`` its angular-velocity Jacobian (Siciliano et
    al. 2009, sec. 7.2).

    Parameters
    ----------
    robot : Robot
    q : array_like, shape (6,) or (n, 6)
        rad.

    Returns
    -------
    ndarray, shape (n, 6, 6)
        kg m^2 (N m s^2/rad).
    """
    return _mass_matrix(robot, *link_frames(robot, q))


def mass_and_jacobian(robot: Robot, q) -> tuple[np.ndarray, np.ndarray]:
    """Mass matrix (n, 6, 6) and tool-tip translational Jacobian (n, 3, 6) at real poses ``q``
    (rad), from the compiled kernel (:mod:`._dyn_kernel`); the same as :func:`mass_matrix` and
    ``tip_jacobian(robot, q)[:, :3]``, several times faster."""
    from ._dyn_kernel import mass_and_tip_jacobian
    from .kinematics import _canonical

    q = np.ascontiguousarray(as_poses(q), dtype=float)
    rots, offs, ps = _canonical(robot)
    mass, com, inertia = body_inertias(robot)
    t = robot.flange_origin
    tip = t[:3, :3] @ robot.tool.tip_m + t[:3, 3]
    m = np.empty((q.shape[0], 6, 6))
    jv = np.empty((q.shape[0], 3, 6))
    mass_and_tip_jacobian(q, rots, offs, ps, mass, com, inertia, tip, m, jv)
    return m, jv


def _mass_matrix(robot: Robot, rot, pos) -> np.ndarray:
    mass, com, inertia = body_inertias(robot)
    n = rot.shape[0]
    z = np.einsum("nijk,ik->nij", rot, robot.joint_axis)
    # Composite rigid bodies (Featherstone, Rigid Body Dynamics Algorithms, 2008, ch. 6), world
    # frame: composite j = bodies j..6, its mass, centre of mass and inertia about it.
    m_c = 0.0
    c_c = np.zeros((n, 3), dtype=rot.dtype)
    i_c = np.zeros((n, 3, 3), dtype=rot.dtype)
    eye = np.eye(3)
    out = np.empty((n, 6, 6), dtype=rot.dtype)
    for j in range(5, -1, -1):
        r = rot[:, j]
        c_b = pos[:, j] + r @ com[j]
        i_b = r @ inertia[j] @ np.swapaxes(r, -1, -2)
        m_new = m_c + mass[j]
        c_new = (m_c * c_c + mass[j] * c_b) / m_new if m_new > 0 else c_b
        i_new = i_c + i_b
        for mm, cc in ((m_c, c_c), (mass[j], c_b)):
            d = cc - c_new
            i_new = i_new + mm * (np.sum(d * d, axis=-1)[:, None, None] * eye - d[:, :, None] * d[:, None, :])
        m_c, c_c, i_c = m_new, c_new, i_new
        force = m_c * _cross(z[:, j], c_c - pos[:, j])  # unit acceleration of joint j
        moment = np.einsum("nab,nb->na", i_c, z[:, j])
        for i in range(j + 1):
            tau = np.einsum("na,na->n", z[:, i], moment + _cross(c_c - pos[:, i], force))
            out[:, i, j] = out[:, j, i] = tau
    m = out
    return 0.5 * (m + np.swapaxes(m, -1, -2))


@dataclass(frozen=True, eq=False)
class RobotModes:
    """The compliant-joint modes at ``n`` poses, ascending frequency.

    Attributes
    ----------
    frequency_hz : ndarray, shape (n, 6)
    damping_ratio : ndarray, shape (n, 6)
    stiffness_N_m : ndarray, shape (n, 6)
        Tool-tip modal stiffness ``w_r^2 / |J_v phi_r|^2`` (inf for a mode that does not move the tip).
    directions : ndarray, shape (n, 6, 3)
        Unit tool-tip directions (sign: largest component positive).
    shapes : ndarray, shape (n, 6, 6)
        Mass-normalised joint-space mode shapes, ``shapes[:, :, r]`` is mode ``r``.
    tip_motion : ndarray, shape (n, 6, 3)
        ``J_v phi_r``, m per unit modal coordinate.
    joints_rad : ndarray, shape (n, 6), optional
        The poses.
    """

    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    stiffness_N_m: np.ndarray
    directions: np.ndarray
    shapes: np.ndarray
    tip_motion: np.ndarray
    joints_rad: np.ndarray | None = None

    def __post_init__(self):
        for name in ("frequency_hz", "damping_ratio", "stiffness_N_m", "directions", "shapes", "tip_motion"):
            object.__setattr__(self, name, _ro(np.asarray(getattr(self, name))))
        if self.joints_rad is not None:
            object.__setattr__(self, "joints_rad", _ro(self.joints_rad))

    @property
    def n_poses(self) -> int:
        return int(self.frequency_hz.shape[0])

    def model(self, i: int, *, min_tip_fraction: float = 1e-9, source: dict | None = None) -> ModalModel:
        """The tool-tip :class:`~oma.modal.ModalModel` at pose ``i`` (``joints_deg`` filled when
        the poses are known); modes whose tip compliance is below ``min_tip_fraction`` of the
        largest are left out (they do not move the tool tip)."""
        compliance = self.compliance_m_N[i]
        keep = compliance >= min_tip_fraction * compliance.max()
        return ModalModel(natural_frequency_hz=self.frequency_hz[i, keep],
                          damping_ratio=np.maximum(self.damping_ratio[i, keep], 1e-6),
                          stiffness_N_m=self.stiffness_N_m[i, keep], directions=self.directions[i, keep],
                          joints_deg=None if self.joints_rad is None else np.degrees(self.joints_rad[i]),
                          source=source)

    @property
    def compliance_m_N(self) -> np.ndarray:
        """Tool-tip modal compliance ``1 / k_r``, shape (n, 6), m/N."""
        return np.sum(self.tip_motion**2, axis=-1) / (2 * np.pi * self.frequency_hz) ** 2

    def dominant(self) -> np.ndarray:
        """Index of the most compliant tool-tip mode at each pose, shape (n,)."""
        return np.argmax(self.compliance_m_N, axis=1)

    def to_dict(self) -> dict:
        return {"frequency_hz": self.frequency_hz.tolist(), "damping_ratio": self.damping_ratio.tolist(),
                "stiffness_N_m": self.stiffness_N_m.tolist(), "directions": self.directions.tolist()}


def _stiffness(robot: Robot, q, stiffness) -> np.ndarray:
    """Joint stiffness per pose, shape (n, 6): given, else the robot's with its correction."""
    if stiffness is not None:
        return np.broadcast_to(np.asarray(stiffness, float), (q.shape[0], 6))
    if robot.joint_stiffness_N_m_rad is None:
        raise RobotError(robot.file, "joints.stiffness_N_m_rad", "joint stiffness (a calibrated robot: "
                         "robomill robot calibrate)", "none")
    from .correction import corrected_stiffness

    return corrected_stiffness(robot, q)


def robot_modes(robot: Robot, q, *, stiffness=None, masses=None) -> RobotModes:
    """Eigen-solution of the compliant-joint arm at many poses at once.

    Parameters
    ----------
    robot : Robot
    q : array_like, shape (6,) or (n, 6)
        rad.
    stiffness : array_like, shape (6,) or (n, 6), optional
        Joint stiffness, N m/rad (default: the robot's, with its calibrated correction).
    masses : ndarray, shape (n, 6, 6), optional
        ``mass_matrix(robot, q)`` when already computed.

    Returns
    -------
    RobotModes
    """
    q = as_poses(q)
    k = _stiffness(robot, q, stiffness)
    m, jv = mass_and_jacobian(robot, q)
    if masses is not None:
        m = masses
    s = 1.0 / np.sqrt(k)  # K^-1/2
    b = s[:, :, None] * m * s[:, None, :]
    mu, y = np.linalg.eigh(b)  # ascending mu = 1/w^2 -> descending frequency
    mu, y = mu[:, ::-1], y[:, :, ::-1]
    omega = 1.0 / np.sqrt(mu)
    phi = s[:, :, None] * y / np.sqrt(mu)[:, None, :]
    tip = np.einsum("nij,njr->nri", jv, phi)  # (n, 6, 3)
    amp2 = np.sum(tip**2, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        stiff = np.where(amp2 > 0, omega**2 / amp2, np.inf)
        directions = tip / np.sqrt(amp2)[:, :, None]
    directions = np.nan_to_num(directions)
    big = np.take_along_axis(directions, np.argmax(np.abs(directions), axis=-1)[..., None], axis=-1)
    directions = directions * np.where(big < 0, -1.0, 1.0)
    if robot.damping_N_m_s_rad is not None:
        zeta = np.einsum("j,njr->nr", robot.damping_N_m_s_rad, phi**2) / (2 * omega)
    elif robot.damping_ratio is not None:
        zeta = np.einsum("j,nj,njr->nr", robot.damping_ratio, k, phi**2) / omega**2
    else:
        zeta = np.zeros_like(omega)
    return RobotModes(omega / (2 * np.pi), zeta, stiff, directions, phi, tip, joints_rad=q)


def damping_matrix(robot: Robot, q, *, stiffness=None) -> np.ndarray:
    """Joint-space damping matrix ``C`` (n, 6, 6), N m s/rad, as the module docstring states."""
    q = as_poses(q)
    if robot.damping_N_m_s_rad is not None:
        return np.broadcast_to(np.diag(robot.damping_N_m_s_rad), (q.shape[0], 6, 6)).copy()
    m = mass_matrix(robot, q)
    modes = robot_modes(robot, q, stiffness=stiffness, masses=m)
    w = 2 * np.pi * modes.frequency_hz
    mp = m @ modes.shapes
    return np.einsum("nir,nr,njr->nij", mp, 2 * modes.damping_ratio * w, mp)


def direct_receptance(robot: Robot, q, freq_hz, *, stiffness=None) -> np.ndarray:
    """``G(w) = J_v (K - w^2 M + i w C)^-1 J_v^T`` at one pose, shape (3, 3, n_freq), m/N
    (a direct solve, the reference the modal model is checked against)."""
    from .kinematics import tip_jacobian

    q = as_poses(q)[:1]
    k = _stiffness(robot, q, stiffness)[0]
    m = mass_matrix(robot, q)[0]
    c = damping_matrix(robot, q, stiffness=stiffness)[0]
    jv = tip_jacobian(robot, q)[0, :3]
    w = 2 * np.pi * np.atleast_1d(np.asarray(freq_hz, float))
    dyn = np.diag(k)[None] - w[:, None, None] ** 2 * m[None] + 1j * w[:, None, None] * c[None]
    g = jv[None] @ np.linalg.solve(dyn, np.broadcast_to(jv.T, (w.size, 6, 3)))
    return np.moveaxis(g, 0, -1)


def robot_modal_model(robot: Robot, q, *, tool_model: ModalModel | None = None, stiffness=None,
                      min_tip_fraction: float = 1e-9, check_limits: bool = True) -> ModalModel:
    """The tool-tip modal model (``robomill-modal/1``) at one pose.

    Parameters
    ----------
    robot : Robot
        With joint stiffness (a calibrated robot).
    q : array_like, shape (6,)
        Joint angles, rad.
    tool_model : ModalModel, optional
        Pose-independent spindle/tool modes, combined in series (receptances add).
    stiffness : array_like, shape (6,), optional
        Joint stiffness overriding the robot's, N m/rad.
    min_tip_fraction : float, optional
        Modes whose tool-tip compliance is below this fraction of the largest are left out (a
        mode that turns the tool about its own tip does not move it).
    check_limits : bool, optional
        Raise :class:`RobotError` for a pose outside the joint limits (default).

    Returns
    -------
    ModalModel
        ``joints_deg`` filled; ``source = {method: robot-model, robot: name}``.
    """
    q = np.asarray(q, float).reshape(6)
    if check_limits:
        robot.check_joints(q)
    modes = robot_modes(robot, q, stiffness=stiffness)
    model = modes.model(0, min_tip_fraction=min_tip_fraction,
                        source={"method": "robot-model", "robot": robot.name or robot.file})
    if tool_model is not None:
        model = in_series(model, tool_model, joints_deg=np.degrees(q), source=model.source)
    return model

