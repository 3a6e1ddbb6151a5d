#!/usr/bin/env bash
# On one host with as many GPUs as the largest count: the time to a solved task at one total number of envs split over
# 1, 2 and 4 GPUs (torchrun, one simulator per GPU, the total envs divided among them).
#   go1      Go1, 4096 envs in total, 400 iterations, a checkpoint every 25 iterations; afterwards every checkpoint
#            is evaluated in test mode in iteration order (1024 episodes; EVALS_PER_GPU, default 4, evaluations
#            side by side on each GPU of the host) until one meets the criterion. Solved: timeout_fraction >= 0.97
#            and lin_vel_tracking_error <= 0.25 m/s.
#   allegro  AllegroHand, 8192 envs in total, BUDGET_S seconds of training (max_train_time_s, default 1500). Solved
#            at 5 and at 10: IGE's consecutive_successes, the task's own running metric, read from summary.json's
#            history.
# The time is from process start: start-up (summary wall time minus training time) plus the training time at the
# first checkpoint or iteration that meets the criterion. One seed decides little where the criterion sits at the edge
# of a seed's noise: SEEDS=1,2,3 runs each GPU count once per seed (one row each; default: the task's own seed).
# Usage: bash benchmarks/gpu_time_to_solve.sh go1|allegro OUTDIR [GPU counts, default 1,2,4] [train.py overrides...]
#   e.g. SEEDS=1,2 bash benchmarks/gpu_time_to_solve.sh allegro OUT 1,2,4 train.actor.distribution_cfg.std_type=log
set -uo pipefail
name=$1; out=$2; counts=${3:-1,2,4}; shift $(( $# < 3 ? $# : 3 ))
overrides=("$@")
seeds=${SEEDS:-default}
mkdir -p "$out"
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # NVLink multicast off
case "$name" in
  go1) task=Go1; total=4096; train_args=(max_iterations=400 train.runner.save_interval=25) ;;
  allegro) task=AllegroHand; total=8192; train_args=(max_iterations=100000 max_train_time_s="${BUDGET_S:-1500}") ;;
  *) echo "unknown run '$name': go1 or allegro"; exit 2 ;;
esac
# Go1's criterion, read by the early stop below and by the table at the end
export SOLVED_TIMEOUT_FRACTION=0.97 SOLVED_TRACKING_ERROR=0.25
# Evaluations side by side on every GPU of the host, whatever the row's count: each is mostly process start-up (about
# 30 s, on the host's CPU), and 1024 Go1 worlds use little of a GPU.
host_gpus=$(nvidia-smi -L | wc -l); side_by_side=$((host_gpus * ${EVALS_PER_GPU:-4}))
go1_solved() {  # EVAL_LOG...: true when one of these test-mode evaluations meets the criterion
  python3 - "$@" <<'PY'
import json, os, sys
def solved(path):
    lines = [x for x in open(path) if x.startswith("[eval] {")]
    e = json.loads(lines[-1][len("[eval] "):]) if lines else {}
    return (e.get("timeout_fraction", 0) >= float(os.environ["SOLVED_TIMEOUT_FRACTION"])
            and e.get("lin_vel_tracking_error", 1e9) <= float(os.environ["SOLVED_TRACKING_ERROR"]))
sys.exit(0 if any(solved(p) for p in sys.argv[1:]) else 1)
PY
}
for seed in ${seeds//,/ }; do
for k in ${counts//,/ }; do
  run="$out/$task.g$k.s$seed"
  seed_arg=(); [ "$seed" != default ] && seed_arg=(seed="$seed")
  launch=(python3 train.py)
  [ "$k" -gt 1 ] && launch=(torchrun --standalone --nnodes=1 --nproc_per_node="$k" train.py multi_gpu=True)
  # the budget ends an AllegroHand run as at its last iteration (max_train_time_s); the timeout only guards a hang
  timeout --preserve-status -s TERM $(( ${BUDGET_S:-1500} + 600 )) "${launch[@]}" task=$task headless=True \
    num_envs=$((total / k)) runs_dir="$run" "${seed_arg[@]}" "${train_args[@]}" "${overrides[@]}" > "$run.log" 2>&1
  echo "$task on $k GPU(s), seed $seed: exit $?" >> "$out/exits.txt"
  if [ "$name" = go1 ]; then  # the checkpoints in test mode in iteration order, side by side, until one solves it
    batch=()
    for ckpt in $(ls "$run"/"$task"/*/model_[0-9]*.pt | sort -V); do
      CUDA_VISIBLE_DEVICES=$(( ${#batch[@]} % host_gpus )) python3 train.py task=$task headless=True test=True \
        checkpoint="$ckpt" num_envs=1024 "${overrides[@]}" > "${ckpt%.pt}.eval.log" 2>&1 &
      batch+=("${ckpt%.pt}.eval.log")
      if [ ${#batch[@]} = "$side_by_side" ]; then wait; go1_solved "${batch[@]}" && break; batch=(); fi
    done
    wait
  fi
done
done
python3 - "$out" "$task" "$name" "$counts" "$seeds" <<'PY'
import glob, itertools, json, os, re, sys
out, task, name, counts, seeds = sys.argv[1:6]
METRIC = "Episode/consecutive_successes"  # the task's running metric in summary.json's history
for seed, k in itertools.product(seeds.split(","), counts.split(",")):
    runs = sorted(glob.glob(f"{out}/{task}.g{k}.s{seed}/{task}/*/summary.json"))
    if not runs:
        print(json.dumps({"task": task, "gpus": int(k), "seed": seed, "error": "no summary.json"}))
        continue
    s = json.load(open(runs[-1]))
    start_up = s["wall_time_s"] - s["train_time_s"]
    at = {h["iteration"]: h for h in s["history"]}
    row = {"task": task, "gpus": s["world_size"], "seed": s["seed"], "envs_in_total": s["num_envs"] * s["world_size"],
           "start_up_s": round(start_up, 1), "env_steps_per_s": round(s["env_steps_per_s"])}
    if name == "go1":
        solved = None
        for ev in sorted(glob.glob(os.path.join(os.path.dirname(runs[-1]), "model_[0-9]*.eval.log")),
                         key=lambda p: int(re.search(r"model_(\d+)", p).group(1))):
            it = int(re.search(r"model_(\d+)", ev).group(1))
            line = [x for x in open(ev) if x.startswith("[eval] {")]
            if not line or it not in at:
                continue
            e = json.loads(line[-1][len("[eval] "):])
            if (e["timeout_fraction"] >= float(os.environ["SOLVED_TIMEOUT_FRACTION"])
                    and e["lin_vel_tracking_error"] <= float(os.environ["SOLVED_TRACKING_ERROR"])):
                solved = {"iteration": it, "seconds_from_start": round(start_up + at[it]["time_s"], 1),
                          "timeout_fraction": e["timeout_fraction"], "tracking_error": e["lin_vel_tracking_error"]}
                break
        row["solved"] = solved
    else:
        for level in (5, 10):
            hit = next((h for h in s["history"] if h.get(METRIC, 0) >= level), None)
            row[f"consecutive_successes_{level}_s"] = None if hit is None else round(start_up + hit["time_s"], 1)
        row["final_consecutive_successes"] = s["history"][-1].get(METRIC)
    print(json.dumps(row))
PY
