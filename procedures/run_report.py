r"""The run report: ``report.md`` with PNG plots (matplotlib, Agg backend: no display needed).

Sections: summary, identified parameters with 1σ (the core's text report), validation per-axis max and RMS,
drift check, and the plots:

- ``wrench_per_pose.png``: raw mean wrench per measured pose (six channels) and the compensated wrench (raw −
  predicted gravity wrench − biases; ≈ 0 without contact);
- ``residuals.png``: identification residual norms |F|, |T| per pose, outliers marked;
- ``validation.png``: compensation error per V pose and axis, and each pose's d² against the verdict's one-pose
  limit (the verdict's own test, :func:`ftacq.verdict.validation_finding`: a pose above the line is a WARN), so
  the plot and the verdict cannot disagree;
- ``wrench_over_motion.png`` (quick run): raw and compensated wrench over the whole motion.

The quick run's report (:func:`write_quick_report`) has the same sections: verdict first (and "not saved" above
it when the calibration was not saved), parameters with 1σ (the rotation as Z-Y-X angles and the matrix),
validation and the plots.

Every text is at least :data:`MIN_FONT_PT` at the saved size (figures are saved at :data:`FIGURE_DPI` without
rescaling; the residual plot widens with the number of poses so that one label per pose stays readable).
Markdown tables escape ``|`` in their cells (``max \|error\|``), so each row has as many cells as the rule.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Sequence

import numpy as np

from ftacq import __version__
from ftacq.channels import AXES, LABELS, UNITS, WRENCH_COLUMNS
from ftacq.fileio import atomic_write
from ftacq.posesets import POSE_SETS, set_colour_rgb

FIGURE_DPI = 110
MIN_FONT_PT = 10.0
"""Smallest text in the report's plots, points at the saved size."""
LABEL_PITCH_IN = 0.2
"""Width per pose label on a per-pose axis (a rotated 10 pt label is about 0.17 in tall)."""


def _colour(set_name: str) -> tuple[float, float, float]:
    """The matplotlib colour (0-1 RGB) of a pose set (:mod:`ftacq.posesets`)."""
    r, g, b = set_colour_rgb(set_name)
    return (r / 255.0, g / 255.0, b / 255.0)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": MIN_FONT_PT, "axes.titlesize": MIN_FONT_PT + 1,
                         "legend.fontsize": MIN_FONT_PT, "xtick.labelsize": MIN_FONT_PT,
                         "ytick.labelsize": MIN_FONT_PT})
    return plt


def _pose_axis_width_in(count: int, minimum_in: float = 12.0) -> float:
    """Figure width that leaves :data:`LABEL_PITCH_IN` per pose label plus margins."""
    return max(minimum_in, 2.0 + LABEL_PITCH_IN * count)


def _save(fig, path: Path) -> None:
    """Save ``fig`` (laid out by its ``tight_layout()``) as a PNG at :data:`FIGURE_DPI`.

    ``tight_layout()`` leaves a placeholder layout engine on the figure, and with any engine ``savefig`` draws the
    whole figure once more (without output) before drawing it for the file: dropping the engine skips that pass
    (a third of the save) and changes no pixel, the layout is already applied."""
    fig.set_layout_engine(None)
    with atomic_write(path, mode="wb") as handle:
        fig.savefig(handle, format="png", dpi=FIGURE_DPI)


