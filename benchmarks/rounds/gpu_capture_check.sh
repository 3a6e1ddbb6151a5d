#!/usr/bin/env bash
# On one GPU: every task's shipped step (compiled and captured) against its eager twin, one JSON line per task
# (benchmarks/diagnostics/check_step_graph.py: rewards, resets, task metrics and, for the tasks whose resets refresh the
# kinematics, the reset worlds' poses). A captured step runs none of the step's Python, so what only Python does
# there is lost on the GPU and never on the CPU: this is the check the CPU suite cannot make. A second eager twin
# (--floor) gives what two eager steps from one state already differ by on the GPU, which is not held against the
# shipped step (contact forces of many-contact tasks).
# Usage: bash benchmarks/rounds/gpu_capture_check.sh OUTDIR [NUM_ENVS] [STEPS]; TASKS="A B" checks only those tasks.
set -uo pipefail
out=$1; envs=${2:-512}; steps=${3:-120}
mkdir -p "$out"
here=$(dirname "$0")
refresh="FrankaCubeLift FrankaCubeLiftDepth FrankaCubeLiftRGB FrankaCubeStack Quadcopter BallBalance"
for task in ${TASKS:-Cartpole Ant Humanoid Anymal Go1 G1 FrankaCabinet AllegroHand ShadowHand $refresh CartpoleCamera}; do
  extra=""; n=$steps
  # the Franka cube episodes last 300 steps: a shorter check resets no world, so it checks no reset pose
  [[ " $refresh " == *" $task "* ]] && extra="--reset_poses" && [[ $task == Franka* ]] && n=$((steps > 320 ? steps : 320))
  timeout 300 python3 "$here/../diagnostics/check_step_graph.py" --task "$task" --num_envs "$envs" --steps "$n" --floor $extra \
    2>"$out/$task.err" | tail -1 | tee -a "$out/capture_check.jsonl"
done
