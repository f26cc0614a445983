"""Commands printed for the user to run next (resume a run, view a recording) that work as printed in a fresh shell.

A fresh shell starts elsewhere and may not have the virtual environment's ``bin`` folder on PATH, so a hint names
the program by its absolute path unless the program found on PATH is this very one, and every path argument is
made absolute and shell-quoted.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path


def program(name: str) -> str:
    """Return how to call the console program ``name`` (``ftacq``, ``rerun``) from a fresh shell.

    The program installed beside this Python (the virtual environment's ``bin``) is the one meant; if PATH finds
    that same file, the bare name is enough, otherwise its absolute path is returned (shell-quoted).
    """
    beside = Path(sys.executable).parent / name
    if name == "ftacq" and Path(sys.argv[0]).name == "ftacq" and Path(sys.argv[0]).exists():
        beside = Path(sys.argv[0])
    if not beside.exists():
        return name
    on_path = shutil.which(name)
    if on_path is not None and os.path.realpath(on_path) == os.path.realpath(beside):
        return name
    return shlex.quote(str(beside.absolute()))


def command(name: str, *arguments: str | os.PathLike) -> str:
    """Return a shell command line: ``program(name)`` and the arguments (paths made absolute, all quoted)."""
    words = [program(name)]
    for argument in arguments:
        if isinstance(argument, os.PathLike):
            argument = str(Path(argument).absolute())
        words.append(shlex.quote(str(argument)))
    return " ".join(words)


def ftacq_command(*arguments: str | os.PathLike) -> str:
    """Return an ``ftacq …`` command line that runs as printed in a fresh shell."""
    return command("ftacq", *arguments)


__all__ = ["program", "command", "ftacq_command"]
