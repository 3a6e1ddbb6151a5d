#!/usr/bin/env bash
# ShadowHand, seed 1, 900 s of training each, one variant per GPU of a 4-GPU host: which of the three settings the
# hands' recipes took from rl_games on 2026-11-28 made ShadowHand go from 11.8 to 25.7 consecutive successes (and
# AllegroHand from 5.9 to 14.8; issue 58 item 3). Each variant takes one of them back out of the shipped recipe:
#   shipped   the recipe as it is (16384 envs x 8 steps, shared trunk, rl_games' input scaling)
#   batch     8192 envs x 16 steps in 4 mini-batches of 32768, as before
#   trunk     separate actor and critic networks
#   obsform   rsl-rl-lib's input scaling, (x - mean) / (std + 1e-2)
# Test mode: seed 11, the best and the last checkpoint, on the run's own number of envs (num_envs is given in every
# variant because the overrides reach test mode too, after gpu_train_eval.sh's 1024).
#
# Longer than one device call: start it detached, then wait for OUT/done in the next call:
#   call 1: setsid nohup bash benchmarks/rounds/hands_ablation.sh /tmp/ha > /tmp/ha.log 2>&1 &
#   call 2: while [ ! -f /tmp/ha/done ]; do sleep 20; done; cat /tmp/ha/results.txt
set -uo pipefail
out=${1:-/tmp/hands_ablation}
seconds=${TRAIN_SECONDS:-900}
# One line per variant: consecutive successes with the best and the last checkpoint, training speed.
bash "$(dirname "$0")/round.sh" "$out" "$seconds" \
  "shipped 0 ShadowHand 1 num_envs=16384" \
  "batch 1 ShadowHand 1 num_envs=8192 train.runner.num_steps_per_env=16" \
  "trunk 2 ShadowHand 1 num_envs=16384 train.algorithm.share_trunk=False" \
  "obsform 3 ShadowHand 1 num_envs=16384 train.algorithm.obs_normalization_form=rsl_rl"
