"""Learning curve as a PNG: mean episode reward (and, with --length, episode length) against wall-clock training
time, read from the ``history`` of one or more runs' ``summary.json``.

Each history record is one training iteration (``time_s``: cumulative collection + update time of the run;
``mean_episode_reward``: episodes that ended in that iteration, absent when none did). The x axis is that training
time, not the process wall time: start-up (kernel compilation, model build) is reported in the title from
``wall_time_s - train_time_s`` of the first run.

  python benchmarks/learning_curve.py runs/Humanoid/<stamp>/summary.json --out docs/humanoid_learning_curve.png
  python benchmarks/learning_curve.py runs/Ant/*/summary.json --labels seed42 seed7 --out docs/ant_curve.png
  python benchmarks/learning_curve.py a/summary.json b/summary.json --key Episode/terrain_level --out terrain.png

A sweep (``python train.py -m ...``) draws the same curves for its jobs by itself (``sweep.png``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from isaacgymenvs_mw.learning.sweep import curve, plot_curves as plot  # noqa: F401  (curve: used by its test)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("summaries", nargs="+", type=Path, help="summary.json files written by train.py")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--labels", nargs="*", help="one legend label per summary (default: its run folder)")
    parser.add_argument("--length", action="store_true", help="add a panel with the mean episode length")
    parser.add_argument("--key", action="append", default=[],
                        help="add a panel with this per-iteration history key, e.g. Episode/terrain_level (repeatable)")
    args = parser.parse_args()
    labels = args.labels or [p.parent.name for p in args.summaries]
    if len(labels) != len(args.summaries):
        parser.error(f"--labels gives {len(labels)} labels for {len(args.summaries)} summaries")
    summaries = []
    for path in args.summaries:
        data = json.loads(path.read_text())
        if not any(r.get("mean_episode_reward") is not None for r in data.get("history", [])):
            parser.error(f"{path}: its history has no iteration with a finished episode; nothing to plot")
        for key in args.key:
            if not any(r.get(key) is not None for r in data.get("history", [])):
                known = sorted({k for r in data.get("history", []) for k in r if k not in ("iteration", "losses")})
                parser.error(f"--key {key}: {path} has no iteration with it; its history has {', '.join(known)}")
        summaries.append(data)
    keys = ["mean_episode_reward"] + (["mean_episode_length"] if args.length else []) + args.key
    plot(summaries, labels, args.out, keys)
    print(json.dumps({"png": str(args.out), "runs": len(summaries)}))


if __name__ == "__main__":
    main()
