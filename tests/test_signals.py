"""SIGTERM as Ctrl-C (ftacq.app.signals): raised as KeyboardInterrupt inside the block, the old handler after."""

from __future__ import annotations

import signal
import threading

import pytest

from ftacq.app.signals import sigterm_as_interrupt


def test_sigterm_raises_keyboard_interrupt_inside_and_the_previous_handler_comes_back():
    seen: list[int] = []
    before = signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    try:
        with pytest.raises(KeyboardInterrupt, match=f"signal {int(signal.SIGTERM)}"):
            with sigterm_as_interrupt():
                signal.raise_signal(signal.SIGTERM)
        signal.raise_signal(signal.SIGTERM)  # the test's own handler again: recorded, no exception
        assert seen == [signal.SIGTERM]
    finally:
        signal.signal(signal.SIGTERM, before)


def test_outside_the_main_thread_the_block_runs_with_the_handler_unchanged():
    handler_before = signal.getsignal(signal.SIGTERM)
    results: list[object] = []

    def worker() -> None:
        with sigterm_as_interrupt():
            results.append(signal.getsignal(signal.SIGTERM))

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join(timeout=10)
    assert not thread.is_alive()
    assert results == [handler_before]


def test_the_cli_stops_any_command_on_sigterm_as_on_ctrl_c(monkeypatch, capsys, tmp_path):
    from ftacq.app import cli
    from ftacq.app.commands import config

    def terminated(args) -> int:
        signal.raise_signal(signal.SIGTERM)
        raise AssertionError("SIGTERM did not interrupt the command")

    def ignored(signum, frame) -> None:  # the test's own handler: a CLI that forgot SIGTERM fails, not dies
        pass

    monkeypatch.setattr(config, "run_init", terminated)
    before = signal.signal(signal.SIGTERM, ignored)
    try:
        assert cli.main(["config", "init", str(tmp_path / "CELL.toml")]) == 130
        assert "interrupted" in capsys.readouterr().err
        assert signal.getsignal(signal.SIGTERM) is ignored
    finally:
        signal.signal(signal.SIGTERM, before)
