#!/usr/bin/env bash
# The Gym-Aloha lane: gym-aloha 0.1.5 (dm-control 1.0.28, MuJoCo 3.3.0) in a venv of its own, outside the
# repository (reused across runs and clones): $GAZEREG_ALOHA_VENV, default ~/.cache/gazereg/aloha-py<X.Y>.
# Creates/reuses it (CPU torch, then gazereg editable with its `aloha` and `viz` extras and pytest; about 90 s and 1.6 GB
# the first time), then runs tests_aloha/ with MuJoCo's headless EGL, or, given a command, runs that in the venv:
#
#   bash scripts/aloha_lane.sh                     # create/refresh the venv, run tests_aloha/
#   bash scripts/aloha_lane.sh -k expert           # ... with pytest arguments
#   bash scripts/aloha_lane.sh --run gazereg collect --env aloha --tasks AlohaTransferCube-v0 --out /tmp/a
#
# Exits 0 printing "skipped: ..." where the lane cannot be set up: no Python interpreter of the wanted version,
# the packages cannot be installed (no registry), or no headless OpenGL (EGL) for MuJoCo.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY=${GAZEREG_ALOHA_PYTHON:-python3.11}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
start=$(date +%s)

if ! command -v "$PY" >/dev/null 2>&1; then
    echo "skipped: no $PY (set GAZEREG_ALOHA_PYTHON to a Python >= 3.10)"
    exit 0
fi
PYVER=$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
VENV=${GAZEREG_ALOHA_VENV:-$HOME/.cache/gazereg/aloha-py$PYVER}
# The stamp: the torch spec and the `aloha` extra's line in pyproject.toml; either changing rebuilds the venv.
want="$TORCH_SPEC $(grep -E '^aloha = ' pyproject.toml)"
stamp="$VENV/.gazereg-aloha"
log=$(mktemp)
trap 'rm -f "$log"' EXIT

if [[ -x "$VENV/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
    echo "aloha lane: reusing $VENV" >&2
else
    echo "aloha lane: creating $VENV with $PY (about 90 s and 1.6 GB)" >&2
    rm -rf "$VENV"
    mkdir -p "$(dirname "$VENV")"
    if ! { "$PY" -m venv "$VENV" && "$VENV/bin/pip" install -q --upgrade pip \
        && "$VENV/bin/pip" install -q "$TORCH_SPEC"; } >"$log" 2>&1; then
        echo "skipped: could not create the venv or install $TORCH_SPEC into $VENV: $(grep -v 'is ignored' "$log" | tail -1)"
        rm -rf "$VENV"
        exit 0
    fi
fi
# gazereg editable with the `aloha` extra (gym-aloha, dm-control, mujoco), `viz` (the report's figures) and pytest;
# re-run every time
# (seconds) so the venv follows the checkout.
if ! "$VENV/bin/pip" install -q --no-build-isolation -e "$ROOT[aloha,viz]" "pytest>=8" >"$log" 2>&1; then
    echo "skipped: could not install gazereg[aloha,viz] into $VENV: $(grep -v 'is ignored' "$log" | tail -1)"
    exit 0
fi
echo "$want" >"$stamp"

export MUJOCO_GL=${MUJOCO_GL:-egl}
if [[ "$MUJOCO_GL" == egl ]] && ! "$VENV/bin/python" -c "
from gazereg.envs.render import egl_status
ok, missing = egl_status()
raise SystemExit(0 if ok else 1)" 2>/dev/null; then
    echo "skipped: no headless OpenGL for MuJoCo (EGL: install libegl1 libegl-mesa0 libgl1-mesa-dri, see scripts/setup.sh)"
    exit 0
fi

if [[ "${1:-}" == "--run" ]]; then
    shift
    PATH="$VENV/bin:$PATH" exec "$@"
fi
set +e
"$VENV/bin/python" -m pytest -q -p no:cacheprovider -p no:randomly "$ROOT/tests_aloha" "$@"
rc=$?
set -e
echo "aloha lane: pytest exit $rc, wall time $(($(date +%s) - start)) s"
exit $rc
