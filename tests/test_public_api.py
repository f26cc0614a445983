"""The curated public names of the ftacq, drivers and procedures packages: each resolves, and importing a package
imports none of its modules (the names load lazily)."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ftacq", "drivers", "procedures")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_resolves_to_its_module(package):
    module = importlib.import_module(package)
    assert module.__all__ and len(set(module.__all__)) == len(module.__all__)
    for name in module.__all__:
        value = getattr(module, name)
        assert value is not None
        assert name in dir(module)
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        module.not_a_name  # noqa: B018 - the lazy __getattr__ must refuse an unknown name


def test_importing_the_packages_loads_nothing_heavy():
    code = ("import sys, ftacq, drivers, procedures; "
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numpy', 'pinocchio', 'rtde_control', 'rtde_receive', 'can', 'rerun', 'matplotlib', "
            "'ftacq', 'drivers', 'procedures'))))")
    loaded = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60,
                            check=True).stdout.split()
    # the packages and their one shared helper (ftacq.lazy, standard library only), no module behind a name
    assert loaded == ["drivers", "ftacq", "ftacq.lazy", "procedures"]


def test_a_public_name_is_the_object_of_its_module():
    import ftacq
    import procedures
    from ftacq.calibration import Calibration
    from procedures.plan import make_plan

    assert ftacq.Calibration is Calibration and procedures.make_plan is make_plan
