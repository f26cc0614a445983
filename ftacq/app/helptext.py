"""Help text: every command's ``--help`` ends with one to three examples that run as shown.

:func:`examples` returns the ``add_parser`` keywords (``epilog`` and ``formatter_class``) for a command. The
formatter keeps the examples' lines as written (argparse's :class:`~argparse.RawDescriptionHelpFormatter`) but
still wraps the description's prose to the terminal width.
"""

from __future__ import annotations

import argparse
import textwrap
from typing import Any

MAX_EXAMPLES = 3
EXAMPLES_HEADING = "examples:"


class ExamplesHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Wrap prose paragraphs as argparse does; keep indented lines (the examples) exactly as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith(EXAMPLES_HEADING):
            return super()._fill_text(text, width, indent)
        paragraphs = [" ".join(p.split()) for p in text.split("\n\n")]
        return "\n\n".join(textwrap.fill(p, width, initial_indent=indent, subsequent_indent=indent)
                           for p in paragraphs if p)


def examples(*lines: str) -> dict[str, Any]:
    """Return ``add_parser`` keywords that end the command's help with these example command lines (1 to 3).

    A line may carry a comment after two spaces and ``#``, e.g. ``"ftacq identify poses.csv -o cal.json  # …"``.
    """
    if not 1 <= len(lines) <= MAX_EXAMPLES:
        raise ValueError(f"give 1 to {MAX_EXAMPLES} examples, got {len(lines)}")
    epilog = EXAMPLES_HEADING + "\n" + "\n".join(f"  {line}" for line in lines)
    return {"epilog": epilog, "formatter_class": ExamplesHelpFormatter}


__all__ = ["examples", "ExamplesHelpFormatter", "EXAMPLES_HEADING"]
