"""Analytic inverse kinematics of Universal Robots arms, verified with Pinocchio.

UR arms have no spherical wrist, but their DH geometry (α = π/2, 0, 0, π/2, −π/2, 0; a1 = a4 = a5 = a6 = 0;
joints 2-4 parallel) has a closed form with eight branches (Hawkins 2013, "Analytic inverse kinematics for
the Universal Robots UR-5/UR-10 arms"; the same derivation as ``ur_kinematics``). In the notation of
:mod:`ftacq.kinematics` (standard DH, ``T_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(α_i)``), with ``z_k`` the z axis of DH
frame ``k``:

1. Shoulder (q1). Joints 2-4 turn about ``z_1 = (sin q1, −cos q1, 0)``; the only offset along it between joint 2
   and the wrist-2 centre ``p_5 = p_6 − d6 z_6`` is ``d4``, so ``p_5 · z_1 = d4``, i.e.
   ``r sin(q1 − ψ) = d4`` with ``(r, ψ)`` the polar coordinates of ``p_5`` in the base xy plane:
   ``q1 = ψ + asin(d4/r)`` (shoulder branch +1) or ``ψ + π − asin(d4/r)`` (branch −1). Needs ``r > d4``.
2. Wrist 2 (q5). ``z_6 · z_1 = cos q5``: ``q5 = ±acos(z_6 · z_1)`` (wrist branch = sign of sin q5).
   ``sin q5 = 0`` is the wrist singularity (z_6 parallel to joints 2-4: q4 and q6 are not separable).
3. Wrist 3 (q6). In flange coordinates, ``w = flange_R_base z_1 = (s5 c6, −s5 s6, c5)``: ``q6 = atan2(−w_y/s5, w_x/s5)``.
4. Planar 3R (q2, q3, q4). ``T14 = A1⁻¹ T06 A6⁻¹ A5⁻¹ = A2 A3 A4``; its origin is ``(x, y, d4)`` with
   ``x + i y = (a2 + a3 e^{i q3}) e^{i q2}``: ``cos q3 = (x² + y² − a2² − a3²) / (2 a2 a3)`` (elbow branch =
   sign of sin q3; ``sin q3 = 0`` is the stretched/folded elbow singularity),
   ``q2 = atan2(y, x) − atan2(a3 s3, a2 + a3 c3)``, ``q4 = atan2(T14[1,0], T14[0,0]) − q2 − q3``.

Each branch is then mapped joint by joint to the 2π-equivalent value nearest a reference configuration
within the joint limits less the planning margin (:data:`ftacq.kinematics.JOINT_LIMIT_MARGIN_RAD`), refined by a few Gauss-Newton steps on Pinocchio's FK (``pin.log6`` error, local
Jacobian) and verified to :data:`IK_TOLERANCE`. :func:`solve_ik` keeps the branch of the previous
configuration: a change of shoulder, elbow or wrist branch between consecutive poses means passing a
singularity (a wrist flip, for instance), which the planner refuses.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ftacq.kinematics.pinocchio_models import FLANGE_FRAME, pinocchio_model
from ftacq.kinematics.ur import (
    URModel,
    dh_step,
    dh_transforms,
    dh_transforms_batch,
    forward_kinematics,
    planning_limits_rad,
)
from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation

TWO_PI = 2.0 * np.pi

IK_TOLERANCE = 1e-10
"""Maximum ‖log6(target⁻¹ · FK(q))‖ (m / rad) accepted for an IK solution."""
IK_REFINE_ITERATIONS = 5
"""Gauss-Newton iterations on Pinocchio's FK (the closed form is already at ~1e-15 away from singularities)."""
WRIST_SINGULAR_SIN_Q5 = 0.1
"""|sin q5| below this (q5 within ≈5.7° of 0 or π) is too close to the wrist singularity."""
ELBOW_SINGULAR_SIN_Q3 = 0.05
"""|sin q3| below this (elbow within ≈2.9° of stretched or folded) is too close to the elbow singularity."""
SHOULDER_SINGULAR_MARGIN = 0.02
"""(r − d4)/r below this: the wrist centre is nearly on the shoulder's offset cylinder (shoulder singularity)."""