def plot_wrench_per_pose(path: Path, labels: Sequence[str], sets: Sequence[str], raw: np.ndarray,
                         compensated: np.ndarray | None, band: np.ndarray | None = None) -> None:
    """Write the raw and compensated mean wrench per pose (N, 6) as a 6-panel PNG (raw only when
    ``compensated`` is None: a stopped or failed run has no calibration to compensate with). ``band`` (6,) is
    the typical expected error per axis (± k σ), shaded around the compensated panels' zero line for scale; the
    verdict's test is the d² of validation.png."""
    plt = _pyplot()
    columns = [(raw, "raw mean")] + ([] if compensated is None else [(compensated, "compensated")])
    fig, axes = plt.subplots(6, len(columns), figsize=(6 * len(columns), 12), sharex=True, squeeze=False)
    x = np.arange(len(labels))
    colours = [_colour(s) for s in sets]
    for k in range(6):
        for col, (data, title) in enumerate(columns):
            ax = axes[k, col]
            ax.scatter(x, data[:, k], c=colours, s=12, zorder=2)
            ax.axhline(0.0, color="black", lw=0.5)
            if band is not None and col == 1:
                ax.axhspan(-band[k], band[k], color="lightgray", zorder=0)
            ax.set_ylabel(f"{AXES[k]} [{UNITS[k]}]")
            if k == 0:
                ax.set_title(f"{title} (colour = pose set)"
                             + ("; grey: ± 3σ expected" if band is not None and col == 1 else ""))
    for name in sorted(set(sets), key=lambda s: list(POSE_SETS).index(s) if s in POSE_SETS else len(POSE_SETS)):
        kind = POSE_SETS.get(name)
        axes[0, -1].scatter([], [], color=_colour(name), s=12, label=f"{name}: {kind.title}" if kind else name or "?")
    axes[0, -1].legend(loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("pose (execution order)")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def plot_residuals(path: Path, labels: Sequence[str], residuals: np.ndarray, outliers: Sequence[str]) -> None:
    """Write the identification residual norms per pose as a PNG (outliers in red)."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(_pose_axis_width_in(len(labels)), 7), sharex=True)
    x = np.arange(len(labels))
    colours = ["tab:red" if label in set(outliers) else "tab:blue" for label in labels]
    axes[0].bar(x, np.linalg.norm(residuals[:, :3], axis=1), color=colours)
    axes[0].set_ylabel("|F residual| [N]")
    axes[1].bar(x, np.linalg.norm(residuals[:, 3:], axis=1), color=colours)
    axes[1].set_ylabel("|T residual| [N·m]")
    axes[1].set_xticks(x)
    axes[1].set_xticklabels(labels, rotation=90)
    axes[1].set_xlim(-0.6, len(labels) - 0.4)
    axes[0].set_title("identification residuals (measured − predicted); red = outlier")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def plot_validation(path: Path, labels: Sequence[str], errors: np.ndarray, test: dict | None = None) -> dict | None:
    """Write the compensation error per validation pose and axis as a PNG.

    ``test`` is the verdict's validation figures (:func:`ftacq.verdict.validation_finding`: ``pose_d2``,
    ``pose_d2_limit``, ``chi2``, ``dof``, ``p_value``); with it a third panel draws each pose's d² (its error
    against its predicted covariance) and the one-pose limit, the verdict's own test: a pose above the line is the
    verdict's WARN. Returns what that panel drew (``labels``, ``d2``, ``limit``, ``beyond``), or None without it.
    """
    plt = _pyplot()
    errors = np.asarray(errors, dtype=float).reshape(-1, 6)
    panels = 3 if test is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(max(12.0, 4.5 * panels + 0.3 * len(labels)), 4.8))
    x = np.arange(len(labels))
    width = 0.25
    for k in range(3):
        for ax, channel in ((axes[0], k), (axes[1], 3 + k)):
            ax.bar(x + (k - 1) * width, errors[:, channel], width * 0.9, label=AXES[channel], zorder=2)
    axes[0].set_ylabel("force error [N]")
    axes[1].set_ylabel("torque error [N·m]")
    drawn = None
    if test is not None:
        d2 = np.asarray(test["pose_d2"], dtype=float)
        limit = float(test["pose_d2_limit"])
        beyond = d2 > limit
        axes[2].bar(x, d2, 0.6, color=np.where(beyond, "tab:red", "tab:green").tolist(), zorder=2)
        axes[2].axhline(limit, color="black", ls="--", lw=1.0, label=f"one-pose limit {limit:.1f}")
        axes[2].set_ylabel("d² (error vs its expected covariance)")
        axes[2].set_title(f"the verdict's test: χ² = {test['chi2']:.1f} on {test['dof']} dof, "
                          f"p = {test['p_value']:.2g}")
        drawn = {"labels": [str(label) for label in labels], "d2": d2.tolist(), "limit": limit,
                 "beyond": [str(label) for label, b in zip(labels, beyond) if b]}
    for ax in axes:
        ax.set_xticks(x)
        ax.set_xticklabels(labels, rotation=90)
        ax.axhline(0.0, color="black", lw=0.5)
        ax.legend()
    fig.suptitle("validation: compensated wrench at held-out poses (should be ≈ 0)"
                 + ("; right: above the line = WARN" if test is not None else ""))
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return drawn


def validation_dict(validated) -> dict:
    """Return a :class:`procedures.events.Validated` in the core's form (:func:`ftacq.report.validation_errors`)."""
    errors = np.asarray(validated.errors, dtype=float).reshape(-1, 6)
    return {
        "labels": list(validated.labels),
        "columns": list(WRENCH_COLUMNS),
        "errors": errors.tolist(),
        "max_abs": np.asarray(validated.max_abs).tolist(),
        "rms": np.asarray(validated.rms).tolist(),
        "max_force_norm": float(np.linalg.norm(errors[:, :3], axis=1).max()) if len(errors) else 0.0,
        "max_torque_norm": float(np.linalg.norm(errors[:, 3:], axis=1).max()) if len(errors) else 0.0,
    }


