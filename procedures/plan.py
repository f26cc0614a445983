"""The calibration plan: pose sets, reachability and collision checks, duration estimate.

:func:`make_plan` builds the A/E/V pose sets (:mod:`procedures.poses`) about a centre, solves the IK of every pose
in each of the eight branches (:mod:`ftacq.kinematics.ik`), keeps the branch that reaches the most poses without
collision (:mod:`procedures.collision`; ties go to the robot's current branch), rejects the rest with a reason,
has :mod:`procedures.tour` order the poses and check every joint move of that order along its path, and
estimates the duration from trapezoidal joint profiles. When no centre is given and the default one loses poses,
alternative centres are tried. The settings are :class:`procedures.plan_settings.PlanSettings`.

Joint limits: every planned target, the drift-check revisit's included, keeps
:data:`ftacq.kinematics.JOINT_LIMIT_MARGIN_RAD` (5°) from each limit (a joint that would leave that range goes to
its 2π-equivalent nearest the middle of the range, :mod:`procedures.tour`); the robot's measured configuration may
lie :data:`ftacq.kinematics.MEASURED_ANGLE_TOLERANCE_RAD` beyond a limit (encoder jitter).

Order of the sets: A, E and V poses are interleaved in one tour. Validation poses measured among the others
see the same thermal state and time as the identification poses, so their error measures the calibration, not
the drift (which the executor's revisit of the first pose reports separately); putting V last would also add
a long detour back to the region the tour has left. Identification and validation stay separate by
``Plan.set_names``, not by order.

A little over 500 lines: the pose set, its reachability, collision and speed checks and the choice among
candidate centres are one search that passes one candidate state around; the tour's order already lives in
:mod:`procedures.tour`, and the time estimates (:mod:`ftacq.kinematics.trapezoid`,
``estimate_duration_s``) are the next candidate to move apart.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ftacq.errors import PlanError
from ftacq.kinematics import (
    JOINT_LIMIT_MARGIN_RAD,
    MEASURED_ANGLE_TOLERANCE_RAD,
    UR_MODELS,
    URModel,
    planning_limits_rad,
    ur_model,
)
from ftacq.kinematics.trapezoid import move_duration_s
from ftacq.mounts import mount_of
from ftacq.posesets import IDENTIFICATION_SETS, PLANNED_SETS, RANDOM_SET, SPECIAL_SET, VALIDATION_SET
from ftacq.so3 import rotation_from_rotvec
from procedures.collision import CollisionChecker
from ftacq.kinematics.ik import Branch, IKResult, branch_of, solve_ik_batch
from procedures.plan_settings import PlanSettings
from procedures.poses import PoseSet, explicit_poses, random_cone_poses, special_poses, tool_down_rotation
from procedures.tour import (
    MoveGraph,
    joint_weights,
    listing_targets,
    order_and_check,
    path_travel,
    revisit_target,
)

PLAN_FORMAT_VERSION = 1

DEFAULT_CENTER_FRACTION: dict[str, tuple[float, float, float]] = {
    "floor": (-0.30, -0.45, 0.45),
    "wall": (-0.40, -0.50, 0.45),
    "ceiling": (-0.10, -0.35, 0.75),
}
"""Default pose-set centre per mount (every name of :data:`ftacq.mounts.MOUNTS`), as a fraction of the arm's reach
|a2| + |a3| (UR5e floor: (−0.245, −0.368, 0.368) m). Chosen so that all 24 cube rotations and the 40° cone are
reachable without collision, with the wrist clear of singularities, for every model in the table with a
0.05 × 0.1 m tool, except the CB3 UR3 and UR5 whose short wrists need a slimmer tool (UR5: 0.045 m) for all 24."""
MODEL_CENTER_FRACTION: dict[tuple[str, str], tuple[float, float, float]] = {
    ("UR3e", "floor"): (-0.30, -0.45, 0.55),
    ("UR3", "floor"): (-0.30, -0.45, 0.50),
}
"""Overrides of DEFAULT_CENTER_FRACTION for (model, mount): the small arms need the centre a little higher."""
ALTERNATIVE_CENTER_FRACTIONS: tuple[tuple[float, float, float], ...] = (
    (-0.30, -0.45, 0.50), (-0.30, -0.50, 0.45), (-0.25, -0.45, 0.45), (-0.40, -0.50, 0.30), (-0.20, -0.35, 0.75),
    (-0.10, -0.35, 0.75), (-0.30, -0.45, 0.40), (-0.40, -0.50, 0.45), (-0.30, -0.35, 0.60), (-0.20, -0.55, 0.45),
)
"""Tried in this order when no centre is given and the mount's default does not reach every pose."""

