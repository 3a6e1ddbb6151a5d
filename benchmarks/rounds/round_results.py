"""One line per run of a training round: the task's test-mode headline (the hands' consecutive successes, else the
success rate, else the share of episodes to the time limit) with the best and the last checkpoint, the training
speed, and FrankaCubeStack's furthest stage in training.

    python benchmarks/rounds/round_results.py OUT_DIR NAME [NAME ...]

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


HEADLINES = ("consecutive_successes", "success", "timeout_fraction")  # the first a report has is printed


def headline(report: dict) -> tuple[str, float] | tuple[None, None]:
    for key in HEADLINES:
        for name in (key, f"task/{key}"):
            for where in (report, report.get("metrics", {}), report.get("task_metrics", {})):
                if isinstance(where, dict) and name in where:
                    return key, where[name]
    return None, None


def main(out: pathlib.Path, names: list[str]) -> None:
    for name in names:
        best, last = read(out / f"{name}.eval_best.json"), read(out / f"{name}.eval_last.json")
        summary = read(out / f"{name}.summary.json")
        speed = summary.get("env_steps_per_s") or summary.get("steps_per_s")
        key, value = headline(best)
        stage = f", furthest stage {summary['furthest_stage']:.2f}" if "furthest_stage" in summary else ""
        print(f"{name}: {key or headline(last)[0]} best {value}, last {headline(last)[1]}, env-steps/s {speed}, "
              f"iterations {summary.get('iterations')}{stage}")
        if value is None:
            print(f"  {name}.eval_best.json: {json.dumps(best)[:600]}")


if __name__ == "__main__":
    main(pathlib.Path(sys.argv[1]), sys.argv[2:])
