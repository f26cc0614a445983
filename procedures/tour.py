"""Tour ordering: the order in which the robot visits the planned poses, and the joint moves between them.

The poses are nodes of a graph whose node 0 is the robot's start configuration; the cost of a move is its
speed-weighted joint travel (:func:`joint_weights`: proportional to the time the joints need at rated speed). The
order is a nearest-neighbour tour from the start, improved by 2-opt segment reversals (:func:`two_opt`). Every
move of that order is then checked for collisions along its path (:class:`MoveGraph`, cached, trying a wrist or
the base the long way round when the shortest move collides); a colliding move is penalised and the order
re-optimised, and a pose that no order reaches cleanly is dropped with its reason (:func:`order_and_check`).
The drift-check revisit of the first pose at the end is made clear by rotating the cycle or a 2-opt step on its
closing move (:func:`clear_revisit`, :func:`revisit_target`).

Joint limits: every target keeps :data:`ftacq.kinematics.JOINT_LIMIT_MARGIN_RAD` from each limit. A move takes
each joint the shortest way (a ±360° wrist may wind past ±180°); where that would leave the range less the
margin, the joint goes instead to the 2π-equivalent nearest the middle of its range
(:func:`ftacq.kinematics.middle_equivalent`), and that move is checked as it is. Without the margin, winding put
targets exactly on a limit (q6 = ±360° after a few cube rotations), where the encoders' jitter reads them outside.

Nothing here knows about pose sets or settings: :mod:`procedures.plan` builds the poses, solves their IK and
hands the joint configurations, the collision checker and the model to this module.
"""

from __future__ import annotations

import numpy as np

from ftacq.kinematics import URModel, middle_equivalent, planning_limits_rad
from procedures.collision import CollisionChecker
from ftacq.kinematics.ik import TWO_PI

COLLIDING_EDGE_PENALTY_RAD = 1e3
"""Cost added to a joint move that failed the path check, so the 2-opt avoids it."""
MAX_REORDER_ROUNDS = 20
"""Re-orderings tried (each avoiding the moves found colliding so far) before a pose is dropped."""
MAX_REVISIT_ROTATIONS = 40
"""Rotations of the tour tried to clear a blocked drift-check revisit move."""
MAX_2OPT_PASSES = 50
"""2-opt passes over the tour at most (each pass applies the best reversal found from every position)."""


def joint_weights(model: URModel) -> np.ndarray:
    """Return the per-joint weights of the travel metric: slowest rated joint speed / rated speed of each joint.

    With them, weighted travel (rad) is proportional to the time the joints need at rated speed.
    """
    speeds = np.array(model.max_joint_speed_rad_s)
    return speeds.min() / speeds


def path_travel(start_q: np.ndarray, q_sequence: np.ndarray, weights: np.ndarray) -> float:
    """Return the weighted joint travel of start → q_sequence[0] → … (rad)."""
    all_q = np.vstack([np.asarray(start_q, dtype=float)[None, :], q_sequence])
    return float((np.abs(np.diff(all_q, axis=0)) @ weights).sum())


def nearest_neighbour_order(dist: np.ndarray) -> list[int]:
    """Return a path over nodes 1..M−1 starting from node 0, greedily nearest first (indices into dist)."""
    m = dist.shape[0]
    unvisited = set(range(1, m))
    order = [0]
    while unvisited:
        last = order[-1]
        nxt = min(unvisited, key=lambda j: dist[last, j])
        order.append(nxt)
        unvisited.remove(nxt)
    return order


