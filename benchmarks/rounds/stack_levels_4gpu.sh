#!/usr/bin/env bash
# FrankaCubeStack's staged reward, which lever gets the policy past the grasp (issue 58's round of 2026-11-28: both
# seeds closed the gripper on A within the first minute and never lifted it in 19 minutes; the mean action std was
# 0.15 by the fourth minute). The grasp stage pays 2 / 8 on the first held step and the whole lift 1 / 8 more, while
# FrankaCubeLift, which lifts in every seed, pays its lift 4 times its grasp. One change per GPU, seed 1, on the
# round's recipe (the hands' rl_games settings and value normalisation, rounds/stack_staged_2gpu.sh):
#   GPU 0  lift  stage levels 0, 1, 3, 4, 6, 8: the grasp pays 1 over reaching, clearing B 2 more
#   GPU 1  osc   IsaacGymEnvs' operational-space control: one action lifts (the scripted stack in
#                tests/test_franka_cube_stack_staged.py uses it)
#   GPU 2  both  the two together
#   GPU 3  floor the shipped levels and control, the action std held at 0.2 or more
# Test mode: seed 11, best and last checkpoints, 1024 envs. Read furthest_stage in the jobs' summary.json (0 reach,
# 1 grasp, 2 carry, ... 5 stacked) beside success: a lever that gets past 1.0 is the one to give two seeds and 20 minutes.
#
#   call 1: setsid nohup bash benchmarks/rounds/stack_levels_4gpu.sh /tmp/sl > /tmp/sl.log 2>&1 &
#   then:   while [ ! -f /tmp/sl/done ]; do sleep 20; done; cat /tmp/sl/results.txt   (in calls <= 540 s, back to back)
set -uo pipefail
rounds=$(cd "$(dirname "$0")" && pwd)
# shellcheck source=rl_games_form.sh
. "$rounds/rl_games_form.sh"
form="$RL_GAMES_FORM +train.algorithm.normalize_value=True"
lift="task.env.reward.stageLevels=[0.0,1.0,3.0,4.0,6.0,8.0]"
osc="task.env.controlType=osc"
bash "$rounds/round.sh" "${1:-/tmp/stack_levels_4gpu}" "${STACK_SECONDS:-900}" \
  "lift 0 FrankaCubeStack 1 $form $lift" \
  "osc 1 FrankaCubeStack 1 $form $osc" \
  "both 2 FrankaCubeStack 1 $form $lift $osc" \
  "floor 3 FrankaCubeStack 1 $form +train.actor.distribution_cfg.std_range=[0.2,10.0]"
