"""Pose record CSV: round trips, row-at-a-time appending, and one clear error per kind of bad input."""

import numpy as np
import pytest

from ftacq.errors import InputError
from ftacq.posefile import (
    OPTIONAL_COLUMNS,
    POSE_COLUMNS,
    POSE_CSV_HEADER,
    PoseRecord,
    format_pose_row,
    read_pose_csv,
    write_pose_csv,
)
from ftacq.so3 import rotation_from_rotvec
from tests.fakes.pose_records import example_record


def test_public_column_names():
    assert POSE_COLUMNS == ("x", "y", "z", "rx", "ry", "rz", "fx", "fy", "fz", "tx", "ty", "tz")
    for name in ("label", "set", "count", "std_fx", "std_tz", "saturated", "lost", "t_start_s", "t_end_s", "q0", "q5"):
        assert name in OPTIONAL_COLUMNS


def test_round_trip_is_exact(tmp_path):
    record = example_record(seed=3)
    record = PoseRecord(
        pose=record.pose, wrench=record.wrench, std=record.std, count=record.count, labels=record.labels,
        sets=record.sets, extra={"lost": np.arange(len(record)), "t_start_s": np.linspace(1.5, 9.25, len(record))},
    )
    path = tmp_path / "poses.csv"
    write_pose_csv(path, record)
    back = read_pose_csv(path)
    np.testing.assert_array_equal(back.pose, record.pose)
    np.testing.assert_array_equal(back.wrench, record.wrench)
    np.testing.assert_array_equal(back.std, record.std)
    np.testing.assert_array_equal(back.count, record.count)
    assert back.labels == record.labels and back.sets == record.sets
    np.testing.assert_array_equal(back.extra["lost"], np.arange(len(record)))
    np.testing.assert_array_equal(back.extra["t_start_s"], record.extra["t_start_s"])
    assert "q0" not in back.extra  # all-empty optional columns are absent


def test_rows_appended_one_at_a_time_read_back(tmp_path):
    path = tmp_path / "live.csv"
    pose = [0.4, -0.1, 0.3, 3.1, 0.05, -0.02]
    with open(path, "w") as handle:
        handle.write(POSE_CSV_HEADER)
        handle.write(format_pose_row(pose, [1, 2, 3, 0.1, 0.2, 0.3], label="A01", set_name="A", count=700,
                                     std=[0.05] * 6, saturated=0, lost=2, t_start_s=10.0, t_end_s=10.1,
                                     joint_positions_rad=[0, -1.5, 1.5, -1.5, -1.5, 0]))
        handle.write(format_pose_row(pose, [1, 2, 3, 0.1, 0.2, 0.25], label="A, two", set_name="A", count=699,
                                     std=[0.04] * 6))
    record = read_pose_csv(path)
    assert len(record) == 2
    assert record.labels == ("A01", "A, two")
    np.testing.assert_array_equal(record.count, [700, 699])
    assert record.extra["lost"][0] == 2 and np.isnan(record.extra["lost"][1])
    np.testing.assert_allclose(record.flange_R_base[0], rotation_from_rotvec(np.array(pose[3:])).T)
    np.testing.assert_allclose(record.standard_error[0], 0.05 / np.sqrt(700))


def test_columns_in_any_order_and_defaults(tmp_path):
    path = tmp_path / "minimal.csv"
    path.write_text("tz,ty,tx,fz,fy,fx,rz,ry,rx,z,y,x,comment\n" + "6,5,4,3,2,1,0,0,0.1,0.3,0.2,0.1,hello\n" * 2)
    record = read_pose_csv(path)
    np.testing.assert_array_equal(record.wrench[0], [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(record.pose[0], [0.1, 0.2, 0.3, 0.1, 0, 0])
    assert record.labels == ("P1", "P2") and record.std is None and record.count is None
    path.write_text(",".join(POSE_COLUMNS) + "\n" + "0,0,0,0,0,0,1,2,3,4,5,6,\n" * 2)  # trailing commas
    assert len(read_pose_csv(path)) == 2


def test_select_by_mask_and_indices():
    record = example_record()
    mask = np.zeros(len(record), bool)
    mask[[2, 5]] = True
    for chosen in (record.select(mask), record.select([2, 5])):
        assert chosen.labels == (record.labels[2], record.labels[5])
        np.testing.assert_array_equal(chosen.wrench, record.wrench[[2, 5]])
        assert chosen.std.shape == (2, 6) and len(chosen) == 2


HEADER = ",".join(POSE_COLUMNS)
ROW = "0.4,0,0.3,3.14,0,0,1,2,3,0.1,0.2,0.3"


@pytest.mark.parametrize(
    "text, expected",
    [
        ("", "empty file"),
        (HEADER + "\n", "no data rows"),
        (HEADER.replace(",fz", "") + "\n" + ROW[:-4] + "\n", "missing required column\\(s\\) fz"),
        (HEADER + ",fx\n" + ROW + ",1\n", "column 'fx' appears twice"),
        (HEADER + "\n" + ROW.replace("3.14", "abc") + "\n", "line 2, column 'rx': value 'abc' is not a number"),
        (HEADER + "\n" + ROW + "\n" + ROW.replace(",2,", ",nan,") + "\n", "line 3, column 'fy': value 'nan' is not finite"),
        (HEADER + "\n" + ROW.replace(",1,", ",inf,") + "\n", "column 'fx': value 'inf' is not finite"),
        (HEADER + "\n" + ROW + ",7\n", "line 2: 13 cells, but the header has 12"),
        (HEADER + "\n" + ROW.replace("0.3,3.14", ",3.14") + "\n", "column 'z': empty cell"),
        (HEADER + ",count\n" + ROW + ",2.5\n", "column 'count': value '2.5' is not a whole number"),
        (HEADER + ",std_fx,std_fy,std_fz,std_tx,std_ty,std_tz\n" + ROW + ",1,1,-1,1,1,1\n", "column 'std_fz': value '-1' is negative"),
        (HEADER + ",std_fx\n" + ROW + ",1\n", "std columns must come as a set of six"),
    ],
)
def test_bad_input_gets_one_clear_message(tmp_path, text, expected):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=expected) as info:
        read_pose_csv(path)
    assert str(path) in str(info.value)


def test_repeated_labels_are_made_unique(tmp_path):
    path = tmp_path / "poses.csv"
    path.write_text(HEADER + ",label\n" + ROW + ",A1\n" + ROW + ",A1\n" + ROW + ",\n")
    assert read_pose_csv(path).labels == ("A1", "A1#2", "P3")


def test_missing_file_names_the_file(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        read_pose_csv(tmp_path / "nope.csv")


def test_write_is_atomic(tmp_path):
    path = tmp_path / "poses.csv"
    path.write_text("old content\n")
    broken = example_record()
    object.__setattr__(broken, "labels", broken.labels[:-1])  # one label short: fails while writing
    with pytest.raises(IndexError):
        write_pose_csv(path, broken)
    assert path.read_text() == "old content\n"
    assert [p.name for p in tmp_path.iterdir()] == ["poses.csv"]
