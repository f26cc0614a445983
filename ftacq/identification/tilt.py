"""Tool mass and base tilt from gravity_base (corrected eqs 46-48), and the tilt relative to a nominal mount.

gravity_base = −m g [cos α sin β, −sin α, cos α cos β] (eq. 47); m g = ‖gravity_base‖ (the paper squares
it), β = atan2(−f_x, −f_z), α = atan2(f_y, √(f_x² + f_z²)), branch cos α ≥ 0, β in (−180°, 180°].
Nominal mounts (as tests/fakes/world.CellTruth.with_mount): floor (α, β) = (0, 0), wall (0, 90°),
ceiling (0, 180°); any other mount is a spec of :func:`ftacq.mounts.mount_of` (``tilted:A,B``, ``gravity:X,Y,Z``).
The gravity direction is −R_y(β) R_x(α) e_z, so the tilt relative to a mount (α_n, β_n) is the tilt of the
measured direction expressed in the nominal frame, (R_y(β_n) R_x(α_n))ᵀ d; for α_n = 0 that is α_rel = α,
β_rel = β − β_n wrapped.
"""

from __future__ import annotations

import numpy as np

from ftacq.mounts import MOUNT_TABLE, mount_of

MOUNT_TILT_DEG = {name: mount.tilt_deg for name, mount in MOUNT_TABLE.items()}
"""Nominal (α, β) in degrees of each mount name (from :data:`ftacq.mounts.MOUNT_TABLE`)."""


def wrap_deg(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle in degrees into (−180, 180]."""
    wrapped = -((-np.asarray(angle, dtype=float) + 180.0) % 360.0 - 180.0)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def tilt_deg(gravity_base: np.ndarray) -> tuple[float, float]:
    """Return (α, β) in degrees of a gravity_base vector (corrected eq. 48)."""
    fx, fy, fz = np.asarray(gravity_base, dtype=float)
    beta = float(wrap_deg(np.degrees(np.arctan2(-fx, -fz))))
    alpha = float(np.degrees(np.arctan2(fy, np.hypot(fx, fz))))
    return alpha, beta


def tilt_jacobian_deg(gravity_base: np.ndarray) -> np.ndarray:
    """Return ∂(α, β)/∂gravity_base (2, 3) in degrees per newton (analytic)."""
    fx, fy, fz = np.asarray(gravity_base, dtype=float)
    rho2 = fx * fx + fz * fz
    rho = np.sqrt(rho2)
    n2 = rho2 + fy * fy
    # β = atan2(y, x) with y = −fx, x = −fz: dβ = (x dy − y dx)/ρ² = (fz dfx − fx dfz)/ρ²
    d_beta = np.array([fz, 0.0, -fx]) / max(rho2, 1e-300)
    # α = atan2(fy, ρ): dα = (ρ dfy − fy dρ)/n², dρ = (fx dfx + fz dfz)/ρ
    d_alpha = np.array([-fy * fx / max(rho, 1e-300), rho, -fy * fz / max(rho, 1e-300)]) / max(n2, 1e-300)
    return np.degrees(np.vstack([d_alpha, d_beta]))


def relative_tilt_deg(gravity_base: np.ndarray, mount: str) -> tuple[float, float, float]:
    """Return (α_rel, β_rel, total angle) in degrees of the base's tilt from a mount (a name or a spec).

    The total angle is the angle between the measured and the mount's gravity direction in the base frame.
    """
    alpha_n, beta_n = np.radians(mount_of(mount).tilt_deg)
    ca, sa, cb, sb = np.cos(alpha_n), np.sin(alpha_n), np.cos(beta_n), np.sin(beta_n)
    base_R_nominal = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]]) @ \
        np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    direction = np.asarray(gravity_base, dtype=float) / np.linalg.norm(gravity_base)
    nominal = base_R_nominal @ np.array([0.0, 0.0, -1.0])
    total = float(np.degrees(np.arccos(np.clip(direction @ nominal, -1.0, 1.0))))
    alpha_rel, beta_rel = tilt_deg(base_R_nominal.T @ direction)
    return alpha_rel, beta_rel, total


def nearest_mount(gravity_base: np.ndarray) -> tuple[str, float]:
    """Return the nominal mount whose gravity direction is nearest, and the angle to it (deg)."""
    best = min(MOUNT_TILT_DEG, key=lambda name: relative_tilt_deg(gravity_base, name)[2])
    return best, relative_tilt_deg(gravity_base, best)[2]
