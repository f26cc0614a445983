"""Collision checks for a UR arm with a tool: capsules from the DH frames, a tool cylinder, the mounting plane.

Geometry (all in the robot base frame, metres). With ``o_k`` the origin of DH frame ``k`` (``o_0`` the base):

====  ============  ==================================  ===============================
 idx  link          segment                              radius
====  ============  ==================================  ===============================
  0   base          o_0 → o_1 (d1 along z_0)             ``link_radius_m``
  1   upper arm     o_1 → o_2 (a2 along x_2)             ``link_radius_m``
  2   forearm       o_2 → o_3 (a3 along x_3)             0.85 × ``link_radius_m``
  3   wrist 1       o_3 → o_4 (d4 along z_3)             0.75 × ``link_radius_m``
  4   wrist 2       o_4 → o_5 (d5 along z_4)             0.75 × ``link_radius_m``
  5   wrist 3       o_5 → o_6 (d6 along z_5)             0.75 × ``link_radius_m``
  6   tool          o_6 → o_6 + L z_6                    ``tool_radius_m`` (a cylinder)
====  ============  ==================================  ===============================

The DH line of the upper arm and forearm differs from the real links by their lateral offsets (UR puts the
shoulder offset there; the DH table moves it all to d4), so this model is an approximation at the level of a
few centimetres: the ``clearance_m`` margin is there for that.

Checks: (1) non-adjacent link pairs and the tool against the arm (:data:`SELF_COLLISION_PAIRS`, capsule-capsule
distance ≥ r_a + r_b + clearance); (2) every link except the base, and the tool, stay ``table_margin_m`` above the
mounting surface: the plane z = 0 of the base frame, which is the table for a floor mount, the wall for a wall
mount and the ceiling for a ceiling mount (the base is bolted to it); (3) joint limits: a planned target must stay
:data:`ftacq.kinematics.JOINT_LIMIT_MARGIN_RAD` inside them, a measured configuration (where a move starts) may
lie :data:`ftacq.kinematics.MEASURED_ANGLE_TOLERANCE_RAD` outside them (encoder jitter). Link frames come from
Pinocchio (``pin.forwardKinematics`` + ``updateFramePlacements``, :func:`ftacq.kinematics.pinocchio_dh_frames`);
distances are plain numpy segment-segment distances, vectorised over the samples of a path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ftacq.kinematics import (
    JOINT_LIMIT_MARGIN_RAD,
    MEASURED_ANGLE_TOLERANCE_RAD,
    URModel,
    dh_transforms_batch,
    pinocchio_dh_frames,
    pinocchio_model,
    planning_limits_rad,
)
from ftacq.mounts import mount_of

LINK_NAMES = ("base", "upper arm", "forearm", "wrist 1", "wrist 2", "wrist 3", "tool")
TOOL = 6
FOREARM_RADIUS_FACTOR = 0.85
WRIST_RADIUS_FACTOR = 0.75

SELF_COLLISION_PAIRS: tuple[tuple[int, int], ...] = (
    (0, 2), (0, 3), (0, 4), (0, 5), (0, 6),
    (1, 3), (1, 4), (1, 5), (1, 6),
    (2, 5), (2, 6),
    (3, 6),
)
"""Non-adjacent pairs checked. Left out: neighbours, and the pairs the DH geometry keeps at a fixed distance
whatever the joint angles (forearm-wrist 2: d4, the wrist-1 offset; wrist 1-wrist 3: d5; wrist 2-tool: d6);
with these models' radii some of those fixed gaps are below the clearance, which would reject every pose."""

PLANE_CHECKED_LINKS = (1, 2, 3, 4, 5, 6)
"""Links kept above the mounting plane (the base is bolted to it)."""

DEFAULT_CLEARANCE_M = 0.01
"""Extra distance required between capsules beyond the sum of their radii."""
PATH_MAX_DISPLACEMENT_M = 0.03
"""Initial sampling of a joint move: at most this displacement of any point between samples (refined where the
bound between samples is not yet proven, see :meth:`CollisionChecker.problems_along`)."""
PATH_MIN_DISPLACEMENT_M = 0.0005
"""Refinement of a joint-move check stops at this displacement per step (the certified bound's tolerance)."""


