#!/usr/bin/env bash
# What a session with a CUDA machine runs, in one go (about 8 minutes on one H100; the first try
# there, 2026-11-26, is written up in docs/results.md, "On a GPU"):
#   1. benchmarks/bench_models.py --device cuda: every model's training step and rollout cost at
#      batch 1, 16, 256 and 4096 on the GPU, MuJoCo beside them on that machine's CPU;
#   2. the same for MDGS with its step compiled (cudagraphs, inductor) at batch 1 and 256;
#   3. tests/test_cuda.py: every model on the GPU against the CPU (step, losses, rollout), the trainer
#      and `mdgs evaluate --device cuda` end to end, compiled steps on the GPU.
# PYTEST_K selects tests (pytest -k). Outputs go to $OUT (default cuda-out/): env.txt, test_cuda.log, bench_eager.txt, bench_compiled.txt.
# Each part has its own time limit (seconds: T_TEST, T_EAGER, T_COMPILED), so one slow part
# leaves the others their time. Needs the project's dependencies importable (PYTHONPATH or an install).
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-cuda-out}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  python3 -c "import os, torch, mujoco; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'mujoco',
mujoco.__version__, 'cpus', os.cpu_count())"; } 2>&1 | tee "$OUT/env.txt"
s=$SECONDS
timeout "${T_EAGER:-150}" python3 benchmarks/bench_models.py --device cuda --batches 1 16 256 4096 2>&1 \
  | grep -v -E "Warning|warnings.warn" | tee "$OUT/bench_eager.txt"
echo "eager bench: $((SECONDS - s)) s" | tee -a "$OUT/bench_eager.txt"
s=$SECONDS
timeout "${T_COMPILED:-150}" python3 benchmarks/bench_models.py --device cuda --models mdgs --batches 1 256 \
  --compile cudagraphs inductor 2>&1 | grep -v -E "Warning|warnings.warn" | tee "$OUT/bench_compiled.txt"
echo "compiled bench: $((SECONDS - s)) s" | tee -a "$OUT/bench_compiled.txt"
s=$SECONDS
timeout "${T_TEST:-270}" python3 -m pytest -q -p no:cacheprovider -rA --durations=8 ${PYTEST_K:+-k "$PYTEST_K"} tests/test_cuda.py 2>&1 \
  | grep -v -E "Warning|warnings.warn|^\s*$|return (cls|torch)" | tee "$OUT/test_cuda.log"
echo "tests: $((SECONDS - s)) s" | tee -a "$OUT/test_cuda.log"
