#!/usr/bin/env bash
# On a GPU machine: the throughput table of docs/BENCHMARKS.md, with the compiled step (sim.compileStep, the
# default) and, for the legged tasks at 4096 envs, without it. Usage: bash benchmarks/rounds/gpu_compile.sh OUTDIR
set -uo pipefail
out=$1; mkdir -p "$out"
python3 -c "import torch, triton; print('torch', torch.__version__, 'triton', triton.__version__)"
run() { timeout "$1" python3 benchmarks/throughput.py "${@:2}" 2>>"$out/throughput.err" | tail -1 | tee -a "$out/throughput.jsonl" | cut -c1-300; }
run 240 --task Go1 --num_envs 4096
run 120 --task Go1 --num_envs 4096 +task.sim.compileStep=False
run 120 --task Go1 --num_envs 8192
run 120 --task Anymal --num_envs 4096
run 120 --task Anymal --num_envs 4096 +task.sim.compileStep=False
run 120 --task Anymal --num_envs 8192
for n in 4096 16384 65536; do run 90 --task Cartpole --num_envs $n; done
