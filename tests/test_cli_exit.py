"""The CLI's exit status comes from the exception's type, never its text; a broken command module is reported."""

from __future__ import annotations

import argparse

import pytest

from ftacq.app import cli
from ftacq.errors import (
    AbortedError,
    ConfigError,
    DeviceTimeoutError,
    FtacqError,
    InputError,
    InterruptedByUser,
    PlanError,
)


def _command_raising(error: BaseException):
    def register(subparsers: argparse._SubParsersAction) -> None:
        parser = subparsers.add_parser("boom")

        def run(args: argparse.Namespace) -> int:
            raise error

        parser.set_defaults(func=run)

    return register


@pytest.mark.parametrize("error, status", [
    (InterruptedByUser("stopped at pose 3"), 130),
    # the text says "interrupt" but the type is a plain abort: status 1 (the old code matched the text)
    (AbortedError("the sensor link was interrupted: poses kept"), 1),
    (InputError("poses.csv: line 3, column 'fx': value 'x' is not a number"), 2),
    (ConfigError("CELL.toml: robot.joint_speed_rad_s = 9: must be in [0.001, 3.2]"), 2),
    (DeviceTimeoutError("no data"), 1),
    (PlanError("interrupted plan"), 1),
    (KeyboardInterrupt(), 130),
])
def test_exit_status_follows_the_error_type(monkeypatch, capsys, error, status):
    register = _command_raising(error)

    class Module:
        pass

    module = Module()
    module.register = register  # type: ignore[attr-defined]
    real_import = cli.importlib.import_module
    monkeypatch.setattr(cli, "COMMAND_MODULES", ("fake.boom",))
    monkeypatch.setattr(cli.importlib, "import_module",
                        lambda name: module if name == "fake.boom" else real_import(name))
    assert cli.main(["boom"]) == status
    err = capsys.readouterr().err
    assert err.startswith("ftacq: ") and "Traceback" not in err
    if isinstance(error, FtacqError):
        assert str(error) in err


def test_every_ftacq_error_type_has_a_status():
    def subclasses(kind):
        for sub in kind.__subclasses__():
            yield sub
            yield from subclasses(sub)

    for kind in subclasses(FtacqError):
        assert cli.exit_status(kind("x")) in (1, 2, 130), kind


def test_a_command_module_that_fails_to_import_is_reported_not_skipped(monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", (*cli.COMMAND_MODULES, "ftacq.app.commands.does_not_exist"))
    assert cli.main(["config", "--help"]) == 1
    err = capsys.readouterr().err
    assert "ftacq.app.commands.does_not_exist" in err and "Traceback" not in err
