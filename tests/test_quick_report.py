"""The quick run's report.md has the full run's sections and plots: the verdict first, "not saved" above it when the
calibration was not saved, parameters with 1σ and the sensor rotation itself, validation, raw vs compensated over
the motion (issue 38, item 2)."""

from dataclasses import replace

import numpy as np
from procedures.quick_analysis import quick_verdict
from ftacq.dynamics.joint import identify_joint
from ftacq.mounts import mount_of
from procedures.quick import VALIDATE
from procedures.run_report import write_quick_report
from tests.fakes.world import CellTruth
from tests.test_quick import designed, recording_for  # noqa: F401 - the module-scoped plan fixture

__all__ = ["designed"]


def test_the_quick_report_has_the_full_runs_sections(tmp_path, designed):  # noqa: F811
    settings, plan = designed
    truth = CellTruth()
    recording = recording_for(settings, plan, truth, 0.2)  # a part in the gripper during the validation holds
    rows = np.ones(len(recording.record.robot_time_s), dtype=bool)
    for (a, b), purpose in zip(recording.hold_rows, plan.purposes):
        if purpose == VALIDATE:
            rows[a:b] = False
    result = identify_joint(recording.record, settings.ur, np.array(truth.sensor_offset_m),
                            np.array(mount_of("floor").down_base), rows=rows, lag_s=0.0)
    verdict = quick_verdict(result, recording, plan, settings.ur, completed=True)
    assert verdict.status == "FAIL"
    truth_cal = replace(truth.calibration(), inertia=truth.inertia)
    path = write_quick_report(tmp_path, result, verdict, plan, {"plan": 1.0}, truth_cal, motion=recording.record,
                              robot=settings.ur, saved=False)
    text = path.read_text()
    head = text.split("## Identified parameters")[0]
    assert text.startswith("# ftacq quick calibration (simulated cell)\n\n**Not saved** (verdict FAIL): "
                           "calibration.json was not written")
    assert "## Verdict: **FAIL**" in head and "- **FAIL** validation" in head  # the verdict before the parameters
    assert "see calibration.json" not in text
    assert "sensor rotation Z-Y-X (deg)" in text and "sensor_R_flange" in text
    assert "## Validation on the still holds" in text and "max \\|error\\|" in text
    for png in ("validation.png", "wrench_over_motion.png"):
        assert f"]({png})" in text and (tmp_path / png).stat().st_size > 10_000
    assert "Against the simulation's ground truth" in text
    saved = write_quick_report(tmp_path, result, verdict, plan, {"plan": 1.0}, motion=recording.record,
                               robot=settings.ur, saved=True).read_text()
    assert "Not saved" not in saved and "- calibration: calibration.json" in saved
