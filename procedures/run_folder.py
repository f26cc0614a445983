"""The run folder: everything one calibration run measured and produced, written as it happens.

::

    RUN_DIR/
      run.json          config, software version, plan (labels, sets, joint targets), status and history
      poses.csv         one pose-record row per measured pose, appended, flushed and fsync'd at once
      calibration.json  the identified calibration (when identification finished)
      report.md, *.png  the report (when identification finished)

``poses.csv`` uses the core's pose-record format (:mod:`ftacq.posefile`; columns ``label`` and ``set`` name the
plan pose; set ``D`` is the drift-check revisit of the first pose, :mod:`ftacq.posesets`). It is valid after every row, so
``ftacq identify RUN_DIR/poses.csv`` works on a partial run too. A crash in the middle of a row leaves a torn
last line; :meth:`RunFolder.open` drops it (and says so) so that the pose is measured again.

``run.json`` is rewritten atomically (:func:`ftacq.fileio.atomic_write`) on every status change. ``--resume``
reopens the folder: the same plan, minus the poses already in ``poses.csv``.

A process killed outright (SIGKILL, power loss) cannot write its last status, so run.json would say
``running`` forever. While running it therefore also records who is running it (``process``: host, pid and
the process's start time, which tells a recycled pid from the original) and a ``heartbeat_utc`` refreshed with
every measured pose. A later reader gets :attr:`RunFolder.status` ``"interrupted"`` (with
:attr:`RunFolder.status_note` "interrupted (process gone)") when that process no longer exists, and ``--resume``
refuses a run whose process is still alive.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import socket
from pathlib import Path
from typing import Any

import numpy as np

from ftacq import __version__
from ftacq.errors import InputError
from ftacq.fileio import atomic_write
from ftacq.posefile import POSE_CSV_HEADER, PoseRecord, format_pose_row, read_pose_csv
from procedures.measured import MeasuredPose

log = logging.getLogger(__name__)

RUN_FORMAT = "ftacq-run"
RUN_FORMAT_VERSION = 1
RUN_JSON = "run.json"
POSES_CSV = "poses.csv"
CALIBRATION_JSON = "calibration.json"
REPORT_MD = "report.md"
STATUSES = ("planned", "running", "stopped", "failed", "done")
"""What run.json stores. :attr:`RunFolder.status` may also be "interrupted" (stored running, process gone)."""
INTERRUPTED = "interrupted"
PROCESS_GONE_NOTE = "interrupted (process gone)"


def _process_start_token(pid: int) -> str | None:
    """Boot id and start time (clock ticks since boot) of process ``pid`` on Linux; None elsewhere or if gone.

    Two processes with the same pid never share this token, so a recycled pid is not mistaken for the run."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
        with open("/proc/sys/kernel/random/boot_id", encoding="ascii") as handle:
            boot_id = handle.read().strip()
    except (OSError, IndexError):
        return None
    return f"{boot_id}:{fields[19]}"  # field 22 of stat, counted after the ")" that ends the command name


def _process_alive(pid: int, token: str | None) -> bool | None:
    """True / False when this host can tell whether process ``pid`` (with ``token``) still runs; None if not."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    except (OSError, ValueError, OverflowError):
        return None
    current = _process_start_token(pid)
    if token is None or current is None:
        return True
    return current == token


def this_process() -> dict[str, Any]:
    """How run.json names the process running a run: host, pid and start token."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "start_token": _process_start_token(os.getpid())}


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


