#!/usr/bin/env bash
# On a machine with 4 GPUs: issue 43's measurements, one lane per GPU, each lane with its own kernel caches.
#   phase A: GPU 0, 1: FrankaCubeLift seeds 1 and 2, 1500 iterations (shipped defaults), then test mode on 1024 envs;
#            GPU 2: FrankaCubeStack, GPU 3: FrankaCubeLiftDepth, each signalled at 60 s (cold caches) and at 300 s.
#   phase B: GPU 0: FrankaCubeLift signalled at 60 s (cold) and 300 s; GPU 1: the blow-up injection on FrankaCubeLift
#            (benchmarks/diagnostics/nan_injection.py, 4096 envs); GPU 2, 3: throughput of Go1 and FrankaCubeLift, this tree and
#            the one in BASE (a copy of the previous commit), one after the other on the same GPU.
#   phase C: throughput against BASE on an idle machine; signals while the step compiles; a late one.
#   phase D: phase C cut to 2 GPUs.
# Usage: bash benchmarks/rounds/gpu_reliability.sh A|B|C|D OUTDIR   (BASE=.base for phases B and C)
set -uo pipefail
phase=$1; out=$2
mkdir -p "$out"
lane() {  # lane GPU COMMAND...: run on one GPU with caches of its own
  local g=$1; shift
  (export CUDA_VISIBLE_DEVICES=$g WARP_CACHE_PATH=/tmp/cache$g/warp TORCHINDUCTOR_CACHE_DIR=/tmp/cache$g/inductor \
          TRITON_CACHE_DIR=/tmp/cache$g/triton; "$@") > "$out/lane$g.txt" 2>&1 &
}
base=${BASE:-.base}  # phases B, C, D: a copy of the commit to compare with
tp() {  # TASK LABEL: one throughput row (benchmarks/throughput.py at 4096 envs): (b)/(a), VecTask.step and training rates
  python3 benchmarks/throughput.py --task "$1" --num_envs 4096 --sim_device cuda:0 --train_iterations 30 2>/dev/null \
    | tail -1 | python3 -c "import json, sys; d = json.loads(sys.stdin.read()); print('$2', d['task'], \
    round(d['ratio_vectask_over_physics'], 4), round(d['vectask_env_steps_per_s']), round(d['train_env_steps_per_s']))"
}
export -f tp
train_and_test() {  # TASK SEED
  timeout --preserve-status 560 python3 train.py task="$1" seed="$2" headless=True runs_dir="$out/runs.$1.$2" \
    > "$out/$1.seed$2.log" 2>&1
  echo "$1 seed $2: rc=$? $(grep -E '^\[train\] done|skipped|restored|replaced|blew up|not finite' "$out/$1.seed$2.log" | cut -c1-200)"
  ckpt=$(ls -t "$out"/runs."$1"."$2"/"$1"/*/model_[0-9]*.pt 2>/dev/null | head -1)
  [ -n "$ckpt" ] && python3 -c "
import json, math, torch
s = json.load(open('$(dirname "$ckpt")/summary.json'))
w = torch.load('$ckpt', map_location='cpu', weights_only=False)
fin = all(bool(torch.isfinite(v).all()) for g in ('actor_state_dict', 'critic_state_dict') for v in w[g].values() if v.is_floating_point())
vl = [h['losses']['value'] for h in s['history']]
print({k: s.get(k) for k in ('final_iteration', 'wall_time_s', 'env_steps_per_s', 'success', 'nonfinite_resets', 'nonfinite_inputs', 'skipped_optimizer_steps', 'learner_restores')}, 'weights_finite', fin, 'value_losses_finite', all(math.isfinite(v) for v in vl), 'max_value_loss', max(vl))"
  [ -n "$ckpt" ] && timeout 200 python3 train.py task="$1" headless=True test=True checkpoint="$ckpt" num_envs=1024 2>&1 \
    | grep "\[eval\] {" | cut -c1-300
}
if [ "$phase" = A ]; then
  lane 0 train_and_test FrankaCubeLift 1
  lane 1 train_and_test FrankaCubeLift 2
  lane 2 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeStack 60 $out; bash benchmarks/rounds/gpu_signal.sh FrankaCubeStack 300 $out"
  lane 3 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeLiftDepth 60 $out; bash benchmarks/rounds/gpu_signal.sh FrankaCubeLiftDepth 300 $out"
elif [ "$phase" = C ]; then
  # Throughput of this tree against BASE on an otherwise idle machine, side by side on the four GPUs, twice with
  # the GPUs swapped; then the signals that land while the step compiles (cold caches) and one late in a long run.
  for swap in 0 1; do
    (CUDA_VISIBLE_DEVICES=$swap tp FrankaCubeLift new) & (cd "$base" && CUDA_VISIBLE_DEVICES=$((1 - swap)) PYTHONPATH=/tmp/site:$PWD tp FrankaCubeLift base) &
    (CUDA_VISIBLE_DEVICES=$((2 + swap)) tp Go1 new) & (cd "$base" && CUDA_VISIBLE_DEVICES=$((3 - swap)) PYTHONPATH=/tmp/site:$PWD tp Go1 base) &
    wait
  done | tee "$out/throughput.txt"
  lane 0 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeStack 60 $out"
  lane 1 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeStack 50 $out/b"
  lane 2 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeLiftDepth 60 $out"
  lane 3 bash -c "bash benchmarks/rounds/gpu_signal.sh FrankaCubeLift 300 $out max_iterations=3000"
elif [ "$phase" = D ]; then
  # Phase C on a machine with 2 GPUs: one throughput pair per task (this tree and BASE side by side, the GPUs
  # swapped between the tasks), then FrankaCubeStack signalled while its step compiles and FrankaCubeLift late.
  { (CUDA_VISIBLE_DEVICES=0 tp FrankaCubeLift new) & (cd "$base" && CUDA_VISIBLE_DEVICES=1 PYTHONPATH=/tmp/site:$PWD tp FrankaCubeLift base) & wait
    (CUDA_VISIBLE_DEVICES=1 tp Go1 new) & (cd "$base" && CUDA_VISIBLE_DEVICES=0 PYTHONPATH=/tmp/site:$PWD tp Go1 base) & wait; } | tee "$out/throughput.txt"
  lane 0 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeStack 60 $out"
  lane 1 bash -c "bash benchmarks/rounds/gpu_signal.sh FrankaCubeLift 240 $out max_iterations=3000"
else
  lane 0 bash -c "CACHE=cold bash benchmarks/rounds/gpu_signal.sh FrankaCubeLift 60 $out; bash benchmarks/rounds/gpu_signal.sh FrankaCubeLift 300 $out"
  lane 1 python3 benchmarks/diagnostics/nan_injection.py --sim_device cuda:0 --num_envs 4096 --iterations 120
  lane 2 bash -c "tp Go1 new; cd $base && PYTHONPATH=/tmp/site:\$PWD tp Go1 base"
  lane 3 bash -c "tp FrankaCubeLift new; cd $base && PYTHONPATH=/tmp/site:\$PWD tp FrankaCubeLift base"
fi
wait
for g in 0 1 2 3; do [ -f "$out/lane$g.txt" ] || continue; echo "== lane $g"; cat "$out/lane$g.txt" | grep -v '^\[it\|^\[isaac\|Warning\|warn' | tail -8 | cut -c1-1500; done
