"""One line per run of a hands round: consecutive successes in test mode with the best and the last checkpoint.

    python benchmarks/rounds/hands_results.py OUT_DIR NAME [NAME ...]

Reads the files ``benchmarks/gpu_train_eval.sh`` leaves in OUT_DIR (<NAME>.eval_best.json, .eval_last.json,
.summary.json).
"""
from __future__ import annotations

import json
import pathlib
import sys


def read(path: pathlib.Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def consecutive_successes(report: dict):
    for key in ("consecutive_successes", "task/consecutive_successes"):
        for where in (report, report.get("metrics", {}), report.get("task_metrics", {})):
            if isinstance(where, dict) and key in where:
                return where[key]
    return None


def main(out: pathlib.Path, names: list[str]) -> None:
    for name in names:
        best, last = read(out / f"{name}.eval_best.json"), read(out / f"{name}.eval_last.json")
        summary = read(out / f"{name}.summary.json")
        speed = summary.get("env_steps_per_s") or summary.get("steps_per_s")
        print(f"{name}: best {consecutive_successes(best)}, last {consecutive_successes(last)}, "
              f"env-steps/s {speed}, iterations {summary.get('iterations')}")
        if consecutive_successes(best) is None:
            print(f"  {name}.eval_best.json: {json.dumps(best)[:600]}")


if __name__ == "__main__":
    main(pathlib.Path(sys.argv[1]), sys.argv[2:])