class RunFolder:
    """A run folder opened for writing (create it with :meth:`create`, reopen it with :meth:`open`)."""

    def __init__(self, path: Path, document: dict[str, Any]) -> None:
        self.path = Path(path)
        self._document = document

    # ------------------------------------------------------------------------------------------ create / open

    @classmethod
    def create(cls, parent: str | os.PathLike, config: dict[str, Any], plan_json: str,
               name: str | None = None, extra: dict[str, Any] | None = None) -> "RunFolder":
        """Create ``parent/NAME`` (default: UTC date and time, made unique) with run.json and an empty poses.csv.

        ``config`` is the configuration as plain dicts, ``plan_json`` the plan's :meth:`Plan.to_json`.
        """
        parent = Path(parent)
        parent.mkdir(parents=True, exist_ok=True)
        base = name or _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S")
        path, k = parent / base, 1
        while True:
            try:
                path.mkdir()
                break
            except FileExistsError:
                if name:
                    raise InputError(f"{path}: run folder already exists (resume it with --resume {path})") from None
                k += 1
                path = parent / f"{base}-{k}"
        plan = json.loads(plan_json)
        document = {
            "format": RUN_FORMAT,
            "version": RUN_FORMAT_VERSION,
            "software_version": __version__,
            "created_utc": _utc_now(),
            "status": "planned",
            "message": "",
            "config": config,
            "labels": plan["labels"],
            "set_names": plan["set_names"],
            "plan": plan,
            "history": [{"utc": _utc_now(), "status": "planned", "message": "plan confirmed"}],
            **(extra or {}),
        }
        folder = cls(path, document)
        folder._write_document()
        with open(path / POSES_CSV, "w", encoding="utf-8", newline="") as handle:
            handle.write(POSE_CSV_HEADER)
            handle.flush()
            os.fsync(handle.fileno())
        _fsync_dir(path)
        return folder

    @classmethod
    def open(cls, path: str | os.PathLike) -> "RunFolder":
        """Reopen a run folder to resume it. Raises InputError naming the file and why it cannot be resumed."""
        path = Path(path)
        run_json = path / RUN_JSON
        if not path.is_dir():
            raise InputError(f"{path}: not a run folder (no such folder)")
        try:
            document = json.loads(run_json.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(f"{run_json}: missing; {path} is not an ftacq run folder") from None
        except (OSError, json.JSONDecodeError) as error:
            raise InputError(f"{run_json}: cannot read: {error}") from error
        if not isinstance(document, dict) or document.get("format") != RUN_FORMAT:
            raise InputError(f"{run_json}: not an ftacq run file (format {document.get('format')!r})"
                             if isinstance(document, dict) else f"{run_json}: not a JSON object")
        if document.get("version") != RUN_FORMAT_VERSION:
            raise InputError(f"{run_json}: version {document.get('version')!r}, this ftacq reads {RUN_FORMAT_VERSION}")
        for key in ("config", "plan", "labels", "set_names", "status"):
            if key not in document:
                raise InputError(f"{run_json}: key {key!r} missing")
        folder = cls(path, document)
        folder._repair_poses_csv()
        return folder

    # ------------------------------------------------------------------------------------------ accessors

    @property
    def document(self) -> dict[str, Any]:
        """The run.json content (do not modify)."""
        return self._document

    @property
    def status(self) -> str:
        """The run's state: run.json's status, except "interrupted" for a "running" run whose process is gone."""
        stored = str(self._document["status"])
        if stored == "running" and self.process_alive() is False:
            return INTERRUPTED
        return stored

    @property
    def status_note(self) -> str:
        """One line for the user: the status, and for a running run who runs it or that its process is gone."""
        status, process = self.status, self._document.get("process") or {}
        if status == INTERRUPTED:
            return (f"{PROCESS_GONE_NOTE}: run.json says running, but process {process.get('pid')} on "
                    f"{process.get('host')} no longer exists (last heartbeat {self._document.get('heartbeat_utc')})")
        if status == "running":
            alive = self.process_alive()
            where = f"process {process.get('pid')} on {process.get('host')}"
            return (f"running ({where})" if alive else
                    f"running on another host? ({where}, last heartbeat {self._document.get('heartbeat_utc')})")
        return status

    def process_alive(self) -> bool | None:
        """Whether the process recorded as running this run still exists (None: another host, or unknown)."""
        process = self._document.get("process")
        if not isinstance(process, dict) or not isinstance(process.get("pid"), int):
            return None
        if process.get("host") != socket.gethostname():
            return None
        return _process_alive(process["pid"], process.get("start_token"))

    @property
    def config(self) -> dict[str, Any]:
        return self._document["config"]

    @property
    def plan_json(self) -> str:
        return json.dumps(self._document["plan"])

    @property
    def poses_csv(self) -> Path:
        return self.path / POSES_CSV

    def read_record(self) -> PoseRecord | None:
        """Return every measured row as a PoseRecord (None when nothing was measured yet)."""
        lines = self.poses_csv.read_text(encoding="utf-8").splitlines()
        if len(lines) <= 1:
            return None
        return read_pose_csv(self.poses_csv)

    def measured(self) -> dict[str, MeasuredPose]:
        """Return the measured poses by label (the last row wins if a label was written twice)."""
        record = self.read_record()
        if record is None:
            return {}
        out: dict[str, MeasuredPose] = {}
        t_end = record.extra.get("t_end_s")
        for i, label in enumerate(record.labels):
            out[label] = MeasuredPose(
                label=label, set_name=record.sets[i], pose=record.pose[i], mean=record.wrench[i],
                std=None if record.std is None else record.std[i],
                count=int(record.count[i]) if record.count is not None else 0,
                t_end_s=None if t_end is None or np.isnan(t_end[i]) else float(t_end[i]))
        return out

    # ------------------------------------------------------------------------------------------ writing

    def append_pose(self, event) -> None:
        """Append one measured pose (a :class:`procedures.events.PoseMeasured`) to poses.csv; flush and fsync."""
        row = format_pose_row(
            event.pose, event.mean, label=event.label, set_name=event.set_name, count=event.count,
            std=event.std, saturated=event.saturated, lost=event.lost, t_start_s=event.t_start_s,
            t_end_s=event.t_end_s, joint_positions_rad=event.joint_positions_rad)
        with open(self.poses_csv, "a", encoding="utf-8", newline="") as handle:
            handle.write(row)
            handle.flush()
            os.fsync(handle.fileno())

    def set_status(self, status: str, message: str = "", **fields: Any) -> None:
        """Record a status ("running", "stopped", "failed", "done") with a message; rewrite run.json atomically."""
        if status not in STATUSES:
            raise ValueError(f"status {status!r}: must be one of {', '.join(STATUSES)}")
        self._document["status"] = status
        self._document["message"] = message
        self._document["updated_utc"] = _utc_now()
        if status == "running":
            self._document["process"] = this_process()
            self._document["heartbeat_utc"] = self._document["updated_utc"]
        self._document.update(fields)
        self._document["history"].append({"utc": _utc_now(), "status": status, "message": message})
        self._write_document()

    def update(self, **fields: Any) -> None:
        """Store extra top-level fields in run.json (e.g. the drift check, validation figures)."""
        self._document.update(fields)
        self._write_document()

    def _write_document(self) -> None:
        with atomic_write(self.path / RUN_JSON) as handle:
            json.dump(self._document, handle, indent=1, default=_json_default)
            handle.write("\n")

    def _repair_poses_csv(self) -> None:
        """Drop a torn last line (a crash mid-write) and recreate a missing header."""
        csv_path = self.poses_csv
        if not csv_path.exists():
            with open(csv_path, "w", encoding="utf-8", newline="") as handle:
                handle.write(POSE_CSV_HEADER)
                handle.flush()
                os.fsync(handle.fileno())
            return
        data = csv_path.read_bytes()
        if not data:
            keep = POSE_CSV_HEADER.encode()
        elif not data.endswith(b"\n"):
            keep = data[: data.rfind(b"\n") + 1] or POSE_CSV_HEADER.encode()
            log.warning("%s: dropped an incomplete last line (a crash while writing); that pose is measured again",
                        csv_path)
        else:
            return
        with atomic_write(csv_path, mode="wb") as handle:
            handle.write(keep)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.bool_):
        return bool(value)
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class RunFolderWriter:
    """A procedure listener that appends every measured pose to the run folder and records status changes.

    ``critical``: an error writing the folder stops the procedure (nothing is measured that cannot be kept).
    """

    critical = True

    def __init__(self, folder: RunFolder) -> None:
        self.folder = folder

    def __call__(self, event) -> None:
        from procedures import events

        if isinstance(event, events.PoseMeasured):
            self.folder.append_pose(event)
            if self.folder.document.get("status") == "running":
                self.folder.update(heartbeat_utc=_utc_now())
        elif isinstance(event, events.StateChanged):
            if event.state in ("done", "stopped", "failed"):
                self.folder.set_status(event.state, event.message)
            elif event.state == "moving" and self.folder.status != "running":
                self.folder.set_status("running", "measuring")
        elif isinstance(event, events.DriftChecked):
            self.folder.update(drift_check={"label": event.label, "drift": np.asarray(event.drift).tolist(),
                                            "elapsed_s": event.elapsed_s, "warning": event.warning})
        elif isinstance(event, events.Validated):
            self.folder.update(validation={"labels": list(event.labels), "max_abs": np.asarray(event.max_abs).tolist(),
                                           "rms": np.asarray(event.rms).tolist()})


__all__ = ["RunFolder", "RunFolderWriter", "RUN_JSON", "POSES_CSV", "CALIBRATION_JSON", "REPORT_MD", "INTERRUPTED",
           "PROCESS_GONE_NOTE"]
