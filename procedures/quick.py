"""The quick calibration's trajectory: designed by the Fisher information of every parameter, checked along its whole
path, then run and recorded as one continuous motion (``ftacq calibrate --quick``, docs/quick.md).

Design (:func:`design_quick`). The waypoints come from the full run's checked pose plan (:func:`procedures.plan.make_plan`):
its 24 special orientations (set A) put gravity along ±x, ±y, ±z of the flange, four spins each, all reachable
and collision-free from this cell's centre. A candidate trajectory is one A pose per gravity direction (a random
spin; optionally a few more), in nearest-neighbour order from the robot's configuration, with a still hold at
each (lengths shared out below), then :data:`VALIDATION_HOLDS` poses of the plan's validation set (V) held still
and never fitted. Between waypoints the arm moves by moveJ at the CELL.toml joint speed and acceleration (the
wrist turns fast: that is what shows the inertia). Each candidate is sampled at :data:`DESIGN_RATE_HZ` and scored
by log det of the Fisher information JᵀWJ of all 21 parameters of :mod:`ftacq.dynamics.joint` and the streams'
lag (22 columns: the lag is fitted too, and a trajectory that cannot tell it from the rotation is a bad one) at a
nominal tool
(the CELL.toml cylinder, 1 kg), W the noise model (at rest the sensor's noise; while moving it grows by
:data:`MOTION_NOISE_PER_RAD_S` per rad/s of joint speed, as the fit's speed groups measure). D-optimality is
invariant to the parameters' units, so no scaling has to be chosen.

Which candidate is run: the one whose predicted 1σ is smallest relative to the full run's, at its worst
parameter (:func:`predicted_sigmas`: the inverse of that information, rotation, tilt, mass, mass moment, force and
torque biases; the full run's from the same pose plan's fitted poses, each averaged still for
``sampling.average_time_s``, the same noise model). So the design answers the question the quick run is judged by
(is it as precise as the full run?) and spends the budget where the weakest parameter gains: the still holds,
whose rows carry the sensor's bare noise (no motion noise, no timing error) with gravity along a flange axis,
carry the biases, the mass, the rotation and the tilt; the moves between them carry the inertia and the lag.
Among the candidates within :data:`DEFAULT_BUDGET_S` of motion the lowest worst ratio is kept (ties: log det).

Recording (:func:`record_quick`) is the motion runner's (procedures/motion_runner.py, the excitation stage's too:
the sensor in its own thread, every robot state, events to the listeners; the sensor's times from its own sample counter, the robot's from the
controller's timestamps, both put on the host clock by the minimum-delay line there and nowhere else); each hold
is a count of robot states at the stream's RTDE rate, so its window is known in the robot's own samples.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ftacq.dynamics.identify import MotionRecord
from ftacq.kinematics.trapezoid import move_duration_s, move_profile
from ftacq.dynamics.joint import LINEAR, NONLINEAR
from ftacq.errors import PlanError
from ftacq.posesets import IDENTIFICATION_SETS, QUICK_SET, SPECIAL_SET, VALIDATION_SET
from procedures import events

log = logging.getLogger(__name__)

DEFAULT_BUDGET_S = 66.0
"""Longest motion (moves and holds, validation included) a design may take, s: with the plan (~1-2 s), the
identification (~4-5 s) and what a loaded computer adds to the moves (~4 s), about 76 s of the 90 s wall-time goal."""
CANDIDATES = 32
"""Candidate trajectories scored per design."""
MIN_HOLD_S = 0.4
"""Every fitted waypoint is held at least this long, s (a moveJ's end settles; the rest of the budget is shared
out by :data:`HOLD_QUANTUM_S`)."""
HOLD_QUANTUM_S = 0.4
"""The budget left after the moves is given to the holds in steps of this, s, each step to the waypoint where it
lowers the worst predicted 1σ ratio most (a hold's second is worth about four seconds of motion for the static
parameters: the motion noise is ×(1 + 2 s/rad · speed))."""
EXTRA_WAYPOINTS = (0, 1, 2)
"""Waypoints beyond one per gravity direction a candidate may add."""
TOUR_CHOICES = 2
"""A candidate's next waypoint is one of this many quickest to reach (random): short tours, still diverse."""
VALIDATION_HOLDS = 3
"""Still validation poses at the end (the verdict's held-out poses)."""
VALIDATION_HOLD_S = 1.0
DESIGN_RATE_HZ = 25.0
"""Sampling of a candidate for its Fisher information."""
MOTION_NOISE_PER_RAD_S = 2.0
"""The design's noise model: sensor noise × (1 + this × fastest joint speed) while moving."""
NOMINAL_NOISE = np.array([0.05, 0.05, 0.08, 0.002, 0.002, 0.0015])
"""1σ of one sample at rest per channel (N, N·m), a Net F/T's typical figure, for the design only."""
FIT, VALIDATE = "fit", "validate"
SIGMA_GROUPS = {"rotation": (0, 1, 2), "tilt": (3, 4), "mass": (5,), "mass moment": (6, 7, 8),
                "force bias": (15, 16, 17), "torque bias": (18, 19, 20)}
