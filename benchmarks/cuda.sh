#!/usr/bin/env bash
# The CUDA checks, as one script for a machine with an NVIDIA GPU (issue 35): the device-aware
# tests, then the renderer, warm-start and whole-pipeline benchmarks on the GPU. Needs a CUDA
# build of torch in .venv (see the README). Prints each part's output; stops at the first failure.
#
#   bash benchmarks/cuda.sh [OUT_DIR]
set -euo pipefail
out="${1:-runs/cuda}"
mkdir -p "$out"
py=.venv/bin/python
"$py" -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.cuda.get_device_name(0), torch.__version__)"
"$py" -m pytest -q -p no:cacheprovider --device cuda tests/test_device.py tests/render 2>&1 | tee "$out/tests.log"
"$py" -m benchmarks.render --device cuda 2>&1 | tee "$out/render.log"
"$py" -m benchmarks.video --device cuda 2>&1 | tee "$out/video.log"
"$py" -m benchmarks.pipeline --device cuda 2>&1 | tee "$out/pipeline.log"