@dataclass(frozen=True)
class Branch:
    """One of the eight IK branches: each field is +1 or −1.

    shoulder: sign of cos(q1 − ψ) (which side of the wrist centre the shoulder offset lies).
    elbow: sign of sin q3. wrist: sign of sin q5.
    """

    shoulder: int
    elbow: int
    wrist: int

    def __str__(self) -> str:
        sign = {1: "+", -1: "-"}
        return f"shoulder {sign[self.shoulder]}, elbow {sign[self.elbow]}, wrist {sign[self.wrist]}"

    @staticmethod
    def all() -> tuple["Branch", ...]:
        """Return the eight branches."""
        return tuple(Branch(s, e, w) for s in (1, -1) for e in (1, -1) for w in (1, -1))


@dataclass(frozen=True)
class IKResult:
    """The outcome of :func:`solve_ik`: ``q_rad`` (6,) and its ``branch``, or ``reason`` why there is none."""

    q_rad: np.ndarray | None
    branch: Branch | None
    reason: str = ""

    @property
    def ok(self) -> bool:
        """Return True when a solution was found."""
        return self.q_rad is not None


def _sign(x: float) -> int:
    return 1 if x >= 0.0 else -1


def _as_transform(pose_or_transform: np.ndarray) -> np.ndarray:
    """Accept a flange pose [x, y, z, rx, ry, rz] or a 4×4 base_T_flange; return the 4×4."""
    arr = np.asarray(pose_or_transform, dtype=float)
    if arr.shape == (4, 4):
        return arr
    if arr.shape != (6,):
        raise ValueError(f"expected a pose (6,) or a transform (4, 4), got shape {arr.shape}")
    return _as_transforms(arr[None])[0]


def _as_transforms(poses_or_transforms: np.ndarray) -> np.ndarray:
    """Accept flange poses (N, 6) or base_T_flange transforms (N, 4, 4); return the (N, 4, 4)."""
    arr = np.asarray(poses_or_transforms, dtype=float)
    if arr.ndim == 3 and arr.shape[1:] == (4, 4):
        return arr
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise ValueError(f"expected poses (N, 6) or transforms (N, 4, 4), got shape {arr.shape}")
    out = np.broadcast_to(np.eye(4), (len(arr), 4, 4)).copy()
    out[:, :3, :3] = rotation_from_rotvec(arr[:, 3:])
    out[:, :3, 3] = arr[:, :3]
    return out


def branch_of(model: URModel, q_rad: np.ndarray) -> Branch:
    """Return the IK branch a joint configuration ``q_rad`` (6,) lies in."""
    q = np.asarray(q_rad, dtype=float)
    frames = dh_transforms(model, q)
    p5 = frames[5, :3, 3] - model.d[5] * frames[5, :3, 2]
    psi = np.arctan2(p5[1], p5[0])
    return Branch(_sign(np.cos(q[0] - psi)), _sign(np.sin(q[2])), _sign(np.sin(q[4])))


def singularity_reason(model: URModel, q_rad: np.ndarray) -> str:
    """Return why ``q_rad`` is too close to a wrist, elbow or shoulder singularity, or "" if it is not."""
    q = np.asarray(q_rad, dtype=float)
    if abs(np.sin(q[4])) < WRIST_SINGULAR_SIN_Q5:
        return f"wrist singularity (q5 = {np.degrees(q[4]):.1f} deg, |sin q5| < {WRIST_SINGULAR_SIN_Q5})"
    if abs(np.sin(q[2])) < ELBOW_SINGULAR_SIN_Q3:
        return f"elbow singularity (q3 = {np.degrees(q[2]):.1f} deg, arm stretched or folded)"
    frames = dh_transforms(model, q)
    p5 = frames[5, :3, 3] - model.d[5] * frames[5, :3, 2]
    r = float(np.hypot(p5[0], p5[1]))
    if r <= 0.0 or (r - abs(model.d[3])) / r < SHOULDER_SINGULAR_MARGIN:
        return "shoulder singularity (wrist centre near the shoulder axis)"
    return ""


