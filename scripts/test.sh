#!/usr/bin/env bash
# Set up (if needed), lint, and run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# a .venv set up before hypothesis or pytest-xdist joined the dev extra (its stamp newer
# than pyproject.toml)
.venv/bin/python -c "import hypothesis, xdist" 2>/dev/null || .venv/bin/python -m pip install --quiet -e ".[dev]"
.venv/bin/ruff check harborsight tests benchmarks
# two workers (HARBORSIGHT_TEST_WORKERS to change; 0 runs in this process)
exec .venv/bin/python -m pytest -q -n "${HARBORSIGHT_TEST_WORKERS:-2}" "$@"
