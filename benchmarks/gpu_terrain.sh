#!/usr/bin/env bash
# On a GPU machine: issue 11's acceptance for one terrain task (AnymalTerrain or Go1Terrain) with shipped defaults.
#  1. train (CACHE=cold empties Warp's and the compiled step's caches first), at most LIMIT seconds;
#  2. from summary.json: the first iteration whose mean terrain level reaches 60 % of the top level, and its time;
#  3. test mode on 1024 envs over every level (curriculum off): tracking error and per-level survival;
# THROUGHPUT=1 also runs the flat/terrain throughput pair at 4096 envs and the no-sync check on terrain.
# Usage: bash benchmarks/gpu_terrain.sh TASK cold|warm OUTDIR [LIMIT_S]
# OUTDIR/done appears when everything is written. A 600-second run does not fit one device call with its
# evaluation: start it detached (setsid; a job merely sent to the background ends with the call) and wait in the next:
#   call 1: THROUGHPUT=1 setsid nohup bash benchmarks/gpu_terrain.sh AnymalTerrain warm /tmp/t 600 > /tmp/t.log 2>&1 < /dev/null &
#   call 2: while [ ! -f /tmp/t/done ]; do sleep 10; done; cat /tmp/t.log
set -uo pipefail
task=$1; cache=$2; out=$3; limit=${4:-580}
here=$(dirname "$0")
mkdir -p "$out"; rm -f "$out/done"
trap 'touch "$out/done"' EXIT  # also when a step fails
[ "$cache" = cold ] && rm -rf "${HOME}/.cache/warp" "/tmp/torchinductor_$(whoami)" "${HOME}/.triton/cache"
t0=$(date +%s.%N)
timeout -s INT "$limit" python3 train.py task="$task" headless=True runs_dir="$out/runs" > "$out/$task.$cache.log" 2>&1
rc=$?
t1=$(date +%s.%N)
grep -E "^\[it +(1|2|100|200|400|600|800|1000|1200|1500)/|\[train\] (done|stopped)|Error" "$out/$task.$cache.log" \
  | cut -c1-170
python3 -c "print('$task $cache: train.py rc=$rc, process wall %.1f s' % ($t1 - $t0))"
summary=$(ls -t "$out"/runs/"$task"/*/summary.json 2>/dev/null | head -1)
[ -n "$summary" ] || exit 1
cp "$summary" "$out/$task.$cache.summary.json"
python3 - "$summary" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
top = 9  # cfg/task/*Terrain.yaml numLevels 10 -> levels 0..9
hit = next((h for h in s["history"] if h.get("Episode/terrain_level", 0.0) >= 0.6 * top), None)
last = s["history"][-1] if s["history"] else {}
print(json.dumps({"task": s["task"], "device": s["device"], "terrain_level_final": last.get("Episode/terrain_level"),
                  "reached_60pct_at_iteration": hit and hit["iteration"],
                  "reached_60pct_at_train_s": hit and hit["time_s"],
                  "wall_time_s": s["wall_time_s"], "env_steps_per_s": s["env_steps_per_s"]}))
PY
ckpt=$(ls -t "$(dirname "$summary")"/model_*.pt 2>/dev/null | head -1)
[ -n "$ckpt" ] && timeout 300 python3 train.py task="$task" headless=True test=True checkpoint="$ckpt" num_envs=1024 \
  task.env.terrain.curriculum=False 2>&1 | grep "\[eval\] {" | cut -c1-1500
if [ "${THROUGHPUT:-0}" = 1 ]; then
  flat=${task%Terrain}
  for t in "$flat" "$task"; do
    python3 "$here/throughput.py" --task "$t" --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/throughput.jsonl" \
      | cut -c1-330
  done
  python3 "$here/check_no_sync.py" --task "$task" --num_envs 4096 2>/dev/null | tail -1 | tee -a "$out/nosync.jsonl"
fi
