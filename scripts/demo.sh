#!/usr/bin/env bash
# Set up (if needed) and run the demo on the bundled sample frames.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/harborsight demo "$@"
