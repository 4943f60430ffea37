#!/usr/bin/env bash
# Make ./.venv with torch and mop installed. Argument: pip extras to add (e.g. "test"). Reuses an existing .venv.
# torch: keeps an installed one (GPU users install theirs first); otherwise the CPU build 2.13.0.
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-}"
[ -x .venv/bin/python ] || python3 -m venv .venv
. .venv/bin/activate
python -c "import torch" 2>/dev/null || pip install -q torch==2.13.0
pip install -q -e ".${extras:+[$extras]}"
