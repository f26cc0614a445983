"""Lazily loaded public names of a package (PEP 562 module ``__getattr__`` and ``__dir__``), written once.

A package lists its public names with the module defining each, and hands this module its namespace::

    _LAZY = {"Calibration": "ftacq.calibration", ...}
    __all__ = list(_LAZY)
    __getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())

``import package`` then imports none of those modules; the first use of a name imports its module and caches
the value in the package's namespace (later uses are plain attribute look-ups). This module imports only the
standard library, so importing a package stays light.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, MutableMapping
from typing import Any


def lazy_names(package: str, homes: Mapping[str, str], namespace: MutableMapping[str, Any]
               ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package`` whose public names live in other modules.

    Args:
        package: the package's dotted name (its ``__name__``), for the error message.
        homes: public name → the dotted name of the module defining it.
        namespace: the package's ``globals()``; a name is cached there once loaded. ``__dir__`` lists the
            namespace and the names not loaded yet.
    """

    def __getattr__(name: str) -> Any:
        module = homes.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(homes))

    return __getattr__, __dir__
