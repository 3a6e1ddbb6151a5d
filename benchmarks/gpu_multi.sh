#!/usr/bin/env bash
# On a machine with >= 2 GPUs: Anymal training throughput on 1 GPU and on K GPUs (torchrun, one simulator per
# GPU, rsl-rl-lib distributed PPO), same envs per GPU. Usage: bash benchmarks/gpu_multi.sh OUTDIR [K] [ITERATIONS]
set -uo pipefail
out=$1; k=${2:-2}; its=${3:-40}; mkdir -p "$out"
# NVLink multicast stays off on shared hosts.
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
python3 train.py task=Anymal headless=True max_iterations=$its runs_dir="$out/g1" > "$out/g1.log" 2>&1 || tail -5 "$out/g1.log"
torchrun --standalone --nnodes=1 --nproc_per_node=$k train.py task=Anymal multi_gpu=True headless=True \
  max_iterations=$its runs_dir="$out/g$k" > "$out/g$k.log" 2>&1 || tail -15 "$out/g$k.log"
python3 - "$out" "$k" <<'PY'
import glob, json, sys
out, k = sys.argv[1], sys.argv[2]
def rate(d):
    s = json.load(open(sorted(glob.glob(f"{out}/{d}/Anymal/*/summary.json"))[-1]))
    h = s["history"][5:]  # skip the first iterations (kernel compilation, graph capture)
    return s["world_size"], sum(x["env_steps"] - y["env_steps"] for x, y in zip(h[1:], h[:-1])) / sum(
        x["time_s"] - y["time_s"] for x, y in zip(h[1:], h[:-1]))
w1, r1 = rate("g1"); wk, rk = rate(f"g{k}")
print(json.dumps({"task": "Anymal", "envs_per_gpu": 4096, "gpus_1": w1, "train_env_steps_per_s_1gpu": r1,
                  f"gpus_{k}": wk, f"train_env_steps_per_s_{k}gpu": rk, "speedup": rk / r1}))
PY
