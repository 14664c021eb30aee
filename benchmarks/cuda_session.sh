#!/usr/bin/env bash
# What a session with a CUDA machine runs (about 12 minutes on one H100, in two calls; the first try
# there, 2026-11-26, is written up in docs/results.md, "On a GPU"):
#   1. benchmarks/bench_models.py --device cuda: every model's training step and rollout cost at
#      batch 1, 16, 256 and 4096 on the GPU, MuJoCo beside them on that machine's CPU;
#   2. the same for MDGS with its step compiled (cudagraphs, inductor) at batch 1 and 256;
#   3. tests/test_cuda.py: every model on the GPU against the CPU (step, losses, rollout), the trainer
#      and `mdgs evaluate --device cuda` end to end, compiled steps on the GPU;
#   4. benchmarks/profile_step.py --device cuda: kernels per single-trajectory step and the GPU-busy share, eager
#      and replayed as CUDA graphs (launches, graph replays and device waits per step; dynamo's graph breaks logged).
# MDGS on the rigid tree's forward dynamics captures as a CUDA graph, one step a frame and in 4 substeps (docs/results.md,
# "fourth loan", "fifth loan"; PARTS=tests PYTEST_K=dynamics_prior). The eight-substep soft prior (mdgs-soft-8, gns-soft-8) was
# measured on the sixth loan with benchmarks/compiled_dynamics.py (docs/results.md, "sixth loan"). Open on the next loan:
# PYTEST_K="soft-8 and replays" (its CUDA graph against its eager step; compiling took about 255 s), and, since the soft
# contact's rows left the system (docs/results.md, "The soft contact's rows out of the system"), its costs again:
# python3 benchmarks/compiled_dynamics.py --device cuda --substeps 8 --contact soft --joint-velocities coordinates
# --models mdgs --modes none cudagraphs --batch 256. Since the passes are solved by fused elimination when compiled
# (docs/results.md, "The joints' rows out of the passes too"), that test also checks the elimination inside a CUDA
# graph, and the benchmark's max |dx| column its rollout against the eager one.
# PARTS picks parts (default "eager compiled tests profile"); all four take more than one 10-minute
# device call, so run PARTS="eager compiled" and PARTS="tests profile" as two calls.
# PYTEST_K selects tests (pytest -k). Outputs go to $OUT (default cuda-out/): env.txt, bench_eager.txt,
# bench_compiled.txt, test_cuda.log, profile_cuda.txt.
# Each part has its own time limit (seconds: T_EAGER, T_COMPILED, T_TEST, T_PROFILE), so one slow part
# leaves the others their time. Needs the project's dependencies importable (PYTHONPATH or an install).
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-cuda-out}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  python3 -c "import os, torch, mujoco; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'mujoco',
mujoco.__version__, 'cpus', os.cpu_count())"; } 2>&1 | tee "$OUT/env.txt"
PARTS=${PARTS:-eager compiled tests profile}
has() { [[ " $PARTS " == *" $1 "* ]]; }
s=$SECONDS
has eager && timeout "${T_EAGER:-150}" python3 benchmarks/bench_models.py --device cuda --batches 1 16 256 4096 2>&1 \
  | grep -v -E "Warning|warnings.warn" | tee "$OUT/bench_eager.txt"
has eager && echo "eager bench: $((SECONDS - s)) s" | tee -a "$OUT/bench_eager.txt"
s=$SECONDS
has compiled && timeout "${T_COMPILED:-150}" python3 benchmarks/bench_models.py --device cuda --models mdgs --batches 1 256 \
  --compile cudagraphs inductor 2>&1 | grep -v -E "Warning|warnings.warn" | tee "$OUT/bench_compiled.txt"
has compiled && echo "compiled bench: $((SECONDS - s)) s" | tee -a "$OUT/bench_compiled.txt"
s=$SECONDS
has tests && timeout "${T_TEST:-270}" python3 -m pytest -q -p no:cacheprovider -rA --durations=8 ${PYTEST_K:+-k "$PYTEST_K"} tests/test_cuda.py 2>&1 \
  | grep -v -E "Warning|warnings.warn|^\s*$|return (cls|torch)" | tee "$OUT/test_cuda.log"
has tests && echo "tests: $((SECONDS - s)) s" | tee -a "$OUT/test_cuda.log"
s=$SECONDS
has profile && timeout "${T_PROFILE:-150}" python3 benchmarks/profile_step.py --device cuda --repeats 3 2>&1 \
  | grep -v -E "Warning|warnings.warn" | tee "$OUT/profile_cuda.txt"
has profile && timeout "${T_PROFILE:-150}" python3 benchmarks/profile_step.py --device cuda --repeats 3 --compile cudagraphs \
  --models mdgs gns constant-twist 2>&1 | grep -v -E "Warning|warnings.warn" | tee -a "$OUT/profile_cuda.txt"
has profile && echo "profile: $((SECONDS - s)) s" | tee -a "$OUT/profile_cuda.txt"