def link_radii(model: URModel, tool_radius_m: float) -> np.ndarray:
    """Return the capsule radii (7,) of base, upper arm, forearm, three wrists and the tool, in metres."""
    r = model.link_radius_m
    return np.array([r, r, FOREARM_RADIUS_FACTOR * r, WRIST_RADIUS_FACTOR * r, WRIST_RADIUS_FACTOR * r,
                     WRIST_RADIUS_FACTOR * r, tool_radius_m])


def segment_distances(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Return the distances (…) between segments p0→p1 and q0→q1 (… , 3), vectorised (Ericson, RTCD §5.1.9)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    eps = 1e-18
    denom = a * e - b * b
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.where(denom > eps, denom, 1.0), 0.0, 1.0), 0.0)
    t = np.where(e > eps, (b * s + f) / np.where(e > eps, e, 1.0), 0.0)
    # t outside [0, 1]: clamp t and recompute s
    t_low, t_high = t < 0.0, t > 1.0
    safe_a = np.where(a > eps, a, 1.0)
    s = np.where(t_low, np.clip(-c / safe_a, 0.0, 1.0), s)
    s = np.where(t_high, np.clip((b - c) / safe_a, 0.0, 1.0), s)
    s = np.where(a > eps, s, 0.0)
    t = np.clip(t, 0.0, 1.0)
    closest_p = p0 + s[..., None] * d1
    closest_q = q0 + t[..., None] * d2
    return np.linalg.norm(closest_p - closest_q, axis=-1)


