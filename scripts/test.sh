#!/usr/bin/env bash
# Fresh-machine test command: make .venv (if missing), install torch (CPU build) and mop[test,docs], lint,
# build the documentation site (strict: a broken link or reference fails), run pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test,docs
. .venv/bin/activate
# one torch thread per pytest worker (2 workers on the 2 CI cores); torch's default of one per core made each
# worker spin against the other, and the fresh-clone suite took 10 min 14 s of pytest against about 5-7 min
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
ruff check mop tests examples scripts
ruff format --check mop tests examples scripts
NO_MKDOCS_2_WARNING=1 mkdocs build --strict --quiet --site-dir "$(mktemp -d)"
python -m pytest -n 2 -q --durations=15 "$@"
