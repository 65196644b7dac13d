#!/usr/bin/env bash
# The CUDA checks, as one script for a machine with an NVIDIA GPU (issue 35): the device-aware
# tests, then the whole-pipeline, renderer and warm-start benchmarks on the GPU. Needs a CUDA
# build of torch (see the README). Each part runs under its own time limit and writes its log to
# OUT_DIR; a failing part does not stop the next (one short lease should show every failure), and
# the script's exit status is the number of parts that failed.
#
#   bash benchmarks/cuda.sh [OUT_DIR]          (PY=python3 to use another interpreter)
set -uo pipefail
out="${1:-runs/cuda}"
py="${PY:-.venv/bin/python}"
mkdir -p "$out"
export PYTHONUNBUFFERED=1
failed=0

part() {  # part NAME SECONDS COMMAND...: one part, its log in $out/NAME.log
    local name="$1" limit="$2"
    shift 2
    local start=$SECONDS
    echo "=== $name (limit ${limit} s)"
    timeout "$limit" "$@" 2>&1 | tee "$out/$name.log"
    local rc=${PIPESTATUS[0]}
    echo "=== $name: exit $rc after $((SECONDS - start)) s"
    [ "$rc" -eq 0 ] || failed=$((failed + 1))
}

"$py" -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.cuda.get_device_name(0), torch.__version__)" || exit 1
part tests 150 "$py" -m pytest -q -p no:cacheprovider --device cuda tests/test_device.py tests/render
part pipeline 200 "$py" -m benchmarks.pipeline --device cuda
part render 60 "$py" -m benchmarks.render --device cuda --repeats 10
part video 150 "$py" -m benchmarks.video --device cuda --frames 6
exit "$failed"