@dataclass
class CollisionChecker:
    """Check configurations and joint moves of ``model`` carrying a cylindrical tool on its flange.

    Attributes:
        model: the arm. tool_radius_m, tool_length_m: the tool's bounding cylinder (along the flange z axis).
        mount: "floor", "wall" or "ceiling" (the mounting surface is the base-frame plane z = 0 in every case).
        table_margin_m: how far above the mounting surface everything but the base must stay.
        clearance_m: margin beyond the radii for link-link and tool-link distances.
    """

    model: URModel
    tool_radius_m: float = 0.05
    tool_length_m: float = 0.1
    mount: str = "floor"
    table_margin_m: float = 0.02
    clearance_m: float = DEFAULT_CLEARANCE_M
    _pin: tuple = field(init=False, repr=False, default=())

    def __post_init__(self) -> None:
        mount_of(self.mount)  # ValueError naming the known mounts
        pin_model = pinocchio_model(self.model)
        self._pin = (pin_model, pin_model.createData())

    @cached_property
    def radii(self) -> np.ndarray:
        """Capsule radii (7,), m."""
        return link_radii(self.model, self.tool_radius_m)

    def segments(self, q_rad: np.ndarray) -> np.ndarray:
        """Return the link and tool segments (…, 7, 2, 3) for configurations ``q_rad`` (…, 6).

        One configuration: DH frames from Pinocchio FK (``forwardKinematics`` + ``updateFramePlacements``). Many
        (the samples of a move): the vectorised DH product :func:`ftacq.kinematics.dh_transforms_batch`, equal
        to Pinocchio's to 1e-12 (tested) and ~50× faster than one Pinocchio call per sample from Python.
        """
        q = np.asarray(q_rad, dtype=float)
        flat = q.reshape(-1, 6)
        if flat.shape[0] == 1:
            pin_model, data = self._pin
            frames = pinocchio_dh_frames(pin_model, data, flat[0])[None]
        else:
            frames = dh_transforms_batch(self.model, flat)
        n = flat.shape[0]
        origins = np.concatenate([np.zeros((n, 1, 3)), frames[:, :, :3, 3]], axis=1)  # (n, 7, 3): o_0 … o_6
        out = np.empty((n, 7, 2, 3))
        out[:, :6, 0] = origins[:, :6]
        out[:, :6, 1] = origins[:, 1:]
        out[:, TOOL, 0] = origins[:, 6]
        out[:, TOOL, 1] = origins[:, 6] + self.tool_length_m * frames[:, 5, :3, 2]
        return out.reshape(q.shape[:-1] + (7, 2, 3))

    @cached_property
    def lever_arms_m(self) -> np.ndarray:
        """Return, per joint, a bound (6,) on the distance from its axis to any point of the arm and tool beyond it."""
        m = self.model
        tool = self.tool_length_m + self.tool_radius_m
        # joint j turns about the z axis of DH frame j-1; d_j runs along that axis and moves nothing away from it
        return np.array([abs(m.a[j]) + sum(abs(m.a[k]) + abs(m.d[k]) for k in range(j + 1, 6)) + tool
                         + self.radii.max() for j in range(6)])

    def displacement_bound_m(self, q_from: np.ndarray, q_to: np.ndarray) -> float:
        """Return a bound on how far any point of the arm or tool moves over the joint move q_from → q_to, m."""
        return float(np.abs(np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float)) @ self.lever_arms_m)

    def clearances(self, q_samples: np.ndarray) -> np.ndarray:
        """Return the clearance of every constraint (S, C) at configurations (S, 6), m; ≥ 0 means satisfied.

        Columns: the links of :data:`PLANE_CHECKED_LINKS` above the mounting surface (height of the lowest point
        minus ``table_margin_m``), then the pairs of :data:`SELF_COLLISION_PAIRS` (distance minus both radii minus
        ``clearance_m``).
        """
        seg = self.segments(np.asarray(q_samples, dtype=float).reshape(-1, 6))  # (S, 7, 2, 3)
        radii = self.radii
        plane = []
        for link in PLANE_CHECKED_LINKS:  # lowest point of each capsule (links) or cylinder (tool)
            ends_z = seg[:, link, :, 2]
            if link == TOOL:
                axis = seg[:, link, 1] - seg[:, link, 0]
                length = np.linalg.norm(axis, axis=-1)
                axis_z = np.where(length > 0, axis[:, 2] / np.where(length > 0, length, 1.0), 1.0)
                lowest = ends_z.min(axis=-1) - radii[link] * np.sqrt(np.clip(1.0 - axis_z**2, 0.0, 1.0))
            else:
                lowest = ends_z.min(axis=-1) - radii[link]
            plane.append(lowest - self.table_margin_m)
        pairs = np.array(SELF_COLLISION_PAIRS)
        dist = segment_distances(seg[:, pairs[:, 0], 0], seg[:, pairs[:, 0], 1],
                                 seg[:, pairs[:, 1], 0], seg[:, pairs[:, 1], 1])  # (S, P)
        gaps = dist - (radii[pairs[:, 0]] + radii[pairs[:, 1]] + self.clearance_m)
        return np.concatenate([np.array(plane).T.reshape(len(seg), -1), gaps], axis=1)

    def _describe(self, column: int, clearance_m: float) -> str:
        """Return the message of a violated constraint column with its clearance value."""
        n_plane = len(PLANE_CHECKED_LINKS)
        if column < n_plane:
            link = PLANE_CHECKED_LINKS[column]
            return (f"{LINK_NAMES[link]} {(clearance_m + self.table_margin_m) * 1000:.0f} mm from the "
                    f"{self._surface_name()} (needs {self.table_margin_m * 1000:.0f} mm)")
        a, b = SELF_COLLISION_PAIRS[column - n_plane]
        return (f"{LINK_NAMES[b]} hits {LINK_NAMES[a]} (gap {(clearance_m + self.clearance_m) * 1000:.0f} mm, "
                f"needs {self.clearance_m * 1000:.0f} mm)")

    def _limit_problem(self, q_samples: np.ndarray, margins_rad: np.ndarray) -> tuple[str, int] | None:
        """Return (message, first offending sample) when a sample (S, 6) leaves the joint limits less its margin
        (S,) (negative: a tolerance beyond the limits), or None."""
        margins = np.asarray(margins_rad, dtype=float).reshape(-1, 1)
        lower, upper = planning_limits_rad(self.model, 0.0)
        outside = (q_samples < lower + margins) | (q_samples > upper - margins)
        if not outside.any():
            return None
        k = int(np.argmax(outside.any(axis=-1)))
        margin = float(margins[k, 0])
        kept = (f" (the limits less the {np.degrees(margin):.0f} deg planning margin)" if margin > 0.0 else
                f" (measured; {abs(margin):.0e} rad of encoder noise allowed)" if margin < 0.0 else "")
        return "joint limit: " + ", ".join(
            f"q{j + 1} = {np.degrees(q_samples[k, j]):.4f} deg outside "
            f"[{np.degrees(lower[j] + margin):.0f}, {np.degrees(upper[j] - margin):.0f}]" + kept
            for j in np.flatnonzero(outside[k])), k

    def _surface_name(self) -> str:
        return mount_of(self.mount).surface

    def problems_at(self, q_rad: np.ndarray, measured: bool = False) -> list[str]:
        """Return the collision and limit problems of one configuration (6,); empty when it is clear.

        A planned configuration (default) must keep :data:`JOINT_LIMIT_MARGIN_RAD` from every limit; a
        ``measured`` one (the arm's reported angles) may lie :data:`MEASURED_ANGLE_TOLERANCE_RAD` beyond one.
        """
        q = np.asarray(q_rad, dtype=float).reshape(1, 6)
        problems = []
        limit = self._limit_problem(q, np.array([-MEASURED_ANGLE_TOLERANCE_RAD if measured else JOINT_LIMIT_MARGIN_RAD]))
        if limit:
            problems.append(limit[0])
        clearance = self.clearances(q)[0]
        problems += [self._describe(int(c), clearance[c]) for c in np.flatnonzero(clearance < 0.0)]
        return problems

    def path_samples(self, q_from: np.ndarray, q_to: np.ndarray,
                     max_displacement_m: float = PATH_MAX_DISPLACEMENT_M) -> np.ndarray:
        """Return configurations (S, 6) along the straight joint-space move (a moveJ), both ends included, so
        that no point of the arm or tool moves more than ``max_displacement_m`` between consecutive samples."""
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        steps = max(1, int(np.ceil(self.displacement_bound_m(q_from, q_to) / max_displacement_m)))
        fractions = np.linspace(0.0, 1.0, steps + 1)[:, None]
        return q_from + fractions * (q_to - q_from)

    def problems_along(self, q_from: np.ndarray, q_to: np.ndarray,
                       max_displacement_m: float = PATH_MAX_DISPLACEMENT_M, check_limits: bool = True) -> list[str]:
        """Return the problems along the joint move q_from → q_to; empty = clear.

        Certified by conservative advancement: no point moves faster than ``D = Σ_j |Δq_j| L_j`` per unit of
        the move (:meth:`displacement_bound_m`), so two points' distance changes by at most ``2 D Δt`` and a
        clearance f satisfies, between samples t_k and t_k+1, ``f ≥ (f_k + f_k+1)/2 − D (t_k+1 − t_k)``. The move
        is sampled every ``max_displacement_m`` of displacement; intervals whose bound is negative are bisected
        until the bound holds, a sample violates a constraint (reported), or the step is below
        :data:`PATH_MIN_DISPLACEMENT_M` (accepted: the clearance there is within that of the limit). Each message
        says how far along the move (in %) the problem first occurs. ``check_limits=False`` checks geometry only
        (it is 2π-periodic in every joint, so a planner may check a move once for any winding).

        Joint limits: ``q_from`` is where the arm is (measured, or a target already checked) and may lie
        :data:`MEASURED_ANGLE_TOLERANCE_RAD` beyond a limit; ``q_to`` is a planned target and must keep
        :data:`JOINT_LIMIT_MARGIN_RAD` from every limit.
        """
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        problems: list[str] = []
        if check_limits:  # a straight move is inside if both ends are
            limit = self._limit_problem(np.vstack([q_from, q_to]),
                                        np.array([-MEASURED_ANGLE_TOLERANCE_RAD, JOINT_LIMIT_MARGIN_RAD]))
            if limit:
                problems.append(f"{limit[0]} at {100.0 * limit[1]:.0f} % of the move")
        bound = self.displacement_bound_m(q_from, q_to)
        steps = max(1, int(np.ceil(bound / max_displacement_m)))
        t = np.linspace(0.0, 1.0, steps + 1)
        f = self.clearances(q_from + t[:, None] * (q_to - q_from))
        while True:
            violated = f < 0.0
            if violated.any():
                for c in np.flatnonzero(violated.any(axis=0)):
                    k = int(np.argmax(violated[:, c]))
                    problems.append(f"{self._describe(int(c), f[k, c])} at {100.0 * t[k]:.0f} % of the move")
                return problems
            worst = f.min(axis=1)
            dt = np.diff(t)
            open_ = (worst[:-1] + worst[1:]) / 2.0 - bound * dt < 0.0
            open_ &= bound * dt > PATH_MIN_DISPLACEMENT_M
            if not open_.any():
                return problems
            gaps = np.flatnonzero(open_)
            mids = (t[gaps] + t[gaps + 1]) / 2.0
            f_mid = self.clearances(q_from + mids[:, None] * (q_to - q_from))
            t = np.insert(t, gaps + 1, mids)
            f = np.insert(f, gaps + 1, f_mid, axis=0)
