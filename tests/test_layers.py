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


PACKAGE_PARTS = {
    "drivers.netft": {"protocol": 0, "device_time": 1, "sequence": 1, "discovery": 1, "receiver": 1, "driver": 2},
    "drivers.ati_can": {"protocol": 0, "transport": 1, "driver": 2},
    "ftacq.kinematics": {"trapezoid": 0, "ur": 0, "pinocchio_models": 1, "ik": 2},
}
"""Inside a package split by idea, each part's rank: a part imports only parts of a lower rank (the wire protocol
first, the driver that puts the parts together last); the package's ``__init__`` re-exports."""


def inner_imports(package: str, ranks: dict[str, int], root: Path = ROOT) -> list[str]:
    """The imports between the parts of ``package`` that do not go to a lower rank, and the parts left unranked."""
    folder = root.joinpath(*package.split("."))
    problems = []
    for path in sorted(folder.glob("*.py")):
        if path.name == "__init__.py":
            continue
        part = path.stem
        if part not in ranks:
            problems.append(f"{package}.{part}: no rank in PACKAGE_PARTS")
            continue
        found = {(line, target[len(package) + 1:].split(".")[0]) for line, target in imported_modules(path, root)
                 if target.startswith(package + ".")}
        problems.extend(f"{path.relative_to(root)}:{line}: {part} imports {other}" for line, other in sorted(found)
                        if other in ranks and ranks[other] >= ranks[part])
    return problems


@pytest.mark.parametrize("package", sorted(PACKAGE_PARTS))
def test_the_parts_of_a_split_package_import_downward(package):
    assert inner_imports(package, PACKAGE_PARTS[package]) == []


def test_an_upward_import_inside_a_package_is_caught(tmp_path):
    folder = tmp_path / "drivers" / "board"
    folder.mkdir(parents=True)
    (folder / "__init__.py").write_text("")
    (folder / "protocol.py").write_text("from drivers.board.driver import Board\n")
    (folder / "driver.py").write_text("from drivers.board.protocol import OP\n")
    (folder / "extra.py").write_text("")
    problems = inner_imports("drivers.board", {"protocol": 0, "driver": 1}, tmp_path)
    assert problems == ["drivers.board.extra: no rank in PACKAGE_PARTS",
                        "drivers/board/protocol.py:1: protocol imports driver"]