def _cell(text: str) -> str:
    """A Markdown table cell: ``|`` escaped, or it would split the cell (GitHub-flavoured Markdown)."""
    return str(text).replace("|", "\\|")


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    out = ["| " + " | ".join(map(_cell, header)) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(map(_cell, row)) + " |" for row in rows]
    return out


def format_truth_comparison(calibration, truth) -> str:
    """Return identified parameters beside the simulation's true ones (text table, SI units)."""
    from ftacq.report import _zyx_deg

    unc = calibration.uncertainty

    def vec(v, digits=4, scale=1.0):
        return "[" + ", ".join(f"{x * scale:+.{digits}f}" for x in v) + "]"

    def sig(key, digits=4, scale=1.0):
        s = unc.get(key)
        if s is None:
            return ""
        return "± [" + ", ".join(f"{x * scale:.{digits}f}" for x in np.atleast_1d(s)) + "]"

    rows = [
        ("sensor_rotation Z-Y-X (deg)", vec(_zyx_deg(calibration.sensor_rotation), 3),
         vec(_zyx_deg(truth.sensor_rotation), 3), sig("sensor_rotation_rad", 3, 180.0 / np.pi) + " about x, y, z"
         if unc.get("sensor_rotation_rad") is not None else ""),
        ("force_bias (N)", vec(calibration.force_bias), vec(truth.force_bias), sig("force_bias")),
        ("torque_bias (N·m)", vec(calibration.torque_bias, 5), vec(truth.torque_bias, 5), sig("torque_bias", 5)),
        ("mass (kg)", f"{calibration.mass_kg:.5f}", f"{truth.mass_kg:.5f}", sig("mass_kg", 5)),
        ("center_of_mass (mm)", vec(calibration.center_of_mass, 3, 1000), vec(truth.center_of_mass, 3, 1000),
         sig("center_of_mass_m", 3, 1000)),
        ("base_tilt α, β (deg)", vec(calibration.base_tilt_deg, 4), vec(truth.base_tilt_deg, 4),
         sig("base_tilt_deg", 4)),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"{'parameter':<{width}}  {'identified':<36} {'true (simulation)':<36} 1σ"]
    lines += [f"{name:<{width}}  {got:<36} {true:<36} {sigma}" for name, got, true, sigma in rows]
    return "\n".join(lines)


def _verdict_section(verdict) -> list[str]:
    """The report's first section: the verdict, the reasons in plain words, then the checks' details."""
    lines = [f"## Verdict: **{verdict.status}**", ""]
    lines += [f"- **{f.status}** {f.check}: {f.summary}" for f in verdict.findings]
    lines += ["", "<details><summary>how each check was made</summary>", ""]
    lines += [f"- {f.check}: {f.details}" for f in verdict.findings if f.details]
    lines += ["", "</details>", ""]
    return lines


def _band(verdict) -> np.ndarray | None:
    """Return ± k σ of the validation poses' expected error (M, 6) from the verdict, or None (a scale for the
    wrench plot; the test itself is the d² of :func:`plot_validation`)."""
    finding = None if verdict is None else verdict.finding("validation")
    if finding is None or "expected_sigma" not in finding.figures:
        return None
    return finding.figures["band_sigmas"] * np.asarray(finding.figures["expected_sigma"], dtype=float)


def _validation_test(verdict, labels: Sequence[str]) -> dict | None:
    """Return the verdict's validation figures when they are about these ``labels``, else None."""
    finding = None if verdict is None else verdict.finding("validation")
    if finding is None or "pose_d2" not in finding.figures or list(finding.figures.get("labels", [])) != list(labels):
        return None
    return finding.figures


