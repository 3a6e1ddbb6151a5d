#!/usr/bin/env bash
# One round of side-by-side training jobs and its table: benchmarks/gpu_train_eval.sh with the same arguments, then
# rounds/round_results.py over the jobs' names into OUT_DIR/results.txt, then OUT_DIR/done (what a polling call
# waits for).
#
#   benchmarks/rounds/round.sh OUT_DIR TRAIN_SECONDS "NAME GPU TASK SEED [train.py overrides...]" ...
set -uo pipefail
out=$1
here=$(cd "$(dirname "$0")/.." && pwd)
rm -f "$out/done"
bash "$here/gpu_train_eval.sh" "$@"
names=()
for spec in "${@:3}"; do names+=("${spec%% *}"); done
python3 "$here/rounds/round_results.py" "$out" "${names[@]}" | tee "$out/results.txt"
touch "$out/done"
