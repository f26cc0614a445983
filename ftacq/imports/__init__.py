"""Import recordings made by other tools into the pose record (docs/formats.md, "Importing a recording").

One function, :func:`import_recording`, reads a CSV of still poses (one row each) and returns a
:class:`ftacq.posefile.PoseRecord`: the flange pose as a UR rotation vector and the mean wrench in the sensor frame,
in SI units. What the recording holds is said by :class:`ImportOptions`:

- the flange orientation (``orientation``): rotation vectors (``rx ry rz``), quaternions (``qx qy qz qw``, scalar
  last or first: ``quaternion_order``), rotation matrices (``r11 … r33``, row-major), or joint angles (``q1 … qn``,
  rad) with a robot model (:mod:`ftacq.imports.robot_model`: a UR model, a DH table or a URDF through Pinocchio)
  that gives the flange pose; :mod:`ftacq.imports.orientation` converts;
- the flange position (``x y z``, m; with joint angles it comes from the model; absent: written as 0, the
  identification does not use it);
- the wrench columns ``fx fy fz tx ty tz``, their units (column suffix, header comment or option, as the pose
  record: :func:`ftacq.unitcolumns.unit_header_map`) and their frame (``wrench_frame``: the sensor's, or the robot
  base frame, converted by :mod:`ftacq.imports.wrench_frame`);
- optional ``label``, ``set``, a time column (s) kept as ``t_start_s`` / ``t_end_s``, and ``rename`` for a
  recording whose columns have other names.

A bad value is an InputError naming the file, line and column. The result carries what was done in ``notes``.
"""

from __future__ import annotations

from ftacq.lazy import lazy_names

_LAZY = {
    "ImportOptions": "ftacq.imports.options",
    "ORIENTATIONS": "ftacq.imports.options",
    "ImportResult": "ftacq.imports.recording",
    "import_recording": "ftacq.imports.recording",
}
__all__ = ["ImportOptions", "ImportResult", "ORIENTATIONS", "import_recording"]
__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