PLANNING_HYSTERESIS_M = 0.002
"""Extra clearance the planner keeps over the executor's re-check (more than the 0.5 mm tolerance of the certified
path check), so that a move planned clear is still clear when the executor re-checks it from the robot's actual,
slightly different, configuration."""
MAX_CENTERS_PLANNED = 3
"""When no centre is given: how many candidate centres (best static reachability first) are ordered and checked."""


@dataclass(frozen=True, eq=False)
class Plan:
    """A checked plan, in execution order (arrays are read-only copies).

    Attributes:
        poses: flange poses (N, 6) in the base frame. joint_targets_rad: IK solutions (N, 6), each joint the
            2π-equivalent nearest the previous target, or nearest the middle of its range where that one would
            come within JOINT_LIMIT_MARGIN_RAD of a limit. labels: "A07", "E13", "V02", "X01"… set_names: "A"/"E"/"V".
        rejected: (label, reason) of every pose left out. estimated_duration_s: moves + settle + averaging
            (+ the drift-check revisit). joint_travel_rad: weighted joint travel of this order from the start
            configuration; listing_travel_rad: the same for the listing order (A, E, V as generated).
        settings: the settings it was made from. center_m: the centre used. branch: the IK branch used (str).
        start_q_rad: the configuration the plan starts from.
        warnings: things the technician should know (e.g. the drift-check revisit move is blocked).
        revisit_target_rad: joint target (6,) for the drift-check revisit of the first pose: the same flange pose
            as ``joint_targets_rad[0]``, possibly another 2π-equivalent of it, chosen so that the move from the
            last pose is short and clear (checked); None when the settings have no drift check.
    """

    poses: np.ndarray
    joint_targets_rad: np.ndarray
    labels: tuple[str, ...]
    set_names: tuple[str, ...]
    rejected: tuple[tuple[str, str], ...]
    estimated_duration_s: float
    joint_travel_rad: float
    listing_travel_rad: float
    settings: PlanSettings
    center_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    branch: str = ""
    start_q_rad: tuple[float, ...] = field(default=(0.0,) * 6)
    warnings: tuple[str, ...] = ()
    revisit_target_rad: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        for name in ("poses", "joint_targets_rad"):
            arr = np.array(getattr(self, name), dtype=float).reshape(-1, 6)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def srom_ready(self) -> bool:
        """True when all 24 special poses (A01…A24) are in the plan (the SROM closed form needs all of them)."""
        return sum(1 for s in self.set_names if s == SPECIAL_SET) == 24

    def indices(self, set_name: str) -> np.ndarray:
        """Return the plan indices of the poses of one set ("A", "E" or "V")."""
        return np.array([i for i, s in enumerate(self.set_names) if s == set_name], dtype=int)

    def to_json(self) -> str:
        """Return the plan as JSON (the run folder stores it so --resume continues the same plan)."""
        return json.dumps({
            "format_version": PLAN_FORMAT_VERSION,
            "settings": self.settings.to_dict(),
            "labels": list(self.labels),
            "set_names": list(self.set_names),
            "poses": self.poses.tolist(),
            "joint_targets_rad": self.joint_targets_rad.tolist(),
            "rejected": [list(r) for r in self.rejected],
            "estimated_duration_s": self.estimated_duration_s,
            "joint_travel_rad": self.joint_travel_rad,
            "listing_travel_rad": self.listing_travel_rad,
            "center_m": list(self.center_m),
            "branch": self.branch,
            "start_q_rad": list(self.start_q_rad),
            "warnings": list(self.warnings),
            "revisit_target_rad": None if self.revisit_target_rad is None else list(self.revisit_target_rad),
        }, indent=1)

    @staticmethod
    def from_json(text: str) -> "Plan":
        """Rebuild a plan from :meth:`to_json`. Raises PlanError naming what is missing or inconsistent."""
        try:
            data = json.loads(text)
            if data.get("format_version") != PLAN_FORMAT_VERSION:
                raise PlanError(f"plan JSON: format_version {data.get('format_version')!r}, "
                                f"expected {PLAN_FORMAT_VERSION}")
            plan = Plan(
                poses=np.array(data["poses"], dtype=float).reshape(-1, 6),
                joint_targets_rad=np.array(data["joint_targets_rad"], dtype=float).reshape(-1, 6),
                labels=tuple(data["labels"]),
                set_names=tuple(data["set_names"]),
                rejected=tuple((str(a), str(b)) for a, b in data["rejected"]),
                estimated_duration_s=float(data["estimated_duration_s"]),
                joint_travel_rad=float(data["joint_travel_rad"]),
                listing_travel_rad=float(data["listing_travel_rad"]),
                settings=PlanSettings.from_dict(data["settings"]),
                center_m=_xyz(data["center_m"]),
                branch=str(data["branch"]),
                start_q_rad=tuple(float(v) for v in data["start_q_rad"]),
                warnings=tuple(str(w) for w in data.get("warnings", ())),
                revisit_target_rad=None if data.get("revisit_target_rad") is None
                else tuple(float(v) for v in data["revisit_target_rad"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, PlanError):
                raise
            raise PlanError(f"plan JSON is invalid: {exc!r}") from exc
        n = len(plan.labels)
        if not (len(plan.poses) == len(plan.joint_targets_rad) == len(plan.set_names) == n):
            raise PlanError(f"plan JSON is inconsistent: {n} labels, {len(plan.poses)} poses, "
                            f"{len(plan.joint_targets_rad)} joint targets, {len(plan.set_names)} set names")
        return plan


# ------------------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------------------

def _xyz(values) -> tuple[float, float, float]:
    """Three floats (x, y, z) from any 3-sequence."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def reach_m(model: URModel) -> float:
    """Return |a2| + |a3|: the distance from shoulder to wrist when stretched, m."""
    return abs(model.a[1]) + abs(model.a[2])


def _default_fraction(model: URModel, mount: str) -> tuple[float, float, float]:
    nominal = mount_of(mount).nominal  # a tilted mount takes the default of the nominal mount nearest its gravity
    return MODEL_CENTER_FRACTION.get((model.name, nominal), DEFAULT_CENTER_FRACTION[nominal])


def default_center_m(model: URModel | str, mount: str = "floor") -> np.ndarray:
    """Return the default centre (3,) of the pose sets for a model and mount, m (see DEFAULT_CENTER_FRACTION)."""
    model = ur_model(model) if isinstance(model, str) else model
    return reach_m(model) * np.array(_default_fraction(model, mount))


def home_configuration_rad(mount: str = "floor") -> np.ndarray:
    """Return a typical start configuration (6,): the UR "home" with the elbow up and the tool down (floor)."""
    del mount  # the same joint angles work as a start for every mount; kept for symmetry with default_center_m
    return np.array([np.pi / 2, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


def estimate_duration_s(settings: PlanSettings, start_q: np.ndarray, q_sequence: np.ndarray,
                        revisit_target: np.ndarray | None = None) -> float:
    """Return moves + (settle + averaging) per pose, plus the drift-check revisit of the first pose, s.

    ``revisit_target``: the joint target of the revisit (default the first target).
    """
    all_q = np.vstack([np.asarray(start_q, dtype=float)[None, :], q_sequence])
    moves = sum(move_duration_s(a, b, settings.joint_speed_rad_s, settings.joint_acceleration_rad_s2)
                for a, b in zip(all_q[:-1], all_q[1:]))
    per_pose = settings.settle_time_s + settings.average_time_s
    total = moves + len(q_sequence) * per_pose
    if settings.drift_check and len(q_sequence):
        target = q_sequence[0] if revisit_target is None else revisit_target
        total += move_duration_s(q_sequence[-1], target, settings.joint_speed_rad_s,
                             settings.joint_acceleration_rad_s2) + per_pose
    return float(total)


@lru_cache(maxsize=8)
def _checker(model: str, tool_radius_m: float, tool_length_m: float, mount: str, table_margin_m: float,
             clearance_m: float) -> CollisionChecker:
    return CollisionChecker(ur_model(model), tool_radius_m, tool_length_m, mount, table_margin_m, clearance_m)


def collision_checker(settings: PlanSettings, planning: bool = False) -> CollisionChecker:
    """Return the (cached) collision checker for the settings' arm, tool and mount.

    ``planning=True``: the planner's checker, with :data:`PLANNING_HYSTERESIS_M` more clearance and table margin
    than the executor's :func:`check_path`, so that a move planned clear stays clear when the executor re-checks
    it from the robot's actual (slightly different) configuration.
    """
    extra = PLANNING_HYSTERESIS_M if planning else 0.0
    return _checker(settings.model, settings.tool_radius_m, settings.tool_length_m, settings.mount,
                    settings.table_margin_m + extra, settings.clearance_m + extra)


def check_path(settings: PlanSettings, q_from: np.ndarray, q_to: np.ndarray) -> list[str]:
    """Return the collision and joint-limit problems along the moveJ q_from → q_to (sampled); empty = clear.

    The executor calls this before every move, so that nothing leaves the checked plan. ``q_from`` is where the
    arm is (its measured angles may lie MEASURED_ANGLE_TOLERANCE_RAD beyond a limit: encoder jitter); ``q_to`` is
    a planned target and must keep JOINT_LIMIT_MARGIN_RAD from every limit.
    """
    q_from, q_to = np.asarray(q_from, dtype=float).reshape(6), np.asarray(q_to, dtype=float).reshape(6)
    if not (np.all(np.isfinite(q_from)) and np.all(np.isfinite(q_to))):
        return ["joint values are not finite"]
    return collision_checker(settings).problems_along(q_from, q_to)


def build_pose_set(settings: PlanSettings, center_m: np.ndarray) -> PoseSet:
    """Return the listing-order pose set: A (if special), E, explicit (set "E", labels X01…), V."""
    nominal = None if settings.nominal_rotvec is None else rotation_from_rotvec(np.array(settings.nominal_rotvec))
    if nominal is None:
        nominal = tool_down_rotation(settings.mount)
    out = PoseSet.empty()
    if settings.special:
        out = out + special_poses(center_m)
    if settings.random_count:
        out = out + random_cone_poses(settings.random_count, settings.cone_half_angle_deg, nominal, center_m,
                                      settings.position_jitter_m, settings.seed, RANDOM_SET, settings.mount)
    if settings.explicit_poses:
        out = out + explicit_poses(np.array(settings.explicit_poses))
    if settings.validation_count:
        out = out + random_cone_poses(settings.validation_count, settings.cone_half_angle_deg, nominal, center_m,
                                      settings.position_jitter_m, settings.seed, VALIDATION_SET, settings.mount)
    return out


@dataclass
class _Candidate:
    center: np.ndarray
    poses: PoseSet
    branch: Branch
    q: list[np.ndarray | None]
    reasons: list[str]

    @property
    def ok_count(self) -> int:
        return sum(q is not None for q in self.q)


def _evaluate(settings: PlanSettings, center: np.ndarray, start_q: np.ndarray) -> _Candidate:
    """Solve and statically check every pose in all branches; return the best branch's outcome."""
    model = settings.ur
    checker = collision_checker(settings, planning=True)
    poses = build_pose_set(settings, center)
    per_branch: dict[Branch, tuple[list, list]] = {b: ([], []) for b in Branch.all()}
    results = solve_ik_batch(model, poses.poses, start_q)
    solved = [r.q_rad for by_branch in results for r in by_branch.values() if r.ok]
    clear = iter(_clear_at(checker, np.array(solved).reshape(-1, 6)))  # one batched check of every solution
    for by_branch in results:
        for b, result in by_branch.items():
            known_clear = next(clear) if result.ok else False
            per_branch[b][0].append(result.q_rad if known_clear else None)
            per_branch[b][1].append(result if result.ok and not known_clear else result.reason)
    start_branch = branch_of(model, start_q)
    weights = joint_weights(model)

    def score(b: Branch):
        qs = [q for q in per_branch[b][0] if q is not None]
        travel = min((float(np.abs(q - start_q) @ weights) for q in qs), default=np.inf)
        return (-len(qs), b != start_branch, travel)

    best = min(Branch.all(), key=score)
    qs = per_branch[best][0]
    # the collision messages only for the branch kept (most of a cramped cell's solutions collide)
    reasons = [_collision_reason(checker, r) if isinstance(r, IKResult) else r for r in per_branch[best][1]]
    for i, q in enumerate(qs):  # say when another branch would have reached a rejected pose
        if q is None:
            others = [b for b in Branch.all() if per_branch[b][0][i] is not None]
            if others:
                reasons[i] += f" (reachable in branch {others[0]}, but not without a flip from branch {best})"
    return _Candidate(center, poses, best, qs, reasons)


def _clear_at(checker: CollisionChecker, q_rad: np.ndarray) -> np.ndarray:
    """Return, per configuration (S, 6), whether it is certainly clear (S,) bool: every clearance ≥ 0 and every
    joint inside its limits less the planning margin, from one vectorised evaluation (the messages of the others
    come from :meth:`CollisionChecker.problems_at`, one configuration at a time)."""
    if not len(q_rad):
        return np.zeros(0, dtype=bool)
    lower, upper = planning_limits_rad(checker.model)
    inside = np.all((q_rad >= lower) & (q_rad <= upper), axis=1)
    return inside & np.all(checker.clearances(q_rad) >= 0.0, axis=1)


def _collision_reason(checker: CollisionChecker, result: IKResult) -> str:
    """Why a solution the batched check found in collision or at a limit is rejected (problems, one line)."""
    assert result.q_rad is not None  # only solutions are checked
    problems = checker.problems_at(result.q_rad) or ["a clearance within rounding of its limit"]
    return "collision: " + "; ".join(problems)


def _minimum_problems(settings: PlanSettings, candidate: _Candidate, keep: list[bool]) -> list[str]:
    """Return why the kept poses are not enough (empty = enough)."""
    names = candidate.poses.set_names
    n_ident = sum(1 for k, s in zip(keep, names) if k and s in IDENTIFICATION_SETS)
    n_a = sum(1 for k, s in zip(keep, names) if k and s == SPECIAL_SET)
    n_v = sum(1 for k, s in zip(keep, names) if k and s == VALIDATION_SET)
    problems = []
    need = min(settings.min_identification_poses, sum(1 for s in names if s in IDENTIFICATION_SETS))
    if n_ident < need:
        problems.append(f"only {n_ident} identification poses (A + E) remain, at least {need} needed")
    if settings.require_srom and settings.special and n_a < 24:
        problems.append(f"only {n_a} of the 24 special poses remain; SROM needs all 24 (require_srom)")
    if settings.validation_count and n_v == 0:
        problems.append("no validation pose (V) remains")
    return problems


def _candidate_centers(settings: PlanSettings) -> list[np.ndarray]:
    if settings.center_m is not None:
        return [np.array(settings.center_m)]
    reach = reach_m(settings.ur)
    default = _default_fraction(settings.ur, settings.mount)
    fractions = [default] + [f for f in ALTERNATIVE_CENTER_FRACTIONS if f != default]
    return [reach * np.array(f) for f in fractions]


def make_plan(settings: PlanSettings, start_q_rad: np.ndarray) -> Plan:
    """Build, check and order the pose plan from the robot's current configuration ``start_q_rad`` (6,), rad.

    Raises:
        PlanError: not enough poses remain; its message lists every rejected pose with its reason.
        ConfigError: bad settings (raised by PlanSettings).
    """
    start_q = np.asarray(start_q_rad, dtype=float).reshape(6)
    model = settings.ur
    lower, upper = np.array(model.joint_min_rad), np.array(model.joint_max_rad)
    tolerance = MEASURED_ANGLE_TOLERANCE_RAD  # the start is measured: its angles jitter
    if not np.all(np.isfinite(start_q)) or np.any(start_q < lower - tolerance) or np.any(start_q > upper + tolerance):
        raise PlanError(f"start configuration {np.round(start_q, 4).tolist()} rad is outside the joint limits")
    start_problems = collision_checker(settings).problems_at(start_q, measured=True)
    if start_problems:
        raise PlanError("the robot's current configuration is too close to a collision in the planner's model ("
                        + "; ".join(start_problems) + "): jog it clear (e.g. to the home configuration) and plan again")
    best_plan: Plan | None = None
    first_error = ""
    planned = 0
    for center in _candidate_centers(settings):
        candidate = _evaluate(settings, center, start_q)  # static checks only: cheap
        if best_plan is not None and candidate.ok_count <= len(best_plan):
            continue  # cannot beat the best plan so far
        plan, error = _plan_from(settings, candidate, start_q)  # ordering and path checks: the costly part
        planned += 1
        if plan is None:
            first_error = first_error or error
        elif best_plan is None or len(plan) > len(best_plan):
            best_plan = plan
        if (best_plan is not None and not best_plan.rejected) or planned >= MAX_CENTERS_PLANNED:
            break
    if best_plan is None:
        raise PlanError(first_error)
    return best_plan


def _plan_from(settings: PlanSettings, candidate: _Candidate, start_q: np.ndarray) -> tuple[Plan | None, str]:
    """Order and check the statically feasible poses of one candidate; return (plan, "") or (None, why not)."""
    model = settings.ur
    poses = candidate.poses
    keep = [q is not None for q in candidate.q]
    rejected: list[tuple[str, str]] = [(poses.labels[i], candidate.reasons[i]) for i, k in enumerate(keep) if not k]
    problems = _minimum_problems(settings, candidate, keep)
    if problems:
        return None, _plan_error_message(problems, rejected, candidate.center)
    kept = [i for i, k in enumerate(keep) if k]
    q_kept = np.array([candidate.q[i] for i in kept])
    graph = MoveGraph(collision_checker(settings, planning=True), model, start_q, q_kept)
    order, q_exec, dropped = order_and_check(graph, [poses.labels[i] for i in kept], settings.drift_check)
    for local, reason in dropped:
        keep[kept[local]] = False
        rejected.append((poses.labels[kept[local]], reason))
    problems = _minimum_problems(settings, candidate, keep)
    if problems:
        return None, _plan_error_message(problems, rejected, candidate.center)
    chosen = [kept[i] for i in order]
    warnings = []
    revisit = None
    if settings.drift_check and len(q_exec):
        revisit, problem = revisit_target(collision_checker(settings, planning=True), model, q_exec)
        if problem:
            warnings.append(f"the drift-check revisit of {poses.labels[chosen[0]]} is blocked: {problem}")
    weights = joint_weights(model)
    listing = [i for i in kept if keep[i]]
    q_listing = listing_targets(model, start_q, np.array([candidate.q[i] for i in listing]))
    return Plan(
        poses=poses.poses[chosen],
        joint_targets_rad=q_exec,
        labels=tuple(poses.labels[i] for i in chosen),
        set_names=tuple(poses.set_names[i] for i in chosen),
        rejected=tuple(rejected),
        estimated_duration_s=estimate_duration_s(settings, start_q, q_exec, revisit),
        joint_travel_rad=path_travel(start_q, q_exec, weights),
        listing_travel_rad=path_travel(start_q, q_listing, weights),
        settings=settings,
        center_m=_xyz(candidate.center),
        branch=str(candidate.branch),
        start_q_rad=tuple(float(v) for v in start_q),
        warnings=tuple(warnings),
        revisit_target_rad=None if revisit is None else tuple(float(v) for v in revisit),
    ), ""


def _plan_error_message(problems: list[str], rejected: list[tuple[str, str]], center: np.ndarray) -> str:
    lines = ["the pose plan cannot proceed: " + "; ".join(problems),
             f"centre {np.round(center, 3).tolist()} m; {len(rejected)} pose(s) rejected:"]
    lines += [f"  {label}: {reason}" for label, reason in rejected]
    return "\n".join(lines)


def _minutes(seconds: float) -> str:
    return f"{int(seconds // 60)} min {seconds % 60:04.1f} s"


def format_plan(plan: Plan) -> str:
    """Return the plan as text for the terminal: poses per set, rejected poses, duration, travel, limits."""
    s = plan.settings
    counts = {name: sum(1 for x in plan.set_names if x == name) for name in PLANNED_SETS}
    wanted = {SPECIAL_SET: 24 if s.special else 0,
              RANDOM_SET: s.random_count + (len(s.explicit_poses) if s.explicit_poses else 0),
              VALIDATION_SET: s.validation_count}
    lines = [
        f"Pose plan for {s.model} ({s.mount} mount), centre "
        f"({', '.join(f'{v:+.3f}' for v in plan.center_m)}) m, IK branch {plan.branch}",
        f"  tool cylinder r = {s.tool_radius_m:.3f} m, length {s.tool_length_m:.3f} m; "
        f"mounting-surface margin {s.table_margin_m * 1000:.0f} mm",
        "  poses: " + ", ".join(f"{name} {counts[name]}/{wanted[name]}" for name in PLANNED_SETS if wanted[name])
        + f"  (total {len(plan)})",
        "  SROM closed form: " + ("available (all 24 special poses)" if plan.srom_ready
                                   else "not available (LROM + refinement only)"),
    ]
    lines += [f"  warning: {w}" for w in plan.warnings]
    if plan.rejected:
        lines.append(f"  rejected {len(plan.rejected)}:")
        lines += [f"    {label}: {reason}" for label, reason in plan.rejected]
    saving = 100.0 * (1.0 - plan.joint_travel_rad / plan.listing_travel_rad) if plan.listing_travel_rad else 0.0
    lines += [
        f"  joint travel: {plan.joint_travel_rad:.1f} rad in this order, {plan.listing_travel_rad:.1f} rad in "
        f"listing order ({saving:.0f} % shorter)",
        f"  limits: joint speed {s.joint_speed_rad_s:.2f} rad/s, acceleration {s.joint_acceleration_rad_s2:.2f} rad/s²; "
        f"every target at least {np.degrees(JOINT_LIMIT_MARGIN_RAD):.0f}° inside each joint limit",
        f"  estimated duration: {_minutes(plan.estimated_duration_s)} (settle {s.settle_time_s:.1f} s + average "
        f"{s.average_time_s:.1f} s per pose" + (", drift-check revisit of the first pose" if s.drift_check else "")
        + ")",
        "  order: " + " ".join(plan.labels),
    ]
    return "\n".join(lines)


__all__ = ["PlanSettings", "Plan", "make_plan", "format_plan", "check_path", "default_center_m",
           "home_configuration_rad", "collision_checker", "build_pose_set", "UR_MODELS"]
