"""One chunk of the atlas: a pure function of plain inputs (positions -> table columns).

For every tool-tip position of the chunk and every tool rotation of the problem (rows in that
order: position-major, rotation-minor):

1. **Inverse kinematics** (:func:`planner.robot.ik.inverse_kinematics`, every closed-form branch):
   the tool tip at the position, the tool axis along the setup's ``a = f x n``, the flange turned by
   the rotation from the feed direction. **Branch rule**: among the branches inside the joint
   limits, the one farthest from them (largest smallest distance of a joint to its limits, rad;
   ties: the lower branch number). ``reachable`` says that such a branch exists; its distance to
   the joint limits (deg) and its singularity measure (inverse condition number of the tool-tip
   Jacobian, :func:`planner.robot.ik.singularity_measure`) are reported, and a pose whose measure is
   below ``singularity_threshold`` is ``near_singularity`` and gets no cut (its Jacobian, and so
   its tool-tip modes, cannot be trusted).
2. **The robot's tool-tip modes** at that pose (:func:`planner.robot.robot_modes`, compliant joints,
   rigid links), optionally with pose-independent spindle/tool modes in series. Modes whose tool-tip
   compliance is below ``min_tip_fraction`` of the largest are left out (they cannot set a limit
   within the depth range). Reported: the lowest tool-tip mode and the most compliant one.
3. **Stability over the speed range** (zero-order approximation, Altintas & Budak, CIRP Annals
   44(1), 1995, the method of ``robomill predict``): the lobe envelope on ``rpm_grid``
   (:mod:`planner.atlas._kernel`: the log chatter-frequency grid plus lines around every mode,
   lobe onsets included), and its smallest value over the range (``min_depth_limit_m``: the depth
   stable at every speed of the grid; never above the exact limit at the chosen speed).
4. **The best stable removal rate** under the setup's limits: ``MRR = ap ae fz N n / 60`` with
   ``fz`` fixed at the feed bound (MRR grows with ``fz`` under every constraint used here: the
   stability limit does not depend on it, and the mean torque, power and peak force grow slower
   than ``fz`` at the depth they allow; see :func:`planner.atlas.problem.build_problem`), and
   ``ap = min(depth bound, force bound, torque bound, power bound(n), margin x limit(n))`` at each
   speed of the grid; the speed with the largest rate (ties: the largest stability reserve). The
   limit at that speed, and at up to three others whose rate is within 5 % of it where stability
   may bind, is then solved exactly (as :func:`stability.lobes.predict_point`), the best of them by
   the exact limit kept, and ``ap`` recomputed with it.

The surface location error is not part of the atlas (it needs the forced response per pose and
speed; ``robomill check --robot`` gives it along a toolpath). Everything is vectorised over the
chunk, and every row depends only on its own position and rotation (so the table does not depend
on how the points are cut into chunks: tested bit for bit).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["evaluate_chunk", "COLUMNS", "CONSTRAINT_NAMES"]

#: ``active_constraint`` codes of the kernel.
CONSTRAINT_NAMES = {-1: "none_feasible", 0: "stability", 1: "depth_max", 2: "force", 3: "torque", 4: "power",
                    -2: "unreachable", -3: "near_singularity"}

#: Columns of one chunk's result, in table order (positions are added by the caller).
COLUMNS = ("rotation_deg", "reachable", "near_singularity", "branch", "q1_deg", "q2_deg", "q3_deg", "q4_deg",
           "q5_deg", "q6_deg", "joint_limit_distance_deg", "singularity_measure", "lowest_mode_hz",
           "lowest_mode_stiffness_N_m", "lowest_mode_damping_ratio", "dominant_mode_hz",
           "dominant_mode_stiffness_N_m", "min_depth_limit_m", "spindle_rpm", "depth_limit_m",
           "chatter_frequency_hz", "axial_depth_m", "feed_per_tooth_m", "mrr_m3_s", "mean_torque_N_m",
           "power_W", "stability_reserve", "active_constraint")


def _choose_branch(robot, sol):
    """Per target: the valid branch farthest from the joint limits (-1: none); its q (NaN: none)."""
    q = sol.q  # (n, 8, 6)
    dist = np.minimum(q - robot.lower_rad, robot.upper_rad - q).min(axis=2)  # (n, 8), NaN unreachable
    dist = np.where(sol.valid, dist, -np.inf)
    branch = np.argmax(dist, axis=1)  # first maximum: the lower branch number on ties
    ok = np.isfinite(dist[np.arange(dist.shape[0]), branch])
    branch = np.where(ok, branch, -1)
    chosen = np.full((q.shape[0], 6), np.nan)
    chosen[ok] = q[np.flatnonzero(ok), branch[ok]]
    return branch, chosen


def _structures(problem, modes):
    """Kernel inputs from the robot modes at ``n`` poses (plus the tool modes in series)."""
    fn, zeta, stiff, dirs = modes.frequency_hz, modes.damping_ratio, modes.stiffness_N_m, modes.directions
    if problem.tool_modes is not None:
        t = problem.tool_modes
        n = fn.shape[0]
        fn = np.hstack([fn, np.broadcast_to(t["frequency_hz"], (n, t["frequency_hz"].size))])
        zeta = np.hstack([zeta, np.broadcast_to(t["damping_ratio"], (n, t["frequency_hz"].size))])
        stiff = np.hstack([stiff, np.broadcast_to(t["stiffness_N_m"], (n, t["frequency_hz"].size))])
        dirs = np.concatenate([dirs, np.broadcast_to(t["directions"], (n,) + t["directions"].shape)], axis=1)
    with np.errstate(divide="ignore"):
        compliance = np.where(np.isfinite(stiff), 1.0 / stiff, 0.0)
    keep = compliance >= problem.min_tip_fraction * compliance.max(axis=1, keepdims=True)
    stiff = np.where(keep, stiff, np.inf)
    zeta = np.maximum(zeta, 1e-6)
    v = np.einsum("ij,nmj->nmi", problem.cut_frame, dirs)  # mode directions in the cut frame
    w = np.einsum("nmi,jl,nmj->nmil", v[:, :, :2], problem.b0, v)
    w = np.where(keep[:, :, None, None], w, 0.0)
    f_lo = np.where(keep, fn, np.inf).min(axis=1) / 3.0
    f_hi = np.where(keep, fn, 0.0).max(axis=1) * 3.0
    return (np.ascontiguousarray(fn), np.ascontiguousarray(zeta), np.ascontiguousarray(stiff),
            np.ascontiguousarray(w), np.zeros((fn.shape[0], 2, 2)), f_lo, f_hi)


def evaluate_chunk(problem, positions_m) -> dict[str, np.ndarray]:
    """The atlas columns of ``positions_m`` x ``problem.rotations_rad``.

    Parameters
    ----------
    problem : planner.atlas.problem.AtlasProblem
        Robot, cut, limits and options (plain, picklable).
    positions_m : array_like, shape (m, 3)
        Tool-tip positions, machine frame, m.

    Returns
    -------
    dict of str to ndarray
        :data:`COLUMNS`, each of length ``m * n_rotations`` (position-major).
    """
    from planner.robot import robot_modes
    from planner.robot.ik import inverse_kinematics, singularity_measure

    from ._kernel import atlas_kernel

    robot = problem.robot
    pos = np.asarray(positions_m, float).reshape(-1, 3)
    n_rot = problem.rotations_rad.size
    rows = pos.shape[0] * n_rot
    p = np.repeat(pos, n_rot, axis=0)
    rho = np.tile(problem.rotations_rad, pos.shape[0])
    out = {name: np.full(rows, np.nan) for name in COLUMNS}
    out["rotation_deg"] = np.degrees(rho)
    out["feed_per_tooth_m"] = np.full(rows, problem.feed_per_tooth_m)
    code = np.full(rows, -2, dtype=np.int64)

    sol = inverse_kinematics(robot, p, problem.tool_axis, rho, problem.feed_direction)
    branch, q = _choose_branch(robot, sol)
    reach = branch >= 0
    out["reachable"] = reach
    out["branch"] = branch.astype(np.int8)
    for j in range(6):
        out[f"q{j + 1}_deg"] = np.degrees(q[:, j])
    idx = np.flatnonzero(reach)
    near = np.zeros(rows, dtype=bool)
    if idx.size:
        qr = q[idx]
        out["joint_limit_distance_deg"][idx] = np.degrees(np.minimum(qr - robot.lower_rad,
                                                                     robot.upper_rad - qr).min(axis=1))
        sing = singularity_measure(robot, qr)
        out["singularity_measure"][idx] = sing
        near[idx] = sing < problem.singularity_threshold
        code[idx[near[idx]]] = -3
    out["near_singularity"] = near
    use = np.flatnonzero(reach & ~near)
    if use.size:
        modes = robot_modes(robot, q[use])
        compliance = modes.compliance_m_N
        tip = compliance >= problem.min_tip_fraction * compliance.max(axis=1, keepdims=True)
        low = np.argmax(tip, axis=1)  # modes ascend in frequency: the first that moves the tip
        dom = np.argmax(compliance, axis=1)
        r = np.arange(use.size)
        out["lowest_mode_hz"][use] = modes.frequency_hz[r, low]
        out["lowest_mode_stiffness_N_m"][use] = modes.stiffness_N_m[r, low]
        out["lowest_mode_damping_ratio"][use] = modes.damping_ratio[r, low]
        out["dominant_mode_hz"][use] = modes.frequency_hz[r, dom]
        out["dominant_mode_stiffness_N_m"][use] = modes.stiffness_N_m[r, dom]

        g = use.size
        res = [np.empty(g) for _ in range(5)] + [np.empty(g, dtype=np.int64), np.empty((0, 0))]
        atlas_kernel()(*_structures(problem, modes), float(problem.teeth), int(problem.n_freq), problem.rpm_grid,
                       problem.ap_lo_m, problem.ap_hi_m, int(problem.ap_hi_code), problem.power_depth_rpm,
                       problem.margin, *res)
        env_min, rpm, ap, limit, fc, kcode = res[:6]
        ok = kcode >= 0
        out["min_depth_limit_m"][use] = env_min
        out["spindle_rpm"][use] = rpm
        out["depth_limit_m"][use] = limit
        out["chatter_frequency_hz"][use] = fc
        ap = np.where(ok, ap, np.nan)
        out["axial_depth_m"][use] = ap
        out["mrr_m3_s"][use] = problem.mrr_per_depth_rpm * ap * rpm
        torque = problem.torque_per_depth_N * ap
        out["mean_torque_N_m"][use] = torque
        out["power_W"][use] = 2.0 * math.pi * rpm / 60.0 * torque
        out["stability_reserve"][use] = problem.margin * limit / ap
        code[use] = kcode
    out["active_constraint"] = code.astype(np.int8)
    return out
