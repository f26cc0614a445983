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
mount and the ceiling for a ceiling mount (the base is bolted to it); (3) joint limits. Link frames come from
Pinocchio (``pin.forwardKinematics`` + ``updateFramePlacements``, :func:`ftacq.kinematics.pinocchio_dh_frames`);
distances are plain numpy segment-segment distances, vectorised over the samples of a path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ftacq.kinematics import URModel, pinocchio_dh_frames, pinocchio_model

LINK_NAMES = ("base", "upper arm", "forearm", "wrist 1", "wrist 2", "wrist 3", "tool")
TOOL = 6
FOREARM_RADIUS_FACTOR = 0.85
WRIST_RADIUS_FACTOR = 0.75

SELF_COLLISION_PAIRS: tuple[tuple[int, int], ...] = (
    (0, 2), (0, 3), (0, 4), (0, 5), (0, 6),
    (1, 3), (1, 4), (1, 5), (1, 6),
    (2, 4), (2, 5), (2, 6),
    (3, 6),
)
"""Non-adjacent pairs checked. Left out: neighbours, and wrist 1-wrist 3 / wrist 2-tool, which the wrist geometry
keeps apart by d5 and d6 whatever the joint angles."""

PLANE_CHECKED_LINKS = (1, 2, 3, 4, 5, 6)
"""Links kept above the mounting plane (the base is bolted to it)."""