def two_opt(order: list[int], dist: np.ndarray, max_passes: int = MAX_2OPT_PASSES) -> list[int]:
    """Improve an open path with a fixed first node by 2-opt segment reversals until no move shortens it."""
    tour = np.array(order)
    n = len(tour)
    for _ in range(max_passes):
        improved = False
        for i in range(1, n - 1):
            a, b = tour[i - 1], tour[i]
            js = np.arange(i + 1, n)
            c = tour[js]
            d_next = np.where(js + 1 < n, dist[c, tour[np.minimum(js + 1, n - 1)]], 0.0)
            e_new = np.where(js + 1 < n, dist[b, tour[np.minimum(js + 1, n - 1)]], 0.0)
            delta = dist[a, c] + e_new - dist[a, b] - d_next
            k = int(np.argmin(delta))
            if delta[k] < -1e-12:
                j = js[k]
                tour[i:j + 1] = tour[i:j + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return tour.tolist()


def angle_delta(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """Return the shortest signed per-joint move from q_from to an equivalent of q_to, each in (−π, π] rad."""
    return np.angle(np.exp(1j * (np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float))))


ALTERNATIVE_MOVE_JOINTS = (5, 3, 0, 4)
"""Joints (0-based: wrist 3, wrist 1, base, wrist 2) tried the long way round (δ ∓ 2π) when the shortest move
collides: turning the wrist the other way often takes the tool round the outside of the forearm."""


class MoveGraph:
    """Moves between poses (node 0 = the start configuration) with their path checks, cached.

    The geometry of a move is 2π-periodic in every joint, so a move is checked once as (from-node, delta) from
    the canonical configuration; joint limits (less the planning margin) are checked on the actual targets of a
    sequence.
    """

    def __init__(self, checker: CollisionChecker, model: URModel, start_q: np.ndarray, q: np.ndarray) -> None:
        self.model = model
        self.checker = checker
        self.weights = joint_weights(self.model)
        self.lower, self.upper = planning_limits_rad(self.model)
        self.nodes = np.vstack([start_q[None, :], q])
        self.delta = angle_delta(self.nodes[:, None, :], self.nodes[None, :, :])  # (n, n, 6), δ[a, b]
        self.delta[0, :] = angle_delta(start_q, self.nodes)  # from the start
        self.cost = np.abs(self.delta) @ self.weights
        self.bad: dict[tuple[int, int], str] = {}
        self._checked: dict[tuple, list[str]] = {}

    def _check(self, a: int, move: np.ndarray) -> list[str]:
        key = (a, tuple(np.round(move, 9)))
        if key not in self._checked:
            self._checked[key] = self.checker.problems_along(self.nodes[a], self.nodes[a] + move, check_limits=False)
        return self._checked[key]

    def move(self, a: int, b: int) -> np.ndarray:
        """Return the joint move a → b (shortest unless an alternative replaced a colliding one)."""
        return self.delta[a, b]

    def check_edge(self, a: int, b: int) -> bool:
        """Check the move a → b; if it collides try the alternatives; return True when clear (updates cost)."""
        key = (min(a, b), max(a, b))
        if key in self.bad:
            return False
        problems = self._check(a, self.delta[a, b])
        if not problems:
            return True
        for j in ALTERNATIVE_MOVE_JOINTS:
            move = self.delta[a, b].copy()
            if move[j] == 0.0:
                continue
            move[j] -= np.sign(move[j]) * TWO_PI
            if not self._check(a, move):
                self._set(a, b, move)
                return True
        self.bad[key] = problems[0]
        return False

    def _set(self, a: int, b: int, move: np.ndarray) -> None:
        self.delta[a, b] = move
        self.cost[a, b] = np.abs(move) @ self.weights
        if a != 0 and b != 0:
            self.delta[b, a] = -move
            self.cost[b, a] = self.cost[a, b]

    def sequence(self, path: list[int]) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Return the actual joint targets along ``path`` (node 0 first) and the moves that failed a check.

        A joint whose target would leave the joint limits less the planning margin goes to its 2π-equivalent
        nearest the middle of its range instead (:func:`ftacq.kinematics.middle_equivalent`), and that move is
        checked as it is.
        """
        q = self.nodes[0].copy()
        out = []
        failed = []
        for a, b in zip(path[:-1], path[1:]):
            ok = self.check_edge(a, b)
            target = q + self.move(a, b)
            outside = (target < self.lower) | (target > self.upper)
            if outside.any():
                target = np.where(outside, middle_equivalent(target, self.lower, self.upper), target)
                problems = self.checker.problems_along(q, target)
                if problems:
                    self.bad[(min(a, b), max(a, b))] = problems[0]
                    ok = False
            if not ok:
                failed.append((a, b))
            target = np.clip(target, self.lower, self.upper)  # only rounding: farther out was moved above
            out.append(target)
            q = target
        return np.array(out).reshape(-1, 6), failed


def order_and_check(graph: MoveGraph, labels: list[str],
                    revisit: bool) -> tuple[list[int], np.ndarray, list[tuple[int, str]]]:
    """Order the poses of ``graph`` (indices into its poses, node i + 1), check each move along its path, and return
    the joint targets. ``revisit``: also make the drift-check revisit of the first pose clear where possible.

    Returns (order, joint targets in that order, rejected) where rejected lists (index, reason) of poses dropped
    because no tour found avoided a colliding move into them.
    """
    active = list(range(len(graph.nodes) - 1))
    rejected: list[tuple[int, str]] = []
    while True:
        sub = [0] + [i + 1 for i in active]
        for _ in range(MAX_REORDER_ROUNDS):
            dist = graph.cost[np.ix_(sub, sub)].copy()
            for (a, b) in graph.bad:
                if a in sub and b in sub:
                    ia, ib = sub.index(a), sub.index(b)
                    dist[ia, ib] += COLLIDING_EDGE_PENALTY_RAD
                    dist[ib, ia] += COLLIDING_EDGE_PENALTY_RAD
            # the first move leaves the start: its cost is directed, the rest symmetric
            tour = two_opt(nearest_neighbour_order(dist), dist)
            path = [sub[t] for t in tour]
            targets, failed = graph.sequence(path)
            if not failed:
                if revisit:
                    path, targets = clear_revisit(graph, path, targets)
                return [p - 1 for p in path[1:]], targets, rejected
        # drop the pose with the most colliding moves found so far (ties: the pose the first failed move enters)
        bad_count: dict[int, int] = {}
        for (a, b) in graph.bad:
            for node in (a, b):
                if node != 0 and (node - 1) in active:
                    bad_count[node] = bad_count.get(node, 0) + 1
        first_a, first_b = failed[0]
        worst = max(bad_count, key=lambda node: (bad_count[node], node == first_b))
        a, b = next(((x, y) if y == worst else (y, x)) for (x, y) in graph.bad if worst in (x, y))
        frm = "the start configuration" if a == 0 else labels[a - 1]
        rejected.append((worst - 1, f"no collision-free joint move found (e.g. from {frm}: "
                                    f"{graph.bad[(min(a, b), max(a, b))]})"))
        active.remove(worst - 1)
        if not active:
            return [], np.empty((0, 6)), rejected


def clear_revisit(graph: MoveGraph, path: list[int], targets: np.ndarray) -> tuple[list[int], np.ndarray]:
    """Make the drift-check revisit (last target → first target, as the executor moves) clear if possible.

    The poses are taken as a cycle: the cycle is started at another pose (either direction), or its closing move
    is exchanged by a 2-opt step, cheapest first, until every move and the revisit are clear. Returns the path
    unchanged if none is (the plan then carries a warning).
    """
    def revisit_clear(t: np.ndarray) -> bool:
        return len(t) < 2 or not revisit_target(graph.checker, graph.model, t)[1]

    if revisit_clear(targets):
        return path, targets
    cycle = path[1:]
    cost = graph.cost
    options = []
    for direction in (cycle, cycle[::-1]):  # rotations of the cycle: another pose first
        for k in range(1, len(direction)):
            rotated = direction[k:] + direction[:k]
            options.append((cost[0, rotated[0]] + cost[direction[-1], direction[0]], [0] + rotated))
    for m in range(1, len(cycle) - 1):  # 2-opt on the closing move: p1…pm, pN…pm+1, then back to p1
        changed = cycle[:m] + cycle[m:][::-1]
        added = cost[cycle[m - 1], cycle[-1]] + cost[cycle[m], cycle[0]] - cost[cycle[m - 1], cycle[m]]
        options.append((cost[0, changed[0]] + added, [0] + changed))
    options.sort(key=lambda option: option[0])
    for _, candidate in options[:MAX_REVISIT_ROTATIONS]:
        candidate_targets, failed = graph.sequence(candidate)
        if not failed and revisit_clear(candidate_targets):
            return candidate, candidate_targets
    return path, targets


def listing_targets(model: URModel, start_q: np.ndarray, q_sequence: np.ndarray) -> np.ndarray:
    """Return the joint targets of a sequence moved through with the shortest joint moves (within the limits less
    the planning margin; a joint that would leave them goes to its equivalent nearest the middle of its range)."""
    lower, upper = planning_limits_rad(model)
    out = np.empty_like(q_sequence)
    q = np.asarray(start_q, dtype=float)
    for i, target in enumerate(q_sequence):
        nxt = q + angle_delta(q, target)
        outside = (nxt < lower) | (nxt > upper)
        nxt = np.where(outside, middle_equivalent(nxt, lower, upper), nxt)
        out[i] = q = np.clip(nxt, lower, upper)
    return out


def revisit_target(checker: CollisionChecker, model: URModel, q_exec: np.ndarray) -> tuple[np.ndarray, str]:
    """Return (joint target for revisiting the first pose, "" or why every candidate move is blocked).

    Candidates, in order: the first target itself, then its 2π-equivalent nearest the last target (shortest
    move), then that with one wrist or base joint the long way round; each within the limits less the planning
    margin (:func:`ftacq.kinematics.planning_limits_rad`) and checked clear.
    """
    lower, upper = planning_limits_rad(model)
    last, first = q_exec[-1], q_exec[0]
    shortest = last + angle_delta(last, first)
    candidates = [first, shortest]
    for j in ALTERNATIVE_MOVE_JOINTS:
        alternative = shortest.copy()
        if alternative[j] != last[j]:
            alternative[j] -= np.sign(alternative[j] - last[j]) * TWO_PI
            candidates.append(alternative)
    first_problem = ""
    for candidate in candidates:
        if np.any(candidate < lower) or np.any(candidate > upper):
            continue
        candidate = np.clip(candidate, lower, upper)
        problems = checker.problems_along(last, candidate)
        if not problems:
            return candidate, ""
        first_problem = first_problem or problems[0]
    return first, first_problem or "no equivalent of the first pose within the joint limits"


__all__ = ["joint_weights", "path_travel", "angle_delta", "nearest_neighbour_order", "two_opt", "MoveGraph",
           "order_and_check", "clear_revisit", "revisit_target", "listing_targets", "ALTERNATIVE_MOVE_JOINTS"]
