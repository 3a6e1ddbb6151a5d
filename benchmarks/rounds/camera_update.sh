#!/usr/bin/env bash
# On one GPU: CartpoleCamera's training speed at 4096 envs with each option of its CNN (issue 61, item 3), then its
# learning curve with each option for seeds 1 and 2. Goal: training >= 0.30 M env-steps/s with the curve unchanged
# (mean episode length >= 475, the cap being 499, within the same number of iterations as float32).
# Variants (train YAML keys, docs/config.md): base (float32, NCHW), bf16 (actor.cnn_precision=bfloat16),
# nhwc (actor.cnn_channels_last=True), both. Images are stored as uint8 in every variant (the shipped behaviour).
# Usage: bash benchmarks/rounds/camera_update.sh OUTDIR [PART]   PART: speed, curves or all (default all)
# Everything is written under OUTDIR; OUTDIR/done appears at the end, so the whole round (about 20 min) can run
# detached and be waited for in a second device call:
#   call 1: setsid nohup bash benchmarks/rounds/camera_update.sh /tmp/cam > /tmp/cam.log 2>&1 &
#   call 2: while [ ! -f /tmp/cam/done ]; do sleep 10; done; cat /tmp/cam/speed.txt /tmp/cam/curves.txt
set -uo pipefail
out=$1; part=${2:-all}
mkdir -p "$out"; rm -f "$out/done"
declare -A variants=(
  [base]=""
  [bf16]="train.actor.cnn_precision=bfloat16"
  [nhwc]="train.actor.cnn_channels_last=True"
  [both]="train.actor.cnn_precision=bfloat16 train.actor.cnn_channels_last=True"
)
order="base bf16 nhwc both"
nvidia-smi --query-gpu=name,memory.used,utilization.gpu --format=csv > "$out/gpu.txt" 2>&1

if [ "$part" = speed ] || [ "$part" = all ]; then
  # Training env-steps/s (throughput.py prints its progress lines, then the JSON object on the last line; 5 timed iterations after 2 warm-up ones; the update is captured from the second on).
  # base runs first and last: the two base numbers bound the drift of the machine over the round.
  for name in $order base; do
    # shellcheck disable=SC2086
    python3 benchmarks/throughput.py --task CartpoleCamera --num_envs 4096 --sim_device cuda:0 --steps 200 \
      --train_iterations 5 ${variants[$name]} > "$out/speed_$name.json" 2> "$out/speed_$name.err"
    python3 -c "import json,sys; r=json.loads(open(sys.argv[1]).read().splitlines()[-1]); print(sys.argv[2], 'train %.3f M/s' % (r['train_env_steps_per_s']/1e6), 'VecTask.step %.3f M/s' % (r['vectask_env_steps_per_s']/1e6), r['device'])" \
      "$out/speed_$name.json" "$name" 2>&1 | tee -a "$out/speed.txt"
  done
fi

if [ "$part" = curves ] || [ "$part" = all ]; then
  # 150 iterations (the shipped max_iterations) per run, one run at a time so that steps/s are the GPU's alone.
  for name in $order; do
    for seed in 1 2; do
      # shellcheck disable=SC2086
      timeout 400 python3 train.py task=CartpoleCamera headless=True num_envs=4096 seed=$seed \
        runs_dir="$out/runs_${name}_$seed" ${variants[$name]} > "$out/train_${name}_$seed.log" 2>&1
      echo "rc=$?" >> "$out/train_${name}_$seed.log"
      summary=$(ls -t "$out"/runs_${name}_$seed/*/*/summary.json 2>/dev/null | head -1)
      if [ -z "$summary" ]; then echo "$name seed $seed: no summary ($(tail -1 "$out/train_${name}_$seed.log"))" \
        | tee -a "$out/curves.txt"; continue; fi
      cp "$summary" "$out/summary_${name}_$seed.json"
      # the first iteration whose mean episode length is >= 475, the last one's, the steady rate and its split
      python3 - "$summary" "$name" "$seed" <<'EOF' | tee -a "$out/curves.txt"
import json, sys
s = json.load(open(sys.argv[1]))
h = s["history"]
hit = next((r["iteration"] for r in h if (r.get("mean_episode_length") or 0) >= 475), None)
last = next((r["mean_episode_length"] for r in reversed(h) if r.get("mean_episode_length") is not None), None)
steady = h[1:] or h
collect = sum(r["collect_s"] for r in steady) / len(steady)
learn = sum(r["learn_s"] for r in steady) / len(steady)
print(f"{sys.argv[2]} seed {sys.argv[3]}: length >= 475 at iteration {hit}, final length {last}, "
      f"{s['env_steps_per_s'] / 1e6:.3f} M env-steps/s, per iteration collect {collect:.3f} s learn {learn:.3f} s")
EOF
    done
  done
  python3 benchmarks/learning_curve.py "$out"/summary_*.json --length --out "$out/curves.png" > /dev/null 2>&1
fi
touch "$out/done"
