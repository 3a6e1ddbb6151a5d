#!/usr/bin/env bash
# ShadowHand and AllegroHand, one per GPU of a 2-GPU host, 900 s of training each, with our PPO given every remaining
# difference from rl_games' hand recipe at once (issue 58 item 3): 16384 envs x 8 steps in 4 mini-batches of 32768,
# one MLP trunk for the action means and the value, and rl_games' observation normalisation. The shipped recipes
# already carry rl_games' KL schedule and form, log-std, value normalisation, bounds loss and global gradient clip;
# with them seeds 1 and 2 gave ShadowHand 11.8 / 12.2 and AllegroHand 5.9 / 4.9 (targets 15 and 10), rl_games 25.2 on
# ShadowHand. Test mode on 16384 envs (the overrides reach it), seed 11, best and last checkpoints.
#
#   call 1: setsid nohup bash benchmarks/rounds/hands_rl_games_form.sh /tmp/hr SEED > /tmp/hr.log 2>&1 &
#   call 2: while [ ! -f /tmp/hr/done ]; do sleep 20; done; cat /tmp/hr/results.txt
set -uo pipefail
out=${1:-/tmp/hands_rl_games_form}
seed=${2:-1}
seconds=${TRAIN_SECONDS:-900}
form="num_envs=16384 train.runner.num_steps_per_env=8 train.algorithm.num_mini_batches=4"
form="$form +train.algorithm.share_trunk=True train.runner.obs_groups.critic=[policy]"
form="$form +train.algorithm.obs_normalization_form=rl_games"
bash "$(dirname "$0")/round.sh" "$out" "$seconds" \
  "shadow 0 ShadowHand $seed $form" \
  "allegro 1 AllegroHand $seed $form"
