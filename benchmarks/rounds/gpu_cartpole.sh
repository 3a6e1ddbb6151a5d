#!/usr/bin/env bash
# On a GPU machine: Cartpole time-to-criterion with a cold and a warm Warp kernel cache, then throughput.
# Usage: bash benchmarks/rounds/gpu_cartpole.sh OUTDIR
set -uo pipefail
out=$1; mkdir -p "$out"
for cache in cold warm; do
  [ "$cache" = cold ] && rm -rf "${HOME}/.cache/warp"
  t0=$(date +%s.%N)
  python3 train.py task=Cartpole headless=True runs_dir="$out/runs_$cache" > "$out/Cartpole.$cache.log" 2>&1
  t1=$(date +%s.%N)
  python3 - "$out" "$cache" "$t0" "$t1" <<'PY'
import glob, json, sys
out, cache, t0, t1 = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
s = json.load(open(sorted(glob.glob(f"{out}/runs_{cache}/Cartpole/*/summary.json"))[-1]))
first = next((h["iteration"], round(h["time_s"], 1)) for h in s["history"] if h.get("mean_episode_length", 0) >= 475)
print(f"Cartpole {cache}: process wall {t1 - t0:.1f} s, summary wall {s['wall_time_s']:.1f} s, "
      f"final ep_len {s['mean_episode_length']:.1f}, first iteration >= 475: {first}, "
      f"train steps/s {s['env_steps_per_s']:.0f}")
PY
done
for n in 4096 16384 65536; do
  python3 benchmarks/throughput.py --task Cartpole --num_envs $n 2>/dev/null | tail -1 | tee -a "$out/throughput.jsonl" | cut -c1-330
done