def _near_singularity(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Whether each configuration (M, 6) is within a margin of :func:`singularity_reason` (M,), vectorised."""
    q = np.asarray(q_rad, dtype=float)
    p5 = np.zeros((len(q), 3))
    if len(q):
        frames = dh_transforms_batch(model, q)
        p5 = frames[:, 5, :3, 3] - model.d[5] * frames[:, 5, :3, 2]
    r = np.hypot(p5[:, 0], p5[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        shoulder = (r <= 0.0) | ((r - abs(model.d[3])) / r < SHOULDER_SINGULAR_MARGIN + 1e-9)  # slack: rounding; the reason confirms
    return (np.abs(np.sin(q[:, 4])) < WRIST_SINGULAR_SIN_Q5) | (np.abs(np.sin(q[:, 2])) < ELBOW_SINGULAR_SIN_Q3) | shoulder


_BRANCHES = tuple(Branch(s, e, w) for s in (1, -1) for w in (1, -1) for e in (1, -1))
"""The eight branches in the order :func:`analytic_ik` lists them (shoulder, then wrist, then elbow)."""


def analytic_ik(model: URModel, pose_or_transform: np.ndarray) -> list[tuple[Branch, np.ndarray | None, str]]:
    """Return the eight closed-form IK branches of a flange pose as ``(branch, q (6,) in (−π, π], reason)``.

    ``q`` is None with a ``reason`` ("out of reach …") for a branch that does not exist for this pose. No joint
    limits, singularity margins or refinement are applied here (see :func:`solve_ik`).
    """
    q, reasons = analytic_ik_batch(model, _as_transform(pose_or_transform)[None])
    return [(b, None if reasons[0][k] else q[0, k], reasons[0][k]) for k, b in enumerate(_BRANCHES)]


def analytic_ik_batch(model: URModel, transforms: np.ndarray) -> tuple[np.ndarray, list[list[str]]]:
    """:func:`analytic_ik` of N flange poses at once (base_T_flange (N, 4, 4)), vectorised over poses and branches.

    Returns q (N, 8, 6) in (−π, π] (NaN where a branch does not exist) and the reasons (N lists of 8 strings,
    "" for a branch that exists), branches in :data:`_BRANCHES` order.
    """
    t06 = np.asarray(transforms, dtype=float)
    n = len(t06)
    d4, d6 = model.d[3], model.d[5]
    a2, a3 = model.a[1], model.a[2]
    p6, z6 = t06[:, :3, 3], t06[:, :3, 2]
    p5 = p6 - d6 * z6
    r = np.hypot(p5[:, 0], p5[:, 1])  # (N,)
    reachable = r > abs(d4)
    psi = np.arctan2(p5[:, 1], p5[:, 0])
    shoulder_angle = np.arcsin(d4 / np.where(reachable, r, 2.0 * abs(d4) + 1.0))
    q1 = np.stack([psi + shoulder_angle, psi + np.pi - shoulder_angle], axis=1)  # (N, 2): shoulder +1, −1
    s1, c1 = np.sin(q1), np.cos(q1)
    z1 = np.stack([s1, -c1, np.zeros_like(s1)], axis=-1)  # (N, 2, 3)
    cos_q5 = np.clip(np.einsum("ni,nsi->ns", z6, z1), -1.0, 1.0)
    q5 = np.arccos(cos_q5)[:, :, None] * np.array([1.0, -1.0])  # (N, 2, 2): wrist +1, −1
    s5 = np.sin(q5)
    w = np.einsum("nji,nsj->nsi", t06[:, :3, :3], z1)[:, :, None, :]  # flange_R_base z1 (N, 2, 1, 3)
    singular = np.abs(s5) < 1e-12  # exactly singular: q6 is free; take 0 (the caller rejects the singularity)
    safe_s5 = np.where(singular, 1.0, s5)
    q6 = np.where(singular, 0.0, np.arctan2(-w[..., 1] / safe_s5, w[..., 0] / safe_s5))
    q1b = np.broadcast_to(q1[:, :, None], q5.shape)
    t14 = (np.linalg.inv(dh_step(model, 0, q1b)) @ t06[:, None, None] @ np.linalg.inv(dh_step(model, 5, q6))
           @ np.linalg.inv(dh_step(model, 4, q5)))  # (N, 2, 2, 4, 4)
    x, y = t14[..., 0, 3], t14[..., 1, 3]
    cos_q3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
    q3 = np.arccos(np.clip(cos_q3, -1.0, 1.0))[..., None] * np.array([1.0, -1.0])  # (N, 2, 2, 2): elbow +1, −1
    q2 = np.arctan2(y, x)[..., None] - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
    q4 = np.arctan2(t14[..., 1, 0], t14[..., 0, 0])[..., None] - q2 - q3
    q = np.stack(np.broadcast_arrays(q1b[..., None], q2, q3, q4, q5[..., None], q6[..., None]), axis=-1)
    q = np.angle(np.exp(1j * q)).reshape(n, 8, 6)  # wrap to (−π, π]
    too_far = np.broadcast_to((np.abs(cos_q3) > 1.0 + 1e-12)[..., None], q3.shape).reshape(n, 8)
    reasons: list[list[str]] = []
    for i in range(n):
        if not reachable[i]:
            reasons.append([f"out of reach: wrist centre {r[i]:.3f} m from the base axis, inside the shoulder "
                            f"offset {abs(d4):.3f} m"] * 8)
            continue
        row = [""] * 8
        for k in np.flatnonzero(too_far[i]):
            dist = float(np.hypot(x.reshape(n, 4)[i, k // 2], y.reshape(n, 4)[i, k // 2]))
            row[k] = (f"out of reach: shoulder-to-wrist distance {dist:.3f} m outside "
                      f"[{abs(abs(a2) - abs(a3)):.3f}, {abs(a2) + abs(a3):.3f}] m")
        reasons.append(row)
    q[~reachable] = np.nan
    q[too_far] = np.nan
    return q, reasons


def wrap_near(q_rad: np.ndarray, reference_rad: np.ndarray, lower_rad: np.ndarray,
              upper_rad: np.ndarray) -> np.ndarray | None:
    """Map each joint to the 2π-equivalent value nearest ``reference_rad`` inside [lower, upper].

    Returns None if some joint has no equivalent inside its limits.
    """
    out, inside = _wrap_near_rows(np.asarray(q_rad, dtype=float)[None], reference_rad, lower_rad, upper_rad)
    return out[0] if inside[0] else None


def _wrap_near_rows(q_rad: np.ndarray, reference_rad: np.ndarray, lower_rad: np.ndarray,
                    upper_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`wrap_near` of configurations (M, 6): (wrapped (M, 6), whether each row has every joint inside (M,))."""
    q = np.asarray(q_rad, dtype=float)
    ref = np.asarray(reference_rad, dtype=float)
    lower, upper = np.asarray(lower_rad, dtype=float), np.asarray(upper_rad, dtype=float)
    k = np.round((ref - q) / TWO_PI)
    out = q + TWO_PI * k
    for _ in range(2):  # step back inside the limits if the nearest equivalent is outside
        out = np.where(out > upper + 1e-12, out - TWO_PI, out)
        out = np.where(out < lower - 1e-12, out + TWO_PI, out)
    inside = ~(np.any(out > upper + 1e-12, axis=1) | np.any(out < lower - 1e-12, axis=1))
    return np.clip(out, lower, upper), inside


@lru_cache(maxsize=16)
def _pin(model: URModel):
    pin_model = pinocchio_model(model)
    return pin_model, pin_model.getFrameId(FLANGE_FRAME)


def refine_ik(model: URModel, pose_or_transform: np.ndarray, q_rad: np.ndarray) -> tuple[np.ndarray, float]:
    """Polish ``q_rad`` with Gauss-Newton on Pinocchio's FK; return (q, final ‖log6 error‖).

    The error is ``log6(target⁻¹ · FK(q))`` in the flange frame; the step solves ``J_local δq = −error``.
    """
    import pinocchio as pin

    pin_model, frame_id = _pin(model)
    data = pin_model.createData()
    target_t = _as_transform(pose_or_transform)
    target = pin.SE3(target_t[:3, :3].copy(), target_t[:3, 3].copy())
    q = np.array(q_rad, dtype=float)
    error = np.inf
    for iteration in range(IK_REFINE_ITERATIONS + 1):
        pin.forwardKinematics(pin_model, data, q)
        pin.updateFramePlacement(pin_model, data, frame_id)
        err = pin.log6(target.actInv(data.oMf[frame_id])).vector
        error = float(np.linalg.norm(err))
        if error < IK_TOLERANCE * 1e-2 or iteration == IK_REFINE_ITERATIONS:
            break
        jac = pin.computeFrameJacobian(pin_model, data, q, frame_id, pin.ReferenceFrame.LOCAL)
        q = q - np.linalg.lstsq(jac, err, rcond=None)[0]
    return q, error


def solve_ik_branches(model: URModel, pose_or_transform: np.ndarray,
                      q_reference_rad: np.ndarray) -> dict[Branch, IKResult]:
    """Solve every branch of a flange pose; each joint the 2π-equivalent nearest ``q_reference_rad`` within the
    joint limits less the planning margin (:func:`ftacq.kinematics.planning_limits_rad`).

    Returns a dict branch → :class:`IKResult` (a solution refined on Pinocchio's FK and verified to
    :data:`IK_TOLERANCE`, or why that branch has none: out of reach, joint limit, near a singularity).
    """
    return solve_ik_batch(model, _as_transform(pose_or_transform)[None], q_reference_rad)[0]


def solve_ik_batch(model: URModel, poses_or_transforms: np.ndarray,
                   q_reference_rad: np.ndarray) -> list[dict[Branch, IKResult]]:
    """:func:`solve_ik_branches` of N flange poses (N, 6) or transforms (N, 4, 4) at once: the closed form, the
    joint-limit wrap and the singularity margins vectorised over poses and branches (a plan solves hundreds of
    poses in eight branches each); only the Pinocchio refinement runs per solution."""
    q_ref = np.asarray(q_reference_rad, dtype=float)
    lower, upper = planning_limits_rad(model)
    targets = _as_transforms(poses_or_transforms)
    q_all, reasons = analytic_ik_batch(model, targets)
    n = len(targets)
    q_flat = q_all.reshape(-1, 6)
    exists = ~np.isnan(q_flat[:, 0])
    wrapped, inside = _wrap_near_rows(np.where(exists[:, None], q_flat, 0.0), q_ref, lower, upper)
    inside &= exists
    singular = inside & _near_singularity(model, wrapped)
    out: list[dict[Branch, IKResult]] = []
    for i in range(n):
        by_branch: dict[Branch, IKResult] = {}
        for k, branch in enumerate(_BRANCHES):
            j = i * 8 + k
            if not exists[j]:
                by_branch[branch] = IKResult(None, None, reasons[i][k])
            elif not inside[j]:
                by_branch[branch] = IKResult(None, None, "joint limit: no equivalent of (" + ", ".join(
                    f"{np.degrees(v):.0f}" for v in q_flat[j]) + ") deg within the limits less the planning margin")
            elif singular[j] and (reason := singularity_reason(model, wrapped[j])):
                by_branch[branch] = IKResult(None, None, reason)
            else:
                refined, error = refine_ik(model, targets[i], wrapped[j])
                if error > IK_TOLERANCE:
                    by_branch[branch] = IKResult(None, None, f"IK did not converge (error {error:.1e})")
                elif np.any(refined < lower - 1e-9) or np.any(refined > upper + 1e-9):
                    by_branch[branch] = IKResult(None, None, "joint limit after refinement")
                else:
                    by_branch[branch] = IKResult(refined, branch, "")
        out.append(by_branch)
    return out


def solve_ik(model: URModel, pose_or_transform: np.ndarray, q_previous_rad: np.ndarray,
             branch: Branch | None = None) -> IKResult:
    """Solve the IK of a flange pose near the previous configuration, without passing a singularity.

    Args:
        model: the arm. pose_or_transform: target flange pose [x, y, z (m), rx, ry, rz (rad)] or base_T_flange.
        q_previous_rad: the configuration the robot comes from (6,), rad.
        branch: the branch to stay in; default the branch of ``q_previous_rad`` (a change of shoulder, elbow or
            wrist branch between consecutive poses means passing a singularity: a wrist flip, for instance).

    Returns:
        :class:`IKResult` with the solution in ``branch``, each joint the 2π-equivalent nearest the previous
        value within the joint limits, refined on Pinocchio's FK and verified to :data:`IK_TOLERANCE`; or the
        reason there is none (out of reach, joint limit, near a singularity, needs a branch change).
    """
    wanted = branch if branch is not None else branch_of(model, q_previous_rad)
    results = solve_ik_branches(model, pose_or_transform, q_previous_rad)
    result = results[wanted]
    if result.ok:
        return result
    others = [b for b, r in results.items() if r.ok]
    reason = result.reason
    if others:
        reason += (f"; reachable only by changing branch from ({wanted}) to ({others[0]}): "
                   "a flip through a singularity")
    return IKResult(None, None, reason)


def pose_error(model: URModel, q_rad: np.ndarray, pose_or_transform: np.ndarray) -> tuple[float, float]:
    """Return (position error m, rotation error rad) of FK(q) against a target pose (DH FK, numpy)."""
    target = _as_transform(pose_or_transform)
    actual = forward_kinematics(model, q_rad)
    angle = float(np.linalg.norm(rotvec_from_rotation(target[:3, :3].T @ actual[:3, :3])))
    return float(np.linalg.norm(actual[:3, 3] - target[:3, 3])), angle
