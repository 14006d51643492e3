#!/usr/bin/env bash
# The GPU check, for a machine with one NVIDIA GPU (about 8 minutes in all): makes the environment if there is none
# (the README's `make env`, plus the test extra; on a machine without a package registry, the wheels carried in
# .gpucarry/ by `scripts/gpu_carry.py`), runs the CUDA-only tests, trains ssnerf-lite and ssnerf on a 640x480 generated scene and
# prints one JSON line (rays/s, GPU memory peak, PSNR, mIoU per method). Without CUDA it prints its plan and exits 0.
#   scripts/gpu_check.sh [--dry-run] [--steps-lite N] [--steps-ssnerf N] [--output DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -x .venv/bin/python ]; then
  PYTHON=.venv/bin/python
elif python3 -c "import nerfstudio, ssnerf_method" 2>/dev/null; then
  PYTHON=python3                                      # an environment that already has everything
elif [ -d .gpucarry/wheels ] && python3 -c "import torch" 2>/dev/null && [[ " $* " != *" --dry-run "* ]]; then
  # a lent machine without a package registry: the wheels `scripts/gpu_carry.py` downloaded, over the image's torch
  python3 -m pip install -q --no-index --no-deps .gpucarry/wheels/*.whl >&2
  python3 -m pip install -q --no-deps --no-build-isolation -e . >&2 && PYTHON=python3
elif command -v nvidia-smi >/dev/null 2>&1 && [[ " $* " != *" --dry-run "* ]]; then
  make env >&2 && PYTHON=.venv/bin/python
else
  echo '{"dry_run": true, "reason": "no environment and no GPU: run make env first", "plan": ["make env", "python scripts/gpu_check.py"]}'
  exit 0
fi
if [[ " $* " != *" --dry-run "* ]] && ! "$PYTHON" -c "import pytest" 2>/dev/null; then
  "$PYTHON" -m pip install -q -e '.[test]' >&2                # pytest, for the CUDA-only tests
fi
exec "$PYTHON" scripts/gpu_check.py "$@"
