#!/usr/bin/env bash
# Everything GPU-specific in one short device session: the CUDA tests under pytest, then the training-step
# benchmark on the device at the paper's batch (4096) and at 65536 samples. Prints as it goes and keeps the
# output under $OUT (default benchmarks/results/gpu_check). GPU_CHECK_TREFOIL=1 also times a paper-size trefoil
# (experiment=minimal_trefoil, preset=paper, trainer=gpu: 1e5 steps) whole, for the results page.
#
#   bash benchmarks/gpu_check.sh                 # on a machine with a CUDA GPU and the project's .venv
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
OUT=${OUT:-benchmarks/results/gpu_check}
mkdir -p "$OUT"
status=0
"$PY" -c "import torch, sys; ok = torch.cuda.is_available(); print('torch', torch.__version__, 'CUDA', torch.version.cuda, \
torch.cuda.get_device_name(0) if ok else 'no CUDA device'); sys.exit(0 if ok else 1)" | tee "$OUT/device.txt" \
    || { echo "gpu_check: this machine has no CUDA device; nothing was measured." >&2; exit 2; }
# the CUDA tests: none may be skipped here (-rs lists any skip and its reason)
"$PY" -m pytest -q -rs -p no:cacheprovider tests/gpu 2>&1 | tee "$OUT/pytest.txt"
[ "${PIPESTATUS[0]}" -eq 0 ] || status=1
if grep -q "skipped" "$OUT/pytest.txt"; then echo "gpu_check: some CUDA tests were skipped on the device." >&2; status=1; fi
for samples in 4096 65536; do
    "$PY" benchmarks/train_step.py --device cuda --samples "$samples" --skip-memory 2>&1 | tee "$OUT/train_step_$samples.txt"
    [ "${PIPESTATUS[0]}" -eq 0 ] || status=1
done
if [ "${GPU_CHECK_TREFOIL:-0}" = 1 ]; then
    /usr/bin/time -f "paper trefoil, whole command: %e s" "$PY" train.py experiment=minimal_trefoil preset=paper \
        trainer=gpu logger=none hydra.run.dir="$OUT/trefoil" 2>&1 | tail -n 3 | tee "$OUT/trefoil.txt"
fi
echo "gpu_check: output in $OUT (status $status)"
exit $status
