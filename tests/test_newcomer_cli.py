"""What a newcomer trips over in the CLI (issue 38, items 7 and 8): a calibration started with SIGINT ignored
says so at once; a --sim run resumes without --sim (run.json knows)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def _cli(*args: str, ignore_sigint: bool = False) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "ftacq.app.cli", *args], cwd=REPO_ROOT, env=env,
                          capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=300,
                          preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None)


def test_calibrate_says_at_once_that_sigint_is_ignored(tmp_path):
    done = _cli("calibrate", "--sim", "--dry-run", "--out", str(tmp_path / "runs"), ignore_sigint=True)
    assert done.returncode == 0, done.stderr
    first = done.stderr.splitlines()[0]
    assert first.startswith("ftacq calibrate: WARNING: Ctrl-C (SIGINT) is ignored in this process"), done.stderr
    assert "kill PID" in first
    plain = _cli("calibrate", "--sim", "--dry-run", "--out", str(tmp_path / "runs"))
    assert "SIGINT" not in plain.stderr


def test_a_sim_run_resumes_without_sim(tmp_path):
    from ftacq.app.config import config_from_dict
    from procedures.plan import home_configuration_rad, make_plan
    from procedures.run_folder import RunFolder

    config = config_from_dict({"robot": {"host": "(simulated)", "model": "UR5e", "mount": "floor"}}, "test")
    plan = make_plan(config.plan_settings(), home_configuration_rad("floor"))
    folder = RunFolder.create(tmp_path / "runs", config.to_dict(), plan.to_json(),
                              extra={"sim": {"sensor": "netft", "time_scale": 0.0, "model": "UR5e", "mount": "floor"}})
    folder.set_status("stopped", "interrupted")
    done = _cli("calibrate", "--resume", str(folder.path), "--dry-run")
    assert done.returncode == 0, done.stderr
    assert "made with --sim (run.json): resuming it on the simulated cell" in done.stderr
    assert "dry run: the robot did not move" in done.stdout


def _parsers():
    """Every parser of the CLI: (command words, parser)."""
    import argparse

    from ftacq.app.cli import build_parser

    out = []

    def walk(parser, words):
        out.append((words, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, words + [name])

    walk(build_parser(), [])
    return out


def test_help_texts_say_values_and_words_not_code_names():
    import re

    code_name = re.compile(r"\b(?:procedures|drivers|ftacq)\.[a-z_]+\.[A-Za-z_]+|\b(?:ftacq|procedures|drivers)/[a-z_/]+"
                           r"\.py\b")
    for words, parser in _parsers():
        text = " ".join(parser.format_help().split())  # argparse wraps lines: join them
        assert not code_name.search(text), (words, code_name.search(text).group(0))
    bridge = dict((" ".join(w), p) for w, p in _parsers())["bridge"].format_help()
    assert "(default 80;" in " ".join(bridge.split())


def test_a_bad_option_prints_the_commands_own_usage(capsys):
    import pytest

    from ftacq.app.cli import main

    for words in (["calibrate"], ["sensor", "info"], ["config", "check", "CELL.toml"]):
        with pytest.raises(SystemExit) as exit_:
            main([*words, "--foo"])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        command = " ".join(w for w in words if w != "CELL.toml")
        assert err.startswith(f"usage: ftacq {command} ") and \
            f"ftacq {command}: error: unrecognized arguments: --foo" in err, err


def test_sensor_and_robot_commands_run_against_the_simulated_cell(tmp_path, capsys):
    import json

    from ftacq.app.cli import main

    assert main(["sensor", "info", "--sim", "--seconds", "0.3"]) == 0
    assert "serial:" in capsys.readouterr().out
    out = tmp_path / "still.csv"
    assert main(["sensor", "record", "--sim", "--seconds", "0.3", "-o", str(out)]) == 0
    assert len(out.read_text().splitlines()) > 50
    capsys.readouterr()
    assert main(["robot", "info", "--sim", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "UR5e"
    assert main(["sensor", "info"]) == 2 and "or --sim" in capsys.readouterr().err
