"""A failed optional step does not discard a run: the drift-check revisit's fault becomes a WARN in the verdict,
and the run identifies with what it measured and writes calibration.json (issue 26, item 1: "PlanError at pose
61/61 (A09-revisit)", 60 poses kept, no calibration).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np
import pytest

from drivers.robot import MotionLimits
from ftacq.verdict import FAIL, PASS, WARN
from procedures import events
from procedures.acceptance import run_verdict
from procedures.calibration_procedure import ProcedureOptions
from procedures.measured import drift_label
from procedures.run_folder import CALIBRATION_JSON, RunFolder, RunFolderWriter
from tests.fakes.cell import SimulatedCell, fast_config, motion_problems, plan_for, run_calibration

pytest.importorskip("rtde_control")


def _protective_stop_at_the_revisit(cell, plan):
    revisit = drift_label(plan.labels[0])

    def listener(event) -> None:
        if isinstance(event, events.StateChanged) and event.state == "moving" and event.label == revisit:
            cell.controller.inject("protective_stop")
    return listener


@pytest.mark.parametrize("fault, expected", [
    ("refused", "refused before moving: joint limit: q6"),
    ("protective_stop", "ProtectiveStopError"),
])
@pytest.mark.slow(seconds=10)
def test_a_failed_drift_check_revisit_still_yields_a_calibration_with_a_warn(tmp_path, capsys, fault, expected):
    from ftacq.app.commands.calibrate import _finish

    with SimulatedCell(sensor="netft", time_scale=0.0) as cell:
        config = fast_config(cell, random_count=2, validation_count=3)
        plan = plan_for(cell, config)
        listeners = []
        if fault == "refused":  # the revisit target the old planner made: q6 on +360°, inside no margin
            target = np.array(plan.revisit_target_rad)
            target[5] = 2.0 * np.pi
            plan = replace(plan, revisit_target_rad=tuple(target))
        else:
            listeners.append(_protective_stop_at_the_revisit(cell, plan))
        folder = RunFolder.create(tmp_path, config.to_dict(), plan.to_json())
        listeners.append(RunFolderWriter(folder))
        _, result = run_calibration(cell, config, listeners, plan=plan)
        options = ProcedureOptions.from_config(config)
        exit_status = _finish(argparse.Namespace(), folder, plan, config, result, cell, options)
        commands = cell.controller.commands()
    assert result.status == "done", result.message
    assert result.identification is not None and result.validation is not None
    assert set(plan.labels) <= set(result.measured)
    assert drift_label(plan.labels[0]) not in result.measured and result.drift is None
    assert expected in result.drift_skipped and drift_label(plan.labels[0]) in result.drift_skipped
    assert any("drift check was not made" in w and expected in w for w in result.warnings)
    moves = [c for c in commands if c["kind"] == "movej"]
    limits = MotionLimits(joint_speed_rad_s=config.robot.joint_speed_rad_s,
                          joint_acceleration_rad_s2=config.robot.joint_acceleration_rad_s2)
    assert motion_problems(moves[:len(plan)], plan, limits) == []  # the plan's moves, then at most the revisit
    assert len(moves) <= len(plan) + 1 and (fault != "refused" or len(moves) == len(plan))

    verdict = run_verdict(result, plan, options)
    drift = verdict.finding("drift")
    assert drift is not None and drift.status == WARN and expected in drift.summary
    assert verdict.finding("poses").status == PASS  # every planned pose measured; the revisit is not due
    assert verdict.status != PASS  # at least the drift WARN (the noise may add a validation finding)
    assert exit_status == (1 if verdict.status == FAIL else 0)
    saved = json.loads((folder.path / CALIBRATION_JSON).read_text())
    assert saved["verdict"]["status"] == verdict.status
    assert any("drift check failed" in r for r in saved["verdict"]["reasons"])
    report = (folder.path / "report.md").read_text()
    assert "**WARN** drift" in report and "## Drift check" in report and "**Not made**" in report
    out = capsys.readouterr().out
    assert "drift check was not made" in out and "WARN  drift" in out


def test_the_path_check_before_a_run_sets_a_blocked_revisit_apart():
    """A revisit whose move fails the check before the run does not keep the run from starting: the problem is
    set apart for the plan summary, and the executor skips the revisit when it gets there."""
    from procedures.calibration_procedure import calibration_steps, check_steps
    from procedures.plan import PlanSettings, home_configuration_rad, make_plan

    start = home_configuration_rad()
    plan = make_plan(PlanSettings(random_count=4, validation_count=2), start)
    target = np.array(plan.revisit_target_rad)
    target[5] = 2.0 * np.pi
    blocked = replace(plan, revisit_target_rad=tuple(target))
    assert check_steps(calibration_steps(plan), plan.settings, start) == []
    assert len(check_steps(calibration_steps(blocked), plan.settings, start)) == 1  # as before, without the list
    optional: list[str] = []
    assert check_steps(calibration_steps(blocked), plan.settings, start, optional) == []
    assert len(optional) == 1 and optional[0].startswith(f"move to {plan.labels[0]}: joint limit: q6")