"""The parameters both runs report, as columns of the fit's (θ, x) vector (:mod:`ftacq.dynamics.joint`); a group's
1σ is the root sum of squares of its columns' (the benchmark's too)."""


@dataclass(frozen=True)
class QuickPlan:
    """A designed, checked trajectory: moveJ waypoints (K, 6) rad from ``start_q_rad``, each followed by a hold of
    ``hold_s`` (K,) s; ``purposes`` "fit" or "validate" (validation holds are never fitted); the last waypoint is
    followed by nothing. ``information_logdet`` the design's score; ``estimated_duration_s`` the motion's length."""

    start_q_rad: np.ndarray
    waypoints_rad: np.ndarray
    hold_s: np.ndarray
    purposes: tuple[str, ...]
    labels: tuple[str, ...]
    speed_rad_s: float
    acceleration_rad_s2: float
    estimated_duration_s: float
    information_logdet: float
    candidates: int
    seed: int = 0
    predicted_sigma_ratio: dict[str, float] = field(default_factory=dict)
    """Per :data:`SIGMA_GROUPS` entry: the design's predicted 1σ over the full run's (the choice's criterion)."""

    @property
    def set_names(self) -> tuple[str, ...]:
        """Each waypoint's pose set (:data:`ftacq.posesets.POSE_SETS`): validation holds V, the others Q."""
        return tuple(VALIDATION_SET if p == VALIDATE else QUICK_SET for p in self.purposes)

    def to_json(self) -> str:
        return json.dumps({"start_q_rad": self.start_q_rad.tolist(), "waypoints_rad": self.waypoints_rad.tolist(),
                           "hold_s": self.hold_s.tolist(), "purposes": list(self.purposes),
                           "labels": list(self.labels),
                           "set_names": list(self.set_names), "speed_rad_s": self.speed_rad_s,
                           "acceleration_rad_s2": self.acceleration_rad_s2,
                           "estimated_duration_s": self.estimated_duration_s,
                           "information_logdet": self.information_logdet, "candidates": self.candidates,
                           "seed": self.seed, "predicted_sigma_ratio": self.predicted_sigma_ratio})

    @staticmethod
    def from_json(text: str) -> "QuickPlan":
        d = json.loads(text)
        return QuickPlan(np.array(d["start_q_rad"]), np.array(d["waypoints_rad"]), np.array(d["hold_s"]),
                         tuple(d["purposes"]), tuple(d["labels"]), float(d["speed_rad_s"]),
                         float(d["acceleration_rad_s2"]), float(d["estimated_duration_s"]),
                         float(d["information_logdet"]), int(d["candidates"]), int(d.get("seed", 0)),
                         {str(k): float(v) for k, v in d.get("predicted_sigma_ratio", {}).items()})


