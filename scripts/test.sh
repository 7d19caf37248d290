#!/usr/bin/env bash
# Set up (if needed), lint, and run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# a .venv set up before hypothesis joined the dev extra (its stamp newer than pyproject.toml)
.venv/bin/python -c "import hypothesis" 2>/dev/null || .venv/bin/python -m pip install --quiet -e ".[dev]"
.venv/bin/ruff check harborsight tests benchmarks
exec .venv/bin/python -m pytest -q "$@"