def write_report(folder: Path, result, plan, config: dict, *, truth=None, title: str = "ftacq calibration",
                 verdict=None) -> Path:
    """Write ``report.md`` and its PNGs into ``folder`` for a :class:`procedures.calibration_procedure.ProcedureResult`.

    Returns the report's path. ``verdict`` (:class:`ftacq.verdict.Verdict`) opens the report and gives the
    plots their acceptance band. Without identification the report lists what was measured and plots the raw
    wrenches.
    """
    from ftacq.report import format_identification_report

    folder = Path(folder)
    ident = result.identification
    band = _band(verdict)
    lines = [f"# {title}", ""] + ([] if verdict is None else _verdict_section(verdict)) + [
             f"- created: {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')} "
             f"(ftacq {__version__})",
             f"- status: **{result.status}** — {result.message}",
             f"- robot: {config.get('robot', {}).get('model', '?')} ({config.get('robot', {}).get('mount', '?')} "
             f"mount) at {config.get('robot', {}).get('host', '?')}; sensor {config.get('sensor', {}).get('url', '?')}",
             f"- poses measured: {sum(1 for label in plan.labels if label in result.measured)} of {len(plan)} "
             f"planned" + (" + the drift-check revisit" if f"{plan.labels[0]}-revisit" in result.measured else "")
             + f"; estimated duration on a real robot {plan.estimated_duration_s:.0f} s", ""]
    if result.warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in result.warnings] + [""]
    order = [label for label in list(plan.labels) + [f"{plan.labels[0]}-revisit"] if label in result.measured]
    if ident is not None:
        cal = ident.calibration
        lines += ["## Identified parameters (value ± 1σ)", "", "```", format_identification_report(
                      ident, validation=None if result.validation is None else validation_dict(result.validation)
                  ).rstrip(),
                  "```", ""]
        if truth is not None:
            lines += ["## Against the simulation's ground truth", "", "```",
                      format_truth_comparison(cal, truth), "```", ""]
        raw = np.array([result.measured[label].mean for label in order])
        poses = np.array([result.measured[label].pose for label in order])
        from ftacq.so3 import rotation_from_rotvec

        flange_R_base = np.swapaxes(rotation_from_rotvec(poses[:, 3:]), -1, -2)
        compensated = np.asarray(cal.compensate(raw, flange_R_base)).reshape(-1, 6)
        sets = [result.measured[label].set_name for label in order]
        typical_band = None if band is None else np.median(band, axis=0)
        plot_wrench_per_pose(folder / "wrench_per_pose.png", order, sets, raw, compensated, typical_band)
        plot_residuals(folder / "residuals.png", list(ident.labels), np.asarray(ident.residuals), ident.outliers)
        lines += ["## Raw and compensated wrench per pose", "", "![raw and compensated](wrench_per_pose.png)", "",
                  "## Identification residuals", "", "![residuals](residuals.png)", ""]
    elif order:  # a stopped or failed run: the raw wrenches measured so far
        raw = np.array([result.measured[label].mean for label in order])
        sets = [result.measured[label].set_name for label in order]
        plot_wrench_per_pose(folder / "wrench_per_pose.png", order, sets, raw, None)
        lines += ["## Raw wrench per measured pose", "", "![raw wrench](wrench_per_pose.png)", ""]
    if result.validation is not None:
        v = result.validation
        lines += ["## Validation on held-out poses (V)", "",
                  f"{len(v.labels)} poses never used for identification, compensated with the calibration:", ""]
        lines += _table(["axis", "max |error|", "RMS error", "unit"],
                        [(AXES[k], f"{v.max_abs[k]:.5f}", f"{v.rms[k]:.5f}", UNITS[k]) for k in range(6)])
        plot_validation(folder / "validation.png", list(v.labels), np.asarray(v.errors),
                        _validation_test(verdict, [str(label) for label in v.labels]))
        lines += ["", "![validation](validation.png)", ""]
    if result.drift is not None:
        d = result.drift
        lines += ["## Drift check", "",
                  f"Pose {d.label} measured again after {d.elapsed_s:.0f} s: bias drift "
                  f"F [{', '.join(f'{x:+.4f}' for x in d.drift[:3])}] N, "
                  f"T [{', '.join(f'{x:+.5f}' for x in d.drift[3:])}] N·m"
                  + (f". **{d.warning}**" if d.warning else " (below the warning thresholds)."), ""]
    elif getattr(result, "drift_skipped", ""):
        lines += ["## Drift check", "", f"**Not made**: {result.drift_skipped}. The calibration uses every pose "
                  "measured before it; the sensor's drift over the run is unknown.", ""]
    lines += ["## Measured poses", ""]
    lines += _table(["label", "set", "count", *LABELS],
                    [(label, result.measured[label].set_name, str(result.measured[label].count),
                      *[f"{x:+.4f}" for x in result.measured[label].mean]) for label in order])
    path = folder / "report.md"
    with atomic_write(path) as handle:
        handle.write("\n".join(lines) + "\n")
    return path


