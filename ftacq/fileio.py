"""Atomic file writing: nothing half written, ever.

Write to a temporary file in the destination folder, flush and fsync it, then rename it over the target.
The file gets mode 0644 (less the process umask), as a plain ``open()`` would give it: ``mkstemp`` creates its
temporary file 0600, which would leave calibration.json and the report unreadable for another user (a ROS node).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

FILE_MODE = 0o644
"""Mode of every file written here (before the umask): owner read-write, everyone else read."""


def _umask() -> int:
    """Return the process umask without changing it (Linux: /proc/self/status; elsewhere assume 0o022)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file next to ``path``; on a clean exit fsync and rename it to ``path``.

    On an exception the temporary file is removed and ``path`` is left as it was. The file's mode is
    :data:`FILE_MODE` less the umask.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        os.fchmod(fd, FILE_MODE & ~_umask())
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding, newline=None if "b" in mode else "") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise
