"""The run report's plots and tables: the validation plot draws the verdict's own test, every text is readable at
the saved size, and report.md's tables have as many cells per row as their rule."""

from __future__ import annotations

import re

import numpy as np
import pytest

from ftacq.verdict import PASS, WARN, validation_finding
from procedures import run_report


@pytest.fixture
def saved_figures(monkeypatch):
    """The figures the report writes, kept (and still saved) so a test can read what was drawn."""
    figures = []
    save = run_report._save

    def keep(fig, path):
        figures.append(fig)
        save(fig, path)

    monkeypatch.setattr(run_report, "_save", keep)
    return figures


def _texts(fig):
    from matplotlib.text import Text

    fig.canvas.draw()
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def test_the_validation_plot_flags_exactly_the_poses_the_verdict_flags(tmp_path):
    """An error of 3.5σ on one axis is inside the verdict's test (d² over six axes): the verdict passes and the
    plot must not show that pose beyond its line (the old grey ± 3σ band did); a 7σ error is a WARN naming the
    pose, and the plot flags that pose and no other."""
    labels = [f"V{i:02d}" for i in range(1, 9)]
    covariance = np.tile(np.eye(6) * 0.01**2, (8, 1, 1))  # σ = 0.01 per axis
    errors = np.random.default_rng(4).standard_normal((8, 6)) * 0.002
    errors[7, 2] = 0.035  # 3.5σ on Fz of V08
    finding = validation_finding(errors, covariance, labels)
    assert finding.status == PASS
    drawn = run_report.plot_validation(tmp_path / "validation.png", labels, errors, finding.figures)
    assert drawn is not None and drawn["beyond"] == [] and max(drawn["d2"]) < drawn["limit"]

    errors[3, 4] = 0.07  # 7σ on Ty of V04
    finding = validation_finding(errors, covariance, labels)
    assert finding.status == WARN and "V04" in finding.summary and "V08" not in finding.summary
    drawn = run_report.plot_validation(tmp_path / "validation.png", labels, errors, finding.figures)
    assert drawn["beyond"] == ["V04"]
    np.testing.assert_allclose(drawn["d2"], finding.figures["pose_d2"])
    assert (tmp_path / "validation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_residual_labels_are_readable_and_do_not_overlap(tmp_path, saved_figures):
    """61 poses (a full default plan): every text at least MIN_FONT_PT at the saved size, and the pose labels
    side by side without overlapping."""
    labels = [f"{s}{i:02d}" for s, n in (("A", 24), ("E", 6), ("V", 4), ("R", 27)) for i in range(1, n + 1)]
    residuals = np.random.default_rng(1).standard_normal((len(labels), 6)) * [0.01, 0.01, 0.01, 0.001, 0.001, 0.001]
    run_report.plot_residuals(tmp_path / "residuals.png", labels, residuals, outliers=["A03"])
    (fig,) = saved_figures
    texts = _texts(fig)
    assert min(t.get_fontsize() for t in texts) >= run_report.MIN_FONT_PT
    ticks = [t for t in fig.axes[-1].get_xticklabels() if t.get_text()]
    assert [t.get_text() for t in ticks] == labels
    boxes = sorted((t.get_window_extent().x0, t.get_window_extent().x1) for t in ticks)
    assert all(right <= next_left for (_, right), (next_left, _) in zip(boxes, boxes[1:]))


def test_validation_and_wrench_plots_use_readable_text(tmp_path, saved_figures):
    labels = ["V01", "V02", "V03", "V04"]
    errors = np.random.default_rng(2).standard_normal((4, 6)) * 0.01
    finding = validation_finding(errors, np.tile(np.eye(6) * 0.01**2, (4, 1, 1)), labels)
    run_report.plot_validation(tmp_path / "validation.png", labels, errors, finding.figures)
    raw = np.random.default_rng(3).standard_normal((4, 6))
    run_report.plot_wrench_per_pose(tmp_path / "wrench.png", labels, ["V"] * 4, raw, raw * 0.01, np.full(6, 0.03))
    for fig in saved_figures:
        assert min(t.get_fontsize() for t in _texts(fig)) >= run_report.MIN_FONT_PT


def table_cells(line: str) -> int:
    """Cells of a Markdown table line, as GitHub-flavoured Markdown splits it (an escaped ``\\|`` does not split)."""
    return len(re.split(r"(?<!\\)\|", line.strip().strip("|")))


def tables(markdown: str) -> list[list[str]]:
    """The Markdown tables of a document, each as its lines (header, rule, rows)."""
    found, current = [], []
    for line in markdown.splitlines() + [""]:
        if line.startswith("|"):
            current.append(line)
        elif current:
            found.append(current)
            current = []
    return found


def assert_tables_render(markdown: str) -> None:
    """Every table: a rule of dashes under the header, and every line with as many cells as the rule."""
    for table in tables(markdown):
        header, rule, *rows = table
        assert re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", rule), rule
        for line in [header, *rows]:
            assert table_cells(line) == table_cells(rule), f"{line!r} against the rule {rule!r}"


def test_tables_escape_pipes_in_their_cells():
    lines = run_report._table(["axis", "max |error|", "RMS error", "unit"], [("Fx", "0.1", "0.05", "N")])
    assert_tables_render("\n".join(lines))
    assert lines[0] == "| axis | max \\|error\\| | RMS error | unit |"
