#!/usr/bin/env bash
# Create .venv (Python 3.11) and install harborsight with its test tools. Idempotent: a
# re-run only installs what changed. Used by scripts/demo.sh and scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "harborsight needs Python 3.11 (bpy 4.5 does); found $("$PYTHON" --version)" >&2
    exit 1
fi

stamp=.venv/.installed
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
# reinstall when the project's requirements changed since the last install
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e ".[dev,train]"
    touch "$stamp"
fi
