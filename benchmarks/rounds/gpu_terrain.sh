#!/usr/bin/env bash
# On a GPU machine: issue 11's acceptance for one terrain task (AnymalTerrain or Go1Terrain) with shipped defaults.
#  1. train (CACHE=cold empties Warp's and the compiled step's caches first), at most LIMIT seconds;
#  2. from the TensorBoard events: the first iteration whose mean terrain level reaches 60 % of the top level, and
#     its time since the process started;
#  3. test mode on 1024 envs over every level (curriculum off): tracking error and per-level survival (the whole
#     line in OUTDIR/TASK.CACHE.eval.txt);
# OVERRIDES="k=v ..." adds Hydra overrides to the training and the test run (say so wherever the numbers go).
# THROUGHPUT=1 also runs the flat/terrain throughput pair at 4096 envs and the no-sync check on terrain.
# Usage: bash benchmarks/rounds/gpu_terrain.sh TASK cold|warm OUTDIR [LIMIT_S]
# OUTDIR/done appears when everything is written. A 600-second run does not fit one device call with its
# evaluation: start it detached (setsid; a job merely sent to the background ends with the call) and wait in the next:
#   call 1: THROUGHPUT=1 setsid nohup bash benchmarks/rounds/gpu_terrain.sh AnymalTerrain warm /tmp/t 600 > /tmp/t.log 2>&1 < /dev/null &
#   call 2: while [ ! -f /tmp/t/done ]; do sleep 10; done; cat /tmp/t.log
set -uo pipefail
task=$1; cache=$2; out=$3; limit=${4:-580}
here=$(dirname "$0")
mkdir -p "$out"; rm -f "$out/done"
trap 'touch "$out/done"' EXIT  # also when a step fails
[ "$cache" = cold ] && rm -rf "${HOME}/.cache/warp" "/tmp/torchinductor_$(whoami)" "${HOME}/.triton/cache"
t0=$(date +%s.%N)
# --preserve-status: the run's own exit status (130: stopped by the SIGINT as designed; 139: a segfault), not 124
timeout --preserve-status -s INT "$limit" python3 train.py task="$task" headless=True runs_dir="$out/runs" ${OVERRIDES:-} > "$out/$task.$cache.log" 2>&1
rc=$?
t1=$(date +%s.%N)
grep -E "^\[it +(1|2|100|200|400|600|800|1000|1200|1500)/|\[train\] (done|stopped)|Error" "$out/$task.$cache.log" \
  | cut -c1-170
python3 -c "print('$task $cache: train.py rc=$rc, process wall %.1f s' % ($t1 - $t0))"
run_dir=$(ls -td "$out"/runs/"$task"/*/ 2>/dev/null | head -1)
[ -n "$run_dir" ] || { echo "no run directory under $out/runs/$task"; exit 1; }
if [ -f "$run_dir/summary.json" ]; then
  cp "$run_dir/summary.json" "$out/$task.$cache.summary.json"
else  # seen once on an H100 (session 8): the SIGINT ended train.py without its summary or last checkpoint
  echo "train.py (rc=$rc) left no summary.json; the level and times below come from its TensorBoard events"
fi
# Time to 60 % of the top level from the TensorBoard events (written every iteration, whatever ends the run),
# counted from the process start, so start-up and compilation are included.
python3 - "$run_dir" "$t0" <<'PY'
import json, sys
from omegaconf import OmegaConf
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
run_dir, t0 = sys.argv[1], float(sys.argv[2])
cfg = OmegaConf.load(f"{run_dir}/config.yaml")
top = int(cfg.task.env.terrain.numLevels) - 1
events = EventAccumulator(run_dir, size_guidance={"scalars": 0})
events.Reload()
level = events.Scalars("Episode/terrain_level")
hit = next((e for e in level if e.value >= 0.6 * top), None)
fps = [e.value for e in events.Scalars("Perf/total_fps")[10:]]
print(json.dumps({"task": cfg.task.name, "top_level": top, "iterations": len(level),
                  "terrain_level_final": level[-1].value if level else None,
                  "reached_60pct_at_iteration": hit and hit.step + 1,
                  "reached_60pct_at_process_s": hit and round(hit.wall_time - t0, 1),
                  "last_iteration_at_process_s": level and round(level[-1].wall_time - t0, 1),
                  "median_env_steps_per_s": sorted(fps)[len(fps) // 2] if fps else None}))
PY
ckpt=$(ls -t "$run_dir"/model_[0-9]*.pt 2>/dev/null | head -1)
[ -n "$ckpt" ] && timeout 300 python3 train.py task="$task" headless=True test=True checkpoint="$ckpt" num_envs=1024 \
  task.env.terrain.curriculum=False ${OVERRIDES:-} 2>&1 | grep "\[eval\] {" | tee "$out/$task.$cache.eval.txt" | cut -c1-1500
if [ "${THROUGHPUT:-0}" = 1 ]; then
  flat=${task%Terrain}
  for t in "$flat" "$task"; do
    python3 "$here/../throughput.py" --task "$t" --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/throughput.jsonl" \
      | cut -c1-330
  done
  python3 "$here/../diagnostics/check_no_sync.py" --task "$task" --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/nosync.jsonl"
fi
