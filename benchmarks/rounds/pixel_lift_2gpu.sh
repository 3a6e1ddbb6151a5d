#!/usr/bin/env bash
# FrankaCubeLiftDepth and FrankaCubeLiftRGB (issue 58, "then the pixel lift tasks with what the hands taught") on a
# 2-GPU host: 0 % lifted after 720 s with their recipe (2026-11-26, 96 M env steps at 133 k/s, about half the steps
# the state-based FrankaCubeLift takes to learn). Here: 1140 s each, the hands' rl_games steering (their actor is a
# CNN and their critic reads the cube's pose, so no shared trunk), and CartpoleCamera's faster CNN (bfloat16,
# channels-last: +38 % training speed there).
#   GPU 0  FrankaCubeLiftDepth seed 1, PIXEL_SECONDS (default 1140, as ran 2026-11-28)
#   GPU 1  FrankaCubeLiftRGB seed 1, PIXEL_SECONDS
# FIRST_GPU=2 moves the pair to GPUs 2 and 3 (rounds/round.sh): a 4-GPU host runs two such rounds at once.
# Test mode: seed 11, best and last checkpoints, 1024 envs.
#
#   call 1: setsid nohup bash benchmarks/rounds/pixel_lift_2gpu.sh /tmp/px > /tmp/px.log 2>&1 &
#   then:   while [ ! -f /tmp/px/done ]; do sleep 20; done; cat /tmp/px/results.txt   (in calls <= 540 s, back to back)
set -uo pipefail
rounds=$(cd "$(dirname "$0")" && pwd)
# shellcheck source=rl_games_form.sh
. "$rounds/rl_games_form.sh"
form="$RL_GAMES_STEERING train.actor.cnn_precision=bfloat16 train.actor.cnn_channels_last=True"
bash "$rounds/round.sh" "${1:-/tmp/pixel_lift_2gpu}" "${PIXEL_SECONDS:-1140}" \
  "depth1 0 FrankaCubeLiftDepth 1 $form" \
  "rgb1 1 FrankaCubeLiftRGB 1 $form"
