#!/usr/bin/env bash
# The hands' second seed on a 2-GPU host (issue 58; only 1- and 2-GPU kinds were lent on 2026-11-28), then, in the
# time a 30-minute lease leaves, FrankaCubeStack's staged reward as a first look (it has never been trained on a GPU;
# its target is >= 80 % stacked within 20 minutes, which this round cannot reach: it shows how far the reward gets
# in STACK_SECONDS).
#   GPU 0  ShadowHand seed 2, 900 s, then FrankaCubeStack seed 1, STACK_SECONDS (default 300)
#   GPU 1  AllegroHand seed 2, 900 s, then FrankaCubeStack seed 2, STACK_SECONDS
# Test mode: seed 11, best and last checkpoints; the hands on 16384 envs (the override reaches test mode),
# FrankaCubeStack on 1024. A FrankaCubeStack run stopped by SIGTERM still leaves its checkpoint and summary.
#
#   call 1: setsid nohup bash benchmarks/rounds/hands_seed2_2gpu.sh /tmp/hs > /tmp/hs.log 2>&1 &
#   then:   while [ ! -f /tmp/hs/done ]; do sleep 20; done; cat /tmp/hs/results.txt   (in calls <= 540 s, back to back)
set -uo pipefail
out=${1:-/tmp/hands_seed2_2gpu}
here=$(cd "$(dirname "$0")/.." && pwd)
rm -f "$out/done"
for pair in "0 shadow2 ShadowHand 2 stack1 1" "1 allegro2 AllegroHand 2 stack2 2"; do
  read -r gpu hand task seed stack stack_seed <<<"$pair"
  (
    bash "$here/gpu_train_eval.sh" "$out" "${HAND_SECONDS:-900}" "$hand $gpu $task $seed num_envs=16384"
    bash "$here/gpu_train_eval.sh" "$out" "${STACK_SECONDS:-300}" "$stack $gpu FrankaCubeStack $stack_seed"
  ) &
done
wait
python3 "$here/rounds/round_results.py" "$out" shadow2 allegro2 stack1 stack2 | tee "$out/results.txt"
touch "$out/done"