DEFAULT_CLEARANCE_M = 0.01
"""Extra distance required between capsules beyond the sum of their radii."""
PATH_MAX_STEP_RAD = 0.02
"""Largest joint step between the samples checked along a joint move (≈1.7 cm at the flange of a UR5e)."""
LIMIT_TOLERANCE_RAD = 1e-9


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
        if self.mount not in ("floor", "wall", "ceiling"):
            raise ValueError(f"mount must be floor, wall or ceiling, got {self.mount!r}")
        pin_model = pinocchio_model(self.model)
        self._pin = (pin_model, pin_model.createData())

    @cached_property
    def radii(self) -> np.ndarray:
        """Capsule radii (7,), m."""
        return link_radii(self.model, self.tool_radius_m)

    def segments(self, q_rad: np.ndarray) -> np.ndarray:
        """Return the link and tool segments (…, 7, 2, 3) for configurations ``q_rad`` (…, 6), from Pinocchio FK."""
        q = np.asarray(q_rad, dtype=float)
        flat = q.reshape(-1, 6)
        out = np.empty((flat.shape[0], 7, 2, 3))
        pin_model, data = self._pin
        for k, qk in enumerate(flat):
            frames = pinocchio_dh_frames(pin_model, data, qk)
            origins = np.vstack([np.zeros(3), frames[:, :3, 3]])
            out[k, :6, 0] = origins[:6]
            out[k, :6, 1] = origins[1:]
            out[k, TOOL, 0] = origins[6]
            out[k, TOOL, 1] = origins[6] + self.tool_length_m * frames[5, :3, 2]
        return out.reshape(q.shape[:-1] + (7, 2, 3))

    def _problems(self, q_samples: np.ndarray, check_limits: bool = True) -> tuple[list[str], np.ndarray]:
        """Return (problems, index of the first bad sample per problem) for samples (S, 6)."""
        problems: list[str] = []
        first_bad: list[int] = []
        lower, upper = np.array(self.model.joint_min_rad), np.array(self.model.joint_max_rad)
        bad_limit = np.any((q_samples < lower - LIMIT_TOLERANCE_RAD) | (q_samples > upper + LIMIT_TOLERANCE_RAD),
                           axis=-1)
        if check_limits and bad_limit.any():
            k = int(np.argmax(bad_limit))
            joints = np.flatnonzero((q_samples[k] < lower - LIMIT_TOLERANCE_RAD)
                                    | (q_samples[k] > upper + LIMIT_TOLERANCE_RAD))
            problems.append("joint limit: " + ", ".join(
                f"q{j + 1} = {np.degrees(q_samples[k, j]):.1f} deg outside "
                f"[{np.degrees(lower[j]):.0f}, {np.degrees(upper[j]):.0f}]" for j in joints))
            first_bad.append(k)
        seg = self.segments(q_samples)  # (S, 7, 2, 3)
        radii = self.radii
        # mounting surface: lowest point of each capsule (links) or cylinder (tool) above z = margin
        for link in PLANE_CHECKED_LINKS:
            ends_z = seg[:, link, :, 2]
            if link == TOOL:
                axis = seg[:, link, 1] - seg[:, link, 0]
                length = np.linalg.norm(axis, axis=-1)
                axis_z = np.where(length > 0, axis[:, 2] / np.where(length > 0, length, 1.0), 1.0)
                lowest = ends_z.min(axis=-1) - radii[link] * np.sqrt(np.clip(1.0 - axis_z**2, 0.0, 1.0))
            else:
                lowest = ends_z.min(axis=-1) - radii[link]
            bad = lowest < self.table_margin_m
            if bad.any():
                k = int(np.argmax(bad))
                problems.append(f"{LINK_NAMES[link]} {lowest[k] * 1000:.0f} mm from the {self._surface_name()} "
                                f"(needs {self.table_margin_m * 1000:.0f} mm)")
                first_bad.append(k)
        pairs = np.array(SELF_COLLISION_PAIRS)
        dist = segment_distances(seg[:, pairs[:, 0], 0], seg[:, pairs[:, 0], 1],
                                 seg[:, pairs[:, 1], 0], seg[:, pairs[:, 1], 1])  # (S, P)
        needed = radii[pairs[:, 0]] + radii[pairs[:, 1]] + self.clearance_m
        bad_pairs = dist < needed
        for p in np.flatnonzero(bad_pairs.any(axis=0)):
            k = int(np.argmax(bad_pairs[:, p]))
            a, b = pairs[p]
            problems.append(f"{LINK_NAMES[b]} hits {LINK_NAMES[a]} (gap {(dist[k, p] - needed[p] + self.clearance_m) * 1000:.0f} mm"
                            f", needs {self.clearance_m * 1000:.0f} mm)")
            first_bad.append(k)
        return problems, np.array(first_bad, dtype=int)

    def _surface_name(self) -> str:
        return {"floor": "table", "wall": "wall", "ceiling": "ceiling"}[self.mount]

    def problems_at(self, q_rad: np.ndarray) -> list[str]:
        """Return the collision and limit problems of one configuration (6,); empty when it is clear."""
        problems, _ = self._problems(np.asarray(q_rad, dtype=float).reshape(1, 6))
        return problems

    def path_samples(self, q_from: np.ndarray, q_to: np.ndarray, max_step_rad: float = PATH_MAX_STEP_RAD) -> np.ndarray:
        """Return configurations (S, 6) along the straight joint-space move (a moveJ), both ends included."""
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        steps = max(1, int(np.ceil(np.max(np.abs(q_to - q_from)) / max_step_rad)))
        fractions = np.linspace(0.0, 1.0, steps + 1)[:, None]
        return q_from + fractions * (q_to - q_from)

    def problems_along(self, q_from: np.ndarray, q_to: np.ndarray, max_step_rad: float = PATH_MAX_STEP_RAD,
                       check_limits: bool = True) -> list[str]:
        """Return the problems along the joint move q_from → q_to, sampled every ``max_step_rad``; empty = clear.

        Each message says how far along the move (in %) the problem first occurs. ``check_limits=False`` checks
        geometry only (it is 2π-periodic in every joint, so a planner may check a move once for any winding).
        """
        samples = self.path_samples(q_from, q_to, max_step_rad)
        problems, first_bad = self._problems(samples, check_limits)
        last = max(len(samples) - 1, 1)
        return [f"{p} at {100.0 * k / last:.0f} % of the move" for p, k in zip(problems, first_bad)]
