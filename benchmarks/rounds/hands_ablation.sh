#!/usr/bin/env bash
# ShadowHand, seed 1, 900 s of training each, one variant per GPU of a 4-GPU host: which of rl_games' differences
# lift our PPO towards rl_games' 25.2 consecutive successes (issue 58 item 3). The shipped recipe (8192 envs x 16
# steps, separate actor and critic) gave 11.8 with seed 1 on one H200 (docs/RESULTS.md); each variant changes it as
# follows:
#   batch   16384 envs x 8 steps, 4 mini-batches of 32768 (rl_games' horizon and minibatch)
#   trunk   one MLP trunk for the action means and the value (rl_games' separate: False), the critic on the policy's
#           observation (ShadowHand has no privileged states by default, so the critic saw the same values before)
#   both    batch and trunk together
#   obsform observations normalised as rl_games does, (x - mean) / sqrt(var + 1e-5) instead of / (std + 1e-2)
# Test mode: seed 11, the best and the last checkpoint; overrides reach test mode too, so batch and both evaluate on
# 16384 envs (as the rl_games row of docs/RESULTS.md did), the others on 1024.
#
# Longer than one device call: start it detached, then wait for OUT/done in the next call:
#   call 1: setsid nohup bash benchmarks/rounds/hands_ablation.sh /tmp/ha > /tmp/ha.log 2>&1 &
#   call 2: while [ ! -f /tmp/ha/done ]; do sleep 20; done; cat /tmp/ha/results.txt
set -uo pipefail
out=${1:-/tmp/hands_ablation}
seconds=${TRAIN_SECONDS:-900}
here=$(cd "$(dirname "$0")/.." && pwd)
rm -f "$out/done"
batch="num_envs=16384 train.runner.num_steps_per_env=8 train.algorithm.num_mini_batches=4"
trunk="+train.algorithm.share_trunk=True train.runner.obs_groups.critic=[policy]"
bash "$here/gpu_train_eval.sh" "$out" "$seconds" \
  "batch 0 ShadowHand 1 $batch" \
  "trunk 1 ShadowHand 1 $trunk" \
  "both 2 ShadowHand 1 $batch $trunk" \
  "obsform 3 ShadowHand 1 +train.algorithm.obs_normalization_form=rl_games"
# One line per variant: consecutive successes with the best and the last checkpoint, training speed.
python3 "$here/rounds/hands_results.py" "$out" batch trunk both obsform | tee "$out/results.txt"
touch "$out/done"
