#!/usr/bin/env bash
# Fresh-machine test command: make .venv (if missing), install torch (CPU build) and mop[test], lint, run pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test
. .venv/bin/activate
ruff check mop tests examples scripts
ruff format --check mop tests examples scripts
python -m pytest -n 2 -q --durations=15 "$@"
