#!/usr/bin/env bash
# One round of side-by-side training jobs and its table: benchmarks/gpu_train_eval.sh with the same arguments, then
# rounds/round_results.py over the jobs' names into OUT_DIR/results.txt, then OUT_DIR/done (what a polling call
# waits for). FIRST_GPU=K adds K to every job's GPU, so that a 4-GPU host runs two 2-GPU rounds at once.
#
#   benchmarks/rounds/round.sh OUT_DIR TRAIN_SECONDS "NAME GPU TASK SEED [train.py overrides...]" ...
set -uo pipefail
out=$1; seconds=$2; shift 2
here=$(cd "$(dirname "$0")/.." && pwd)
rm -f "$out/done"
specs=(); names=()
for spec in "$@"; do
  read -r name gpu rest <<<"$spec"
  specs+=("$name $((gpu + ${FIRST_GPU:-0})) $rest"); names+=("$name")
done
bash "$here/gpu_train_eval.sh" "$out" "$seconds" "${specs[@]}"
python3 "$here/rounds/round_results.py" "$out" "${names[@]}" | tee "$out/results.txt"
touch "$out/done"
