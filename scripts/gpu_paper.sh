#!/usr/bin/env bash
# The paper preset measured on one CUDA GPU, in one command:
#   1. `mop bench train` on the paper configuration: mop's trainer beside the plain Hugging Face GPT-2 loop,
#      phase by phase, and again with CUDA graphs (--compile graphs);
#   2. `mop reproduce linear --preset paper --without gru` (12 x 256, batch 64, M = 20000, N = 1000),
#      train.steps=STEPS;
#   3. eval.json, report.md, the figure and timings.json written to OUT.
#
# Usage: OUT=docs/results/paper/linear bash scripts/gpu_paper.sh [STEPS]   (STEPS: 10000, the paper's)
# PYTHON names the interpreter (default python3); the mop checkout is put on PYTHONPATH, nothing installed.
set -uo pipefail

OUT=${OUT:-runs/gpu_paper}
STEPS=${1:-10000}
PY=${PYTHON:-python3}
WORK=${WORK:-/tmp/mop_gpu_paper}
DEVICE=${DEVICE:-cuda}  # DEVICE=cpu BENCH_ARGS="--steps 2 --warmup 1" checks the script on a CPU
BENCH_ARGS=${BENCH_ARGS:-}
TRAIN_ARGS=${TRAIN_ARGS:-}  # e.g. TRAIN_ARGS=train.compile=graphs
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
log="$OUT/log.txt"
now() { date +%s.%N; }

{
  date -u
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
  "$PY" -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.version.cuda, \
torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'no GPU')"
  nproc
} >"$OUT/env.txt" 2>&1
cat "$OUT/env.txt"

t0=$(now)
echo "== mop bench train (paper configuration, compile auto, phase by phase)" | tee -a "$log"
if ! "$PY" -m mop bench train --device "$DEVICE" $BENCH_ARGS --phases --json >"$OUT/bench.json" 2>>"$log"; then
  echo "== compiled bench failed; again with --compile off" | tee -a "$log"
  "$PY" -m mop bench train --device "$DEVICE" $BENCH_ARGS --compile off --phases --json >"$OUT/bench.json" \
    2>>"$log"
fi
cat "$OUT/bench.json"
echo "== mop bench train --compile graphs (CUDA graphs), mop only" | tee -a "$log"
"$PY" -m mop bench train --device "$DEVICE" $BENCH_ARGS --compile graphs --phases --skip-hf --json \
  >"$OUT/bench_graphs.json" 2>>"$log"
cat "$OUT/bench_graphs.json"
t1=$(now)

# REPRODUCE_ARGS: the paper preset also trains the GRU baseline (~6 min on an H200); leave it out by default
REPRODUCE_ARGS=${REPRODUCE_ARGS---without gru}
echo "== mop reproduce linear --preset paper $REPRODUCE_ARGS train.steps=$STEPS $TRAIN_ARGS" | tee -a "$log"
"$PY" -m mop reproduce linear --preset paper $REPRODUCE_ARGS --out "$WORK/linear" --runs "$WORK/runs" \
  "train.steps=$STEPS" "train.device=$DEVICE" $TRAIN_ARGS >>"$log" 2>&1
rc=$?
t2=$(now)
tail -5 "$log"
for f in eval.json report.md linear_error.png; do
  [ -f "$WORK/linear/$f" ] && cp "$WORK/linear/$f" "$OUT/"
done

"$PY" - "$WORK/runs" "$OUT" "$t0" "$t1" "$t2" "$rc" "$STEPS" <<'EOF'
import json, pathlib, statistics, sys

import torch

runs, out, t0, t1, t2, rc, steps = sys.argv[1:]
timings = {
    "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none (CPU)",
    "torch": torch.__version__,
    "bench_train": json.loads(pathlib.Path(out, "bench.json").read_text() or "{}"),
    "bench_train_graphs": json.loads(pathlib.Path(out, "bench_graphs.json").read_text() or "{}"),
    "bench_wall_s": float(t1) - float(t0),
    "reproduce_wall_s": float(t2) - float(t1),
    "reproduce_rc": int(rc),
    "train_steps": int(steps),
    "runs": {},
}
for run in sorted(pathlib.Path(runs).glob("*")):
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    train = [r for r in rows if "steps_per_s" in r]
    val = [r for r in rows if "val_loss" in r]
    timings["runs"][run.name] = {
        "step": train[-1]["step"] if train else None,
        # each logged rate covers the steps since the last log; the first includes compilation
        "steps_per_s_median": statistics.median(r["steps_per_s"] for r in train[1:] or train) if train else None,
        "steps_per_s_first_log": train[0]["steps_per_s"] if train else None,
        "loss": train[-1]["loss"] if train else None,
        "val_loss": val[-1]["val_loss"] if val else None,
    }
pathlib.Path(out, "timings.json").write_text(json.dumps(timings, indent=1) + "\n")
print(json.dumps(timings, indent=1))
EOF
exit "$rc"