def sample_trajectory(start_q: np.ndarray, waypoints: np.ndarray, hold_s: np.ndarray, speed: float,
                      acceleration: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, q̇, q̈, waypoint index (−1 while moving)) of a trajectory sampled at ``rate_hz``."""
    parts: list[tuple[np.ndarray, ...]] = []
    t0, q = 0.0, np.asarray(start_q, dtype=float)
    for k, (target, hold) in enumerate(zip(waypoints, hold_s)):
        duration = move_duration_s(q, target, speed, acceleration)
        times = np.arange(0.0, duration, 1.0 / rate_hz)
        qs, qds, qdds = move_profile(q, target, speed, acceleration, times)
        parts.append((t0 + times, qs, qds, qdds, np.full(times.size, -1)))
        n_hold = int(round(hold * rate_hz))
        if n_hold:
            parts.append((t0 + duration + np.arange(n_hold) / rate_hz, np.tile(target, (n_hold, 1)),
                          np.zeros((n_hold, 6)), np.zeros((n_hold, 6)), np.full(n_hold, k)))
        t0 += duration + hold
        q = np.asarray(target, dtype=float)
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(5))  # type: ignore[return-value]


def nominal_tool(settings) -> tuple[float, np.ndarray, np.ndarray]:
    """The design's nominal tool: 1 kg, a solid cylinder of the CELL.toml tool's radius and length."""
    mass, r, length = 1.0, float(settings.tool_radius_m), max(float(settings.tool_length_m), 0.02)
    lateral = mass * (3 * r * r + length * length) / 12.0
    return mass, np.array([0.0, 0.0, 0.5 * length]), np.diag([lateral, lateral, 0.5 * mass * r * r])


def information(settings, t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                lag: bool = True) -> np.ndarray:
    """The Fisher information JᵀWJ (22, 22) of the 21 parameters of :mod:`ftacq.dynamics.joint` and the streams'
    lag (the last; left out, (21, 21), with ``lag=False``) over these states at times ``t`` (s), at the nominal
    tool, W from :data:`NOMINAL_NOISE` grown by :data:`MOTION_NOISE_PER_RAD_S` while moving. Rows are states at
    the rate of ``t``: only ratios between designs sampled at the same rate mean something."""
    from ftacq.dynamics.joint import JointModel
    from ftacq.dynamics.model import inertial_parameters
    from ftacq.mounts import mount_of

    mass, com, inertia = nominal_tool(settings)
    model = JointModel(settings.ur, np.zeros(3), q, qd, qdd, np.eye(3), np.array(mount_of(settings.mount).down_base))
    x = np.concatenate([inertial_parameters(mass, com, inertia), np.zeros(6)])
    sigma = NOMINAL_NOISE[None, :] * (1.0 + MOTION_NOISE_PER_RAD_S * np.max(np.abs(qd), axis=1))[:, None]
    a, jacobian = model.design(x)
    if lag:
        jacobian = np.concatenate([jacobian, -np.gradient(a @ x, t, axis=0)[:, :, None]], axis=2)
    jacobian = (jacobian / sigma[:, :, None]).reshape(-1, jacobian.shape[2])
    return jacobian.T @ jacobian


def information_logdet(settings, t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> float:
    """log det of :func:`information` (all 21 parameters and the lag)."""
    sign, logdet = np.linalg.slogdet(information(settings, t, q, qd, qdd))
    return float(logdet) if sign > 0 else -np.inf


def predicted_sigmas(fisher: np.ndarray, columns: list[int] | None = None) -> dict[str, float]:
    """Per :data:`SIGMA_GROUPS` entry, the 1σ the information ``fisher`` predicts (its inverse; ``columns``: which
    parameter each of its rows is, default all 22 in order). inf when singular."""
    columns = list(range(fisher.shape[0])) if columns is None else columns
    try:
        covariance = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:
        return {name: np.inf for name in SIGMA_GROUPS}
    diagonal = dict(zip(columns, np.diag(covariance)))
    return {name: float(np.sqrt(max(sum(diagonal[c] for c in cols), 0.0))) for name, cols in SIGMA_GROUPS.items()}


def worst_ratios(fishers: np.ndarray, reference: dict[str, float]) -> np.ndarray:
    """max over :data:`SIGMA_GROUPS` of (predicted 1σ / ``reference``'s) for each information matrix of ``fishers``
    (K, 22, 22) at once: :func:`predicted_sigmas` batched (the quick design tries every hold at every step). inf
    where one is singular."""
    try:
        variances = np.diagonal(np.linalg.inv(fishers), axis1=1, axis2=2)
    except np.linalg.LinAlgError:
        return np.array([max(s / reference[k] if reference[k] > 0 else np.inf for k, s in
                             predicted_sigmas(f).items()) for f in fishers])
    worst = np.full(len(fishers), -np.inf)
    for name, columns in SIGMA_GROUPS.items():
        sigma = np.sqrt(np.maximum(sum(variances[:, c] for c in columns), 0.0))
        worst = np.maximum(worst, sigma / reference[name] if reference[name] > 0 else np.inf)
    return worst


def full_run_sigmas(settings, pose_plan) -> dict[str, float]:
    """The full run's predicted 1σ per :data:`SIGMA_GROUPS` entry: its fitted poses (sets A and E) each averaged
    still for ``sampling.average_time_s`` at :data:`DESIGN_RATE_HZ` (the static model: the inertia and the lag are
    not seen, so left out)."""
    fitted = [i for i, name in enumerate(pose_plan.set_names) if name in IDENTIFICATION_SETS]
    rows = max(int(round(float(settings.average_time_s) * DESIGN_RATE_HZ)), 1)
    q = np.repeat(np.asarray(pose_plan.joint_targets_rad)[fitted], rows, axis=0)
    still = np.zeros_like(q)
    fisher = information(settings, np.arange(len(q)) / DESIGN_RATE_HZ, q, still, still, lag=False)
    static = [c for c in range(fisher.shape[0]) if not NONLINEAR + 4 <= c < NONLINEAR + 10]  # inertia left out
    return predicted_sigmas(fisher[np.ix_(static, static)], static)


def _gravity_classes(settings, targets: np.ndarray) -> np.ndarray:
    """Which flange axis (0..5: +x, −x, +y, −y, +z, −z) gravity points along at each joint target."""
    from ftacq.kinematics import forward_kinematics
    from ftacq.mounts import mount_of

    down = np.array(mount_of(settings.mount).down_base)
    out = []
    for q in targets:
        g_flange = forward_kinematics(settings.ur, q)[:3, :3].T @ down
        axis = int(np.argmax(np.abs(g_flange)))
        out.append(2 * axis + (0 if g_flange[axis] > 0 else 1))
    return np.array(out)


def _greedy_tour(rng: np.random.Generator, start: np.ndarray, special: list[int], classes: np.ndarray,
                 targets: np.ndarray, extra: int, speed: float, acceleration: float) -> list[int]:
    """One candidate order: from the robot's configuration, repeatedly one of the :data:`TOUR_CHOICES` quickest
    poses of a gravity direction not yet visited (at random among them), then ``extra`` more special poses the
    same way."""
    order: list[int] = []
    q, missing = start, set(range(6))
    while missing or extra > 0:
        options = [i for i, c in zip(special, classes) if i not in order and (c in missing or not missing)]
        if not options:
            break
        cost = np.array([move_duration_s(q, targets[i], speed, acceleration) for i in options])
        nearest = np.argsort(cost)[:TOUR_CHOICES]
        pick = options[int(rng.choice(nearest))]
        if not missing:
            extra -= 1
        missing.discard(int(classes[special.index(pick)]))
        order.append(pick)
        q = targets[pick]
    return order


def _tour(start: np.ndarray, targets: list[int], joint_targets: np.ndarray) -> list[int]:
    """Nearest-neighbour order (largest joint move) from ``start``."""
    order, q, left = [], start, list(targets)
    while left:
        nearest = min(left, key=lambda i: float(np.max(np.abs(joint_targets[i] - q))))
        order.append(nearest)
        left.remove(nearest)
        q = joint_targets[nearest]
    return order


def check_quick(settings, start_q: np.ndarray, waypoints: np.ndarray) -> list[str]:
    """Joint limits and collisions (tool cylinder, links, table) along every move of the trajectory."""
    from procedures.plan import check_path

    problems, q = [], np.asarray(start_q, dtype=float)
    for k, target in enumerate(waypoints):
        problems += [f"move {k + 1}: {p}" for p in check_path(settings, q, target)]
        q = target
    return problems


def design_quick(settings, start_q_rad: np.ndarray, pose_plan=None, budget_s: float = DEFAULT_BUDGET_S,
                 candidates: int = CANDIDATES, seed: int = 0) -> QuickPlan:
    """Design the quick trajectory from ``start_q_rad`` (module docstring). ``pose_plan`` is the full run's plan
    (:func:`procedures.plan.make_plan`; made here when None). Raises PlanError when no candidate is clear."""
    from procedures.plan import make_plan

    start = np.asarray(start_q_rad, dtype=float).reshape(6)
    plan = pose_plan if pose_plan is not None else make_plan(settings, start)
    special = [i for i, s in enumerate(plan.set_names) if s == SPECIAL_SET]
    validation = [i for i, s in enumerate(plan.set_names) if s == VALIDATION_SET]
    if not special:
        raise PlanError("the quick calibration needs the special orientations (CELL.toml poses.special = true)")
    targets = np.asarray(plan.joint_targets_rad)
    classes = _gravity_classes(settings, targets[special])
    if len(set(classes.tolist())) < 6:
        raise PlanError("the plan does not reach gravity along all six flange directions; the quick calibration "
                        "needs them (move the pose centre)")
    speed, acceleration = float(settings.joint_speed_rad_s), float(settings.joint_acceleration_rad_s2)
    reference = full_run_sigmas(settings, plan)
    still = {}  # pose index -> information of one second held still there (22, 22)

    def still_information(index: int) -> np.ndarray:
        if index not in still:
            q = np.tile(targets[index], (int(DESIGN_RATE_HZ), 1))
            fisher = np.zeros((NONLINEAR + LINEAR + 1,) * 2)
            zero = np.zeros_like(q)
            fisher[:-1, :-1] = information(settings, np.arange(len(q)) / DESIGN_RATE_HZ, q, zero, zero, lag=False)
            still[index] = fisher
        return still[index]

    def ratios_of(fisher: np.ndarray) -> dict[str, float]:
        sigmas = predicted_sigmas(fisher)
        return {k: sigmas[k] / reference[k] if reference[k] > 0 else np.inf for k in SIGMA_GROUPS}

    def allocate(order: list[int], moving: np.ndarray, seconds: float) -> tuple[np.ndarray, np.ndarray]:
        """Holds (len(order),) s adding up to ``seconds`` in :data:`HOLD_QUANTUM_S` steps, each step where it
        lowers the worst predicted 1σ ratio most (the information is additive: a hold of h s at a pose adds h
        times that pose's still information); and the total information."""
        holds, fisher = np.zeros(len(order)), moving.copy()
        steps = HOLD_QUANTUM_S * np.stack([still_information(i) for i in order])  # (K, 22, 22)
        for _ in range(int(seconds / HOLD_QUANTUM_S + 1e-9)):
            trials = fisher + steps
            k = int(np.argmin(worst_ratios(trials, reference)))
            holds[k] = round(holds[k] + HOLD_QUANTUM_S, 3)
            fisher = trials[k]
        return holds, fisher

    rng = np.random.default_rng(seed)
    best: tuple[tuple[float, float], list[int], float, dict[str, float], np.ndarray] | None = None
    shortest: tuple[float, list[int]] | None = None
    scored = 0
    for _ in range(candidates):
        order = _greedy_tour(rng, start, special, classes, targets, int(rng.choice(EXTRA_WAYPOINTS)), speed,
                             acceleration)
        checks = _tour(targets[order[-1]], validation, targets)[:VALIDATION_HOLDS] if validation else []
        waypoints = targets[order + checks]
        moves = sum(move_duration_s(a, b, speed, acceleration)
                    for a, b in zip(np.vstack([start, waypoints])[:-1], waypoints))
        fixed = moves + VALIDATION_HOLD_S * len(checks)
        if check_quick(settings, start, waypoints):
            continue
        if fixed + MIN_HOLD_S * len(order) > budget_s:  # kept in case no candidate fits (slow CELL.toml speeds)
            if shortest is None or fixed < shortest[0]:
                shortest = (fixed, order + checks)
            continue
        t, q, qd, qdd, _ = sample_trajectory(start, targets[order], np.zeros(len(order)), speed, acceleration,
                                             DESIGN_RATE_HZ)
        moving = information(settings, t, q, qd, qdd)
        floor = np.full(len(order), MIN_HOLD_S)
        moving = moving + sum(MIN_HOLD_S * still_information(i) for i in order)
        holds, fisher = allocate(order, moving, budget_s - fixed - float(floor.sum()))
        holds = np.round(holds + floor, 3)
        ratios = ratios_of(fisher)
        sign, logdet = np.linalg.slogdet(fisher)
        key = (max(ratios.values()), float(logdet) if sign > 0 else -np.inf)
        scored += 1
        if best is None or (key[0], -key[1]) < (best[0][0], -best[0][1]):
            all_holds = np.concatenate([holds, np.full(len(checks), VALIDATION_HOLD_S)])
            best = (key, order + checks, fixed + float(holds.sum()), ratios, all_holds)
    if best is None and shortest is not None:  # the CELL.toml speeds make every candidate longer: the shortest
        fixed, indices = shortest
        n_fit = len(indices) - min(VALIDATION_HOLDS, len(validation))
        all_holds = np.array([MIN_HOLD_S] * n_fit + [VALIDATION_HOLD_S] * (len(indices) - n_fit))
        duration = fixed + MIN_HOLD_S * n_fit
        log.warning("no quick trajectory fits in %.0f s at these joint speeds; the shortest takes %.0f s",
                    budget_s, duration)
        t, q, qd, qdd, _ = sample_trajectory(start, targets[indices[:n_fit]], all_holds[:n_fit], speed,
                                             acceleration, DESIGN_RATE_HZ)
        fisher = information(settings, t, q, qd, qdd)
        ratios = ratios_of(fisher)
        best, scored = ((max(ratios.values()), float(np.linalg.slogdet(fisher)[1])), indices, duration, ratios,
                        all_holds), 1
    if best is None:
        raise PlanError("no quick trajectory is clear of collisions and joint limits from this configuration; "
                        "use the full calibration")
    (_, logdet), indices, duration, ratios, best_holds = best
    n_fit = len(indices) - min(VALIDATION_HOLDS, len(validation))
    return QuickPlan(start, targets[indices].copy(), best_holds,
                     tuple([FIT] * n_fit + [VALIDATE] * (len(indices) - n_fit)),
                     tuple(plan.labels[i] for i in indices), speed, acceleration, float(duration), logdet,
                     scored, seed, {k: round(float(v), 4) for k, v in ratios.items()})


def format_quick(plan: QuickPlan) -> str:
    """A few lines for the operator: what will move, how fast, how long."""
    fit = sum(1 for p in plan.purposes if p == FIT)
    span = np.ptp(np.vstack([plan.start_q_rad, plan.waypoints_rad]), axis=0)
    holds = [float(h) for h, p in zip(plan.hold_s, plan.purposes) if p == FIT]
    ratios = plan.predicted_sigma_ratio
    worst = (f"≤ {max(ratios.values()):.2f}× ({max(ratios, key=ratios.__getitem__)} the largest)" if ratios
             else "against")
    return (f"Quick calibration plan: one continuous motion through {fit} waypoints (gravity along every flange "
            f"axis; held still {min(holds):g}-{max(holds):g} s each, {sum(holds):.1f} s in all), then {len(plan.purposes) - fit} still validation "
            f"poses ({VALIDATION_HOLD_S:g} s each)\n"
            f"  chosen by the Fisher information of all 21 parameters and the lag among {plan.candidates} checked "
            f"candidates: predicted 1σ {worst} the full run's (log det {plan.information_logdet:.1f})\n"
            f"  joint speed {plan.speed_rad_s:g} rad/s, acceleration {plan.acceleration_rad_s2:g} rad/s²; joint "
            f"ranges (rad): " + " ".join(f"{v:.2f}" for v in span) + "\n"
            f"  every move checked for joint limits and collisions along its path: clear\n"
            f"  estimated duration: {plan.estimated_duration_s:.1f} s")


@dataclass(frozen=True)
class QuickRecording:
    """The recorded motion and each hold's window in robot samples [start, end) (K, 2) (−1 when not reached)."""

    record: MotionRecord
    hold_rows: np.ndarray
    completed: int


def record_quick(plan: QuickPlan, robot, sensor, stream, move_timeout_s: float = 60.0,
                 listeners: Sequence[events.Listener] = ()) -> QuickRecording:
    """Run the plan while recording (:func:`procedures.motion_runner.run_waypoints`, the excitation stage's runner,
    which publishes the run's events to ``listeners``: a hold is a "holding" state of its waypoint, in the set
    :attr:`QuickPlan.set_names` gives it); return the recording. Ctrl-C or a fault stops the robot; the partial recording
    is attached to the raised exception as ``error.quick_recording``."""
    from procedures.motion_runner import run_waypoints

    try:
        run = run_waypoints(robot, sensor, stream, plan.waypoints_rad, plan.speed_rad_s, plan.acceleration_rad_s2,
                            hold_s=plan.hold_s, move_timeout_s=move_timeout_s, labels=plan.labels,
                            set_names=plan.set_names, listeners=listeners)
    except BaseException as error:
        partial = getattr(error, "motion_run", None)
        if partial is not None:
            error.quick_recording = QuickRecording(partial.record, partial.holds, partial.completed)  # type: ignore[attr-defined]
        raise
    return QuickRecording(run.record, run.holds, run.completed)


__all__ = ["QuickPlan", "QuickRecording", "design_quick", "check_quick", "format_quick", "record_quick",
           "sample_trajectory", "move_profile", "information", "information_logdet", "predicted_sigmas", "full_run_sigmas",
           "SIGMA_GROUPS"]
