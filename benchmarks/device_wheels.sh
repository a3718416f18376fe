#!/bin/bash
# Wheels for running this repository on an offline GPU box whose Python (3.12) already has torch, BoTorch,
# GPyTorch, numpy, matplotlib and joblib, but not Taichi, OMPL or Hydra:
#
#     bash benchmarks/device_wheels.sh [DIR]        # default DIR: .whl (git-ignore it)
#
# then, on the box, from the repository root (PYTHONPATH instead of an install: nothing to build there):
#
#     python3 -m pip install -q --no-index --no-deps --target /tmp/site DIR/*.whl
#     export PYTHONPATH=/tmp/site:$PWD
#     STEPS="execute_b2048 paper planner_pool" bash benchmarks/gpu_check.sh OUTDIR 16
#
# If the box's `python` is not the interpreter that holds torch, put a wrapper first on PATH that execs it
# (a symbolic link to a virtual environment's python3 loses the environment). The Taichi wheel is 56 MB; its
# C API library, headers, examples and assets (unused from Python) are dropped, which brings all the wheels
# to 40 MB, so that they and the repository travel together under a 64 MiB limit.
set -euo pipefail
dir=${1:-.whl}
mkdir -p "$dir"
platforms=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64
           --platform manylinux2014_x86_64 --platform manylinux1_x86_64)
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp "${platforms[@]}" \
    -d "$dir" taichi==1.7.4 ompl==2.0.1 hydra-core==1.3.8 omegaconf==2.3.1 hydra-joblib-launcher==1.2.0 dill colorama
python3 -m pip wheel -q --no-deps -w "$dir" antlr4-python3-runtime==4.9.3   # an sdist only: built here (pure Python)
zip -q -d "$dir"/taichi-1.7.4-*.whl 'taichi/_lib/c_api/*' 'taichi-1.7.4.data/*' 'taichi/examples/*' 'taichi/assets/*' || true
du -ch "$dir"/*.whl | tail -1
