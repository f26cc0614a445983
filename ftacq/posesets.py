"""The pose sets of a calibration run (A, E, V, D; Q for a quick run, M for a motion): the one table every layer reads.

Each measured pose belongs to one set, written in the ``set`` column of a pose record (:mod:`ftacq.posefile`):

- ``A``: the 24 special orientations (cube rotations, paper eqs 14-23), identified on (SROM needs all 24);
- ``E``: random orientations in a cone, and the user's explicit poses (labels ``X01``…), identified on;
- ``V``: validation poses, held out: never identified on, compensated with the result to measure its error;
- ``D``: the drift-check revisit of the first pose at the end of a run, held out (it measures the bias drift);
- ``Q``: the quick run's designed orientations (``calibrate --quick``), identified on (its held-out poses are V);
- ``M``: the waypoints of a recorded motion (the excitation stage): the motion is identified on, never a pose alone.

Whether a set is identified on, and its colour in the dashboard and the report, come from :data:`POSE_SETS`;
nothing else names the rule. A new set is one row here (and, if the planner makes it, its generator in
``procedures.plan_settings.build_pose_set``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PoseSetKind:
    """One pose set: its one-letter ``name``, a ``title`` for people, ``colour_rgb`` (0-255) for plots, and
    ``identify``: True when its poses are identified on (False: held out)."""

    name: str
    title: str
    colour_rgb: tuple[int, int, int]
    identify: bool


POSE_SETS: dict[str, PoseSetKind] = {s.name: s for s in (
    PoseSetKind("A", "special orientations", (38, 103, 230), True),
    PoseSetKind("E", "random orientations in the cone", (240, 160, 30), True),
    PoseSetKind("Q", "quick design", (148, 103, 189), True),
    PoseSetKind("V", "validation (held out)", (42, 157, 90), False),
    PoseSetKind("D", "drift-check revisit (held out)", (214, 39, 40), False),
    PoseSetKind("M", "motion waypoints (not measured still)", (127, 127, 127), False),
)}
"""Every pose set by name, in the order reports list them."""

UNKNOWN_SET_COLOUR_RGB = (160, 160, 160)
"""Colour of poses whose set is unknown (a pose record without a ``set`` column)."""
SPECIAL_SET, RANDOM_SET, VALIDATION_SET, DRIFT_SET, QUICK_SET, MOTION_SET = "A", "E", "V", "D", "Q", "M"
"""The names the planner, the procedure, the quick run and the motion runner produce (each a row of
:data:`POSE_SETS`)."""
IDENTIFICATION_SETS: tuple[str, ...] = tuple(s.name for s in POSE_SETS.values() if s.identify)
"""Sets identified on (A, E, Q)."""
HELD_OUT_SETS: tuple[str, ...] = tuple(s.name for s in POSE_SETS.values() if not s.identify)
"""Sets never identified on as still poses (V, D, M)."""
PLANNED_SETS: tuple[str, ...] = (SPECIAL_SET, RANDOM_SET, VALIDATION_SET)
"""Sets a plan contains, in the order the plan summary lists them."""


def spread_hold_out(count: int, fraction: float) -> np.ndarray:
    """Return a boolean mask over ``count`` poses that holds out round(``fraction`` × count) of them (at least
    one), spread evenly over the record's order, so that they span its orientations and its time (a recording
    imported without sets: ``ftacq identify --hold-out``)."""
    held = max(1, int(round(fraction * count)))
    mask = np.zeros(count, dtype=bool)
    mask[np.unique(np.floor((np.arange(held) + 0.5) * count / held).astype(int))] = True
    return mask


def is_identified_on(set_name: str) -> bool:
    """True when poses of ``set_name`` are identified on (an unknown or empty set name counts as identified on:
    a pose record without sets is all identification data). Case and surrounding spaces are ignored."""
    kind = POSE_SETS.get(set_name.strip().upper())
    return True if kind is None else kind.identify


def set_colour_rgb(set_name: str) -> tuple[int, int, int]:
    """Return the plot colour (0-255 RGB) of a set, grey when unknown."""
    kind = POSE_SETS.get(set_name)
    return UNKNOWN_SET_COLOUR_RGB if kind is None else kind.colour_rgb


__all__ = ["PoseSetKind", "POSE_SETS", "IDENTIFICATION_SETS", "HELD_OUT_SETS", "PLANNED_SETS", "SPECIAL_SET",
           "RANDOM_SET", "VALIDATION_SET", "DRIFT_SET", "QUICK_SET", "MOTION_SET", "UNKNOWN_SET_COLOUR_RGB", "is_identified_on",
           "set_colour_rgb", "spread_hold_out"]
