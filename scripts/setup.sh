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
# the narx peer's library (mop.peers.narx), for its tests: its metadata pins numpy <= 2.3.5, which would
# downgrade mop's numpy; 0.9.0 runs with it, so it is installed without its dependencies (scipy and
# matplotlib are mop's own)
# the subnet peer's library (mop.peers.subnet), for its tests: deepSI 0.4.4 pins nonlinear_benchmarks < 0.2,
# whose data class 1.0 (mop's benchmarks extra) kept, so it is installed without its dependencies
case ",$extras," in
*,test,*)
  python -c "import sysidentpy" 2>/dev/null || pip install -q --no-deps sysidentpy==0.9.0
  python -c "import deepSI" 2>/dev/null || {
    pip install -q "nonlinear_benchmarks>=1.0"
    pip install -q --no-deps deepsi==0.4.4 cloudpickle
  }
  ;;
esac
