#!/usr/bin/env bash
# One entry point for a fresh machine with only Python (3.10-3.12) and pip.
#   ./run.sh demo   full calibration against the simulated cell (robot + Net F/T on loopback)
#   ./run.sh test   the test suite
#   ./run.sh check  the linter (ruff) and the type checker (mypy), configured in pyproject.toml
# Both create (once) and reuse a virtual environment in .venv.
set -euo pipefail
cd "$(dirname "$0")"
pick_python() {
  for py in "${FTACQ_PYTHON:-}" python3.12 python3.11 python3.10 python3; do
    [ -n "$py" ] || continue
    if command -v "$py" >/dev/null 2>&1 && "$py" 2>/dev/null -c 'import sys; sys.exit(not ((3,10) <= sys.version_info[:2] <= (3,12)))'; then
      echo "$py"; return 0
    fi
  done
  echo "ftacq needs Python 3.10, 3.11 or 3.12 (ur-rtde ships wheels only for those)" >&2
  return 1
}
setup() {
  if [ ! -x .venv/bin/python ]; then
    "$(pick_python)" -m venv .venv
  fi
  stamp=.venv/.ftacq-installed
  if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e '.[test,ros2]'
    .venv/bin/python -m compileall -q -j 2 ftacq drivers procedures tests >/dev/null  # an editable install compiles nothing
    touch "$stamp"
  fi
}
cmd="${1:-}"; shift || true
case "$cmd" in
  demo) setup; exec .venv/bin/ftacq calibrate --sim --yes "$@" ;;
  # the suite starts Python processes by the hundred (commands, simulated controllers): they share compiled bytecode
  test) setup; exec env -u PYTHONDONTWRITEBYTECODE .venv/bin/python -m pytest -n 4 --dist loadgroup "$@" ;;
  check) setup; .venv/bin/ruff check ftacq drivers procedures tests benchmarks
         if grep -q '^\[tool.mypy\]' pyproject.toml; then .venv/bin/mypy; fi ;;
  setup) setup ;;
  *) echo "usage: ./run.sh demo|test|check|setup [args...]" >&2; exit 2 ;;
esac
