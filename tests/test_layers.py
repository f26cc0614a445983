"""The house's layers, read from the imports (ast): core → drivers → procedures → application, nothing upward.

- core: ``ftacq`` except ``ftacq.app`` (model, identification, compensation, files);
- drivers: ``drivers`` (bytes and devices), may import core;
- procedures: ``procedures`` (steps), may import core and drivers;
- application: ``ftacq.app`` (CLI, commands, CELL.toml, dashboard, simulated-cell launcher), may import all of
  the above, and is the only product code that reaches ``tests.fakes``.

Every import counts, also those inside functions: a lazy upward import is still an upward dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("core", "drivers", "procedures", "app", "tests")
ALLOWED = {
    "core": {"core"},
    "drivers": {"core", "drivers"},
    "procedures": {"core", "drivers", "procedures"},
    "app": {"core", "drivers", "procedures", "app", "tests"},
}


def layer_of(module: str) -> str | None:
    """The layer of a dotted module name, or None for a third-party or standard module."""
    parts = module.split(".")
    if parts[0] == "ftacq":
        return "app" if len(parts) > 1 and parts[1] == "app" else "core"
    if parts[0] in ("drivers", "procedures", "tests"):
        return parts[0]
    return None


def module_name(path: Path, root: Path = ROOT) -> str:
    """The dotted module name of a product file below ``root``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """Every (line, absolute module name) ``path`` imports, relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((node.lineno, name))
            # ``from ftacq import app`` imports the package ftacq.app
            found.extend((node.lineno, f"{name}.{alias.name}") for alias in node.names if alias.name != "*")
    return found


def upward_imports(root: Path = ROOT) -> list[str]:
    """Every import in the product packages that goes to a layer not allowed below it, as 'file:line: a -> b'."""
    problems = []
    files = [p for folder in ("ftacq", "drivers", "procedures") for p in sorted((root / folder).rglob("*.py"))]
    for path in files:
        own = layer_of(module_name(path, root))
        assert own is not None
        reported: set[int] = set()
        for line, target in imported_modules(path, root):
            target_layer = layer_of(target)
            if target_layer is None or target_layer in ALLOWED[own] or line in reported:
                continue
            reported.add(line)
            problems.append(f"{path.relative_to(root)}:{line}: {own} imports {target} ({target_layer})")
    return problems


def test_no_upward_import():
    assert upward_imports() == []


@pytest.mark.parametrize(("folder", "source", "layer"), [
    ("ftacq", "from drivers.sensor import open_sensor\n", "drivers"),
    ("ftacq", "def f():\n    from ftacq.app import cli\n", "app"),
    ("drivers", "import procedures.plan\n", "procedures"),
    ("procedures", "from ftacq import app\n", "app"),
    ("procedures", "from tests.fakes.cell import SimulatedCell\n", "tests"),
])
def test_an_upward_import_is_caught(tmp_path, folder, source, layer):
    for name in ("ftacq", "drivers", "procedures"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("")
    (tmp_path / folder / "offender.py").write_text(source)
    problems = upward_imports(tmp_path)
    assert len(problems) == 1 and problems[0].startswith(f"{folder}/offender.py:") and f"({layer})" in problems[0]


def test_only_the_application_reaches_the_simulator():
    for folder in ("ftacq", "drivers", "procedures"):
        for path in (ROOT / folder).rglob("*.py"):
            if module_name(path).startswith("ftacq.app"):
                continue
            assert not [t for _, t in imported_modules(path) if t.startswith("tests")], path
