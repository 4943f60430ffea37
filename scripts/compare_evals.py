"""Compare two `mop reproduce all` output trees: per experiment, condition and predictor, the largest
difference of the mean error curve (same seed should give the same numbers after a refactor).

    python scripts/compare_evals.py BEFORE_DIR AFTER_DIR
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

MARKER = "complete.json"  # mop.outputs.MARKER: written last by a finished `mop reproduce`


def conditions(data: dict) -> dict[str, dict]:
    """condition name -> {predictor: curves}; older eval.json files nest sweeps under "levels"."""
    if "conditions" in data:
        return {k: v["predictors"] for k, v in data["conditions"].items()}
    if "levels" in data:
        return {f"test noise variance {k}": v["predictors"] for k, v in data["levels"].items()}
    return {"test": data.get("predictors", {})}


def main(before: Path, after: Path) -> None:
    for path in sorted(before.glob("*/eval.json")):
        other = after / path.parent.name / "eval.json"
        if not other.exists():
            print(f"{path.parent.name}: missing in {after}")
            continue
        incomplete = [p.parent for p in (path, other) if not (p.parent / MARKER).exists()]
        if incomplete:  # a stopped `mop reproduce`: its files may mix two runs
            print(f"{path.parent.name}: incomplete in {incomplete[0].parent} (no {MARKER}); rerun it")
            continue
        old, new = conditions(json.loads(path.read_text())), conditions(json.loads(other.read_text()))
        for cond, preds in old.items():
            for name, curves in preds.items():
                if name not in new.get(cond, {}):
                    print(f"{path.parent.name} [{cond}] {name}: absent after")
                    continue
                diff = max(abs(a - b) for a, b in zip(curves["error"], new[cond][name]["error"], strict=True))
                mark = "" if diff < 1e-9 else "  <-- differs"
                print(f"{path.parent.name} [{cond}] {name}: max |d error_t| = {diff:.2e}{mark}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
