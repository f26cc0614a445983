"""What the 3-D view draws, as numbers: the arm's links in their own frames, and where the force labels go.

The arm is logged as Rerun draws a robot from its description: each link's shape once (static) in its DH
frame, and per time only the six frames' transforms base_T_i. For the DH step ``Rz(q_i) Tz(d_i) Tx(a_i) Rx(α_i)``
the link from frame i-1 to frame i visits the origin of frame i-1, the point ``d_i`` along its z axis, then the
origin of frame i; written in frame i these three points do not depend on ``q_i``:
``Rx(-α_i)·(-a_i, 0, -d_i)``, ``(-a_i, 0, 0)`` and ``0``. The UR's shoulder and elbow offsets show as bends.
"""

from __future__ import annotations

import numpy as np

from ftacq.app.dashboard.layout import LABEL_CLEARANCE_M, LABEL_MIN_SEPARATION_M
from ftacq.kinematics import URModel, dh_transforms_batch


def link_shapes(model: URModel) -> np.ndarray:
    """Return the six links' polylines (6, 3, 3) [link, point, xyz], m, each in its own DH frame i (see module)."""
    shapes = np.zeros((6, 3, 3))
    for i in range(6):
        a, d, alpha = float(model.a[i]), float(model.d[i]), float(model.alpha[i])
        shapes[i, 0] = (-a, -d * np.sin(alpha), -d * np.cos(alpha))  # Rx(-α)·(-a, 0, -d): origin of frame i-1
        shapes[i, 1] = (-a, 0.0, 0.0)  # d_i along z_{i-1}
    return shapes


def link_frames(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return base_T_i (S, 6, 4, 4) of the six DH frames for configurations ``q_rad`` (S, 6) rad (vectorised)."""
    return dh_transforms_batch(model, np.asarray(q_rad, dtype=float).reshape(-1, 6))


def arm_polyline(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return the arm's skeleton (13, 3) in the base frame, m: the base origin, then per link the bend and the
    frame's origin (the static shapes placed by :func:`link_frames`)."""
    frames = link_frames(model, q_rad)[0]
    shapes = link_shapes(model)
    points = [np.zeros(3)]
    for i in range(6):
        in_base = shapes[i] @ frames[i][:3, :3].T + frames[i][:3, 3]
        points.extend(in_base[1:])
    return np.array(points)


def _distance_to_segment(point: np.ndarray, start: np.ndarray, vector: np.ndarray) -> float:
    length2 = float(vector @ vector)
    t = 0.0 if length2 == 0.0 else float(np.clip((point - start) @ vector / length2, 0.0, 1.0))
    return float(np.linalg.norm(point - (start + t * vector)))


def label_anchors(origin: np.ndarray, weight: np.ndarray, contact: np.ndarray,
                  clearance_m: float = LABEL_CLEARANCE_M,
                  min_separation_m: float = LABEL_MIN_SEPARATION_M) -> np.ndarray:
    """Return where to write the "tool weight" and "contact" labels (2, 3), m, for two arrows drawn from
    ``origin`` (3,) with vectors ``weight`` and ``contact`` (3,), m (all in one frame).

    Each label sits ``clearance_m`` beyond its arrow's tip, so it never covers a shaft. A contact arrow too short
    to have a direction gets its label on the side opposite the weight. When the two anchors come closer than
    ``min_separation_m`` (arrows nearly alike) or an anchor lands on the other arrow, the contact label moves
    sideways, perpendicular to the weight, until both hold (the weight label moves the other way when a longer
    contact arrow runs through it).
    """
    origin, weight, contact = (np.asarray(v, dtype=float).reshape(3) for v in (origin, weight, contact))
    weight_length = float(np.linalg.norm(weight))
    down = weight / weight_length if weight_length > 1e-9 else np.array([0.0, 0.0, -1.0])
    weight_anchor = origin + weight + clearance_m * down
    contact_length = float(np.linalg.norm(contact))
    direction = contact / contact_length if contact_length > clearance_m else -down
    contact_anchor = origin + contact + clearance_m * direction

    side = np.cross(down, [1.0, 0.0, 0.0])
    if np.linalg.norm(side) < 1e-6:
        side = np.cross(down, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)

    for _ in range(8):  # a longer contact arrow along the weight would run through the weight's label
        if _distance_to_segment(weight_anchor, origin, contact) >= clearance_m:
            break
        weight_anchor = weight_anchor - 0.5 * min_separation_m * side

    def clear(anchor: np.ndarray) -> bool:
        return bool(np.linalg.norm(anchor - weight_anchor) >= min_separation_m
                and _distance_to_segment(anchor, origin, weight) >= clearance_m
                and _distance_to_segment(anchor, origin, contact) >= clearance_m)

    shifted = contact_anchor
    for _ in range(8):
        if clear(shifted):
            break
        shifted = shifted + 0.5 * min_separation_m * side
    return np.array([weight_anchor, shifted])