def plot_wrench_over_motion(path: Path, time_s: np.ndarray, raw: np.ndarray, compensated: np.ndarray) -> None:
    """Write raw and compensated wrench (N, 6) over time (s) as a 6-panel PNG (the quick run's motion)."""
    plt = _pyplot()
    fig, axes = plt.subplots(6, 1, figsize=(12, 12), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(time_s, raw[:, k], lw=0.6, color="tab:gray", label="raw")
        ax.plot(time_s, compensated[:, k], lw=0.6, color="tab:blue", label="compensated")
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_ylabel(f"{AXES[k]} [{UNITS[k]}]")
    axes[0].legend(loc="upper right")
    axes[0].set_title("raw and compensated (gravity and inertia) wrench over the motion; compensated ≈ 0 "
                      "without contact")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


MOTION_PLOT_POINTS = 6000
"""The motion plot draws at most this many samples per channel (every k-th)."""


def _quick_parameters(cal, sigma: dict) -> list[str]:
    """The quick run's parameters with 1σ: a Markdown table, then sensor_R_flange as a matrix."""
    from ftacq.report import _zyx_deg

    def g(values) -> str:
        return "[" + ", ".join(f"{v:.2g}" for v in np.ravel(values)) + "]"

    def v(values, digits: int, scale: float = 1.0) -> str:
        return "[" + ", ".join(f"{x * scale:+.{digits}f}" for x in np.ravel(values)) + "]"

    rows = [("sensor rotation Z-Y-X (deg)", v(_zyx_deg(cal.sensor_rotation), 3),
             g(np.degrees(sigma["sensor_rotation_rad"])) + " about x, y, z"),
            ("force bias (N)", v(cal.force_bias, 4), g(sigma["force_bias"])),
            ("torque bias (N·m)", v(cal.torque_bias, 5), g(sigma["torque_bias"])),
            ("mass (kg)", f"{cal.mass_kg:.4f}", f"{sigma['mass_kg']:.2g}"),
            ("centre of mass (mm, sensor frame)", v(cal.center_of_mass, 3, 1000.0),
             g(1000.0 * np.asarray(sigma["center_of_mass_m"]))),
            ("base tilt α, β (deg)", v(cal.base_tilt_deg, 3), g(sigma["base_tilt_deg"])),
            ("inertia diagonal (kg·m², about the centre of mass)", v(np.diag(cal.inertia), 5),
             g(np.diag(np.array(sigma["inertia_kg_m2"]))))]
    matrix = ["sensor_R_flange (flange-frame vectors into the sensor frame):"]
    matrix += ["  [" + ", ".join(f"{x:+.6f}" for x in row) + "]" for row in cal.sensor_rotation]
    return _table(["parameter", "value", "1σ"], rows) + ["", "```", *matrix, "```", ""]


def _matrix_text(matrix) -> str:
    """A matrix on one line: [[a, b, c], [d, e, f], …] with five decimals."""
    return "[" + ", ".join("[" + ", ".join(f"{x:+.5f}" for x in row) + "]" for row in np.asarray(matrix)) + "]"


def write_quick_report(folder: Path, result, verdict, plan, wall_s: dict, truth=None, *, motion=None, robot=None,
                       saved: bool | None = None, analysis=None) -> Path:
    """Write ``report.md`` and its PNGs for a quick run (:class:`ftacq.dynamics.joint.JointResult` ``result``)
    with the full run's sections: the verdict first (``saved`` False: "not saved" above it; None: not decided
    yet), parameters with 1σ (the rotation included), the truth beside them on the simulated cell, validation on
    the still holds (the verdict's errors and test), and raw vs compensated over the motion (``motion``: the
    :class:`ftacq.dynamics.motionfile.MotionRecord`, ``robot``: its :class:`ftacq.kinematics.URModel`); with the
    quick analysis (``analysis``: its ``drift`` and ``rests``), the drift decision and each hold's settling."""
    folder = Path(folder)
    cal, sigma = result.calibration, result.sigma
    lines = ["# ftacq quick calibration" + (" (simulated cell)" if truth is not None else ""), ""]
    if saved is False:
        lines += [f"**Not saved** (verdict {verdict.status}): calibration.json was not written; nothing here is in "
                  "use.", ""]
    elif saved is None:
        lines += ["**Not saved yet**: calibration.json is written only when the calibration is accepted.", ""]
    lines += _verdict_section(verdict)
    lines += [f"- created: {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')} (ftacq {__version__})",
              f"- one continuous motion ({plan.estimated_duration_s:.1f} s planned) through {len(plan.labels)} "
              "waypoints; every parameter identified from it (docs/quick.md)",
              f"- fit: {result.rows} robot rows, lag {1e3 * result.lag_s:.2f} ms, condition number "
              f"{result.condition_number:.3g}, residual RMS " + " ".join(f"{x:.3g}" for x in result.residual_rms)
              + " (N, N·m)",
              *([f"- drift: {analysis.drift.chosen}; rates " + " ".join(f"{v:.3g}" for v in analysis.drift.rate)
                 + " (N/h, N·m/h), 1σ " + " ".join(f"{v:.2g}" for v in analysis.drift.rate_sigma),
                 "- holds used from their settling (ring-down after the stop), s after the rest began: "
                 + " ".join(f"{r.settled_s:.2f}" for r in analysis.rests)] if analysis is not None else []),
              "- wall time (s): " + ", ".join(f"{k} {x:.1f}" for k, x in wall_s.items()),
              "- calibration: " + ("calibration.json" if saved else "not written"), "",
              "## Identified parameters (value ± 1σ)", ""] + _quick_parameters(cal, sigma)
    if truth is not None:
        lines += ["## Against the simulation's ground truth", "", "```", format_truth_comparison(cal, truth),
                  f"inertia (kg·m²): identified {_matrix_text(cal.inertia)}, true {_matrix_text(truth.inertia)}",
                  "```", ""]
    finding = verdict.finding("validation")
    figures = {} if finding is None else finding.figures
    if figures.get("errors"):
        errors = np.asarray(figures["errors"], dtype=float).reshape(-1, 6)
        labels = [str(label) for label in figures["labels"]]
        lines += ["## Validation on the still holds (never fitted)", "",
                  f"{len(labels)} holds compensated with the calibration (static model: the arm is still):", ""]
        lines += _table(["axis", "max |error|", "RMS error", "unit"],
                        [(AXES[k], f"{np.abs(errors[:, k]).max():.5f}",
                          f"{np.sqrt(np.mean(errors[:, k] ** 2)):.5f}", UNITS[k]) for k in range(6)])
        plot_validation(folder / "validation.png", labels, errors, figures)
        lines += ["", "![validation](validation.png)", ""]
    if motion is not None and robot is not None and len(motion.sensor_time_s):
        from ftacq.dynamics import compensate_moving

        every = max(len(motion.sensor_time_s) // MOTION_PLOT_POINTS, 1)
        times, raw = motion.sensor_time_s[::every], motion.wrench[::every]
        compensated = compensate_moving(cal, raw, motion.q, motion.qd, motion.qdd, robot=robot,
                                        sensor_time_s=times - result.lag_s, robot_time_s=motion.robot_time_s)
        plot_wrench_over_motion(folder / "wrench_over_motion.png", times - times[0], raw, compensated)
        lines += ["## Raw and compensated wrench over the motion", "",
                  "![raw and compensated over the motion](wrench_over_motion.png)", ""]
    path = folder / "report.md"
    with atomic_write(path) as handle:
        handle.write("\n".join(lines) + "\n")
    return path


__all__ = ["write_report", "write_quick_report", "format_truth_comparison", "validation_dict", "plot_wrench_per_pose", "plot_residuals",
           "plot_validation", "plot_wrench_over_motion"]
