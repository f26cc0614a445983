"""Kinematics of the arm, in one package:

- :mod:`ftacq.kinematics.ur`: UR's published DH tables (:class:`URModel`), joint limits, the one DH step
  (:func:`dh_matrix`, one configuration or a batch) and forward kinematics (``base_T_flange``, the flange pose).
- :mod:`ftacq.kinematics.pinocchio_models`: the one Pinocchio builder of a DH chain (a UR model or any DH table),
  the URDF loader, the flange's orientation every controller cycle (:class:`FlangeRotation`).
- :mod:`ftacq.kinematics.ik`: UR's analytic inverse kinematics (eight branches), refined on Pinocchio's FK.

``from ftacq.kinematics import URModel, ur_model, flange_pose, solve_ik …`` is the public entry. Pinocchio is
imported on first use of a Pinocchio model, not by this package.
"""

from ftacq.kinematics.ik import (
    IK_TOLERANCE,
    TWO_PI,
    Branch,
    IKResult,
    analytic_ik,
    analytic_ik_batch,
    branch_of,
    pose_error,
    refine_ik,
    singularity_reason,
    solve_ik,
    solve_ik_batch,
    solve_ik_branches,
    wrap_near,
)
from ftacq.kinematics.pinocchio_models import (
    FLANGE_FRAME,
    FlangeRotation,
    dh_chain_model,
    dh_frame_name,
    pinocchio_dh_frames,
    pinocchio_model,
    pinocchio_model_from_urdf,
)
from ftacq.kinematics.ur import (
    JOINT_LIMIT_MARGIN_RAD,
    MEASURED_ANGLE_TOLERANCE_RAD,
    UR_MODELS,
    URModel,
    dh_matrix,
    dh_step,
    dh_transforms,
    dh_transforms_batch,
    flange_pose,
    pose_of_transform,
    forward_kinematics,
    middle_equivalent,
    planning_limits_rad,
    ur_model,
)

__all__ = ["URModel", "UR_MODELS", "ur_model", "JOINT_LIMIT_MARGIN_RAD", "MEASURED_ANGLE_TOLERANCE_RAD",
           "planning_limits_rad", "middle_equivalent", "dh_matrix", "dh_step", "dh_transforms", "dh_transforms_batch",
           "forward_kinematics", "flange_pose", "pose_of_transform", "FLANGE_FRAME", "dh_frame_name", "dh_chain_model", "pinocchio_model",
           "FlangeRotation", "pinocchio_model_from_urdf", "pinocchio_dh_frames", "IK_TOLERANCE", "TWO_PI", "Branch",
           "IKResult", "analytic_ik", "analytic_ik_batch", "branch_of", "singularity_reason", "wrap_near", "refine_ik",
           "solve_ik_branches", "solve_ik_batch", "solve_ik", "pose_error"]
