#!/usr/bin/env bash
# Idempotent set-up for a fresh machine: virtual environment, CPU torch, the package with its extras,
# and the system libraries headless MuJoCo rendering needs. Re-running it does nothing once done.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV="${VENV:-.venv}"
EXTRAS="${EXTRAS:-sim,viz,data,hf,dev}"
PYTHON="${PYTHON:-python3}"
# A CPU torch lies on disk on this machine kind; elsewhere set TORCH_SPEC to what suits the machine.
TORCH_SPEC="${TORCH_SPEC:-torch==2.13.0}"
# The tested versions of every other package (a new upstream release must not turn CI red by itself);
# GAZEREG_CONSTRAINTS=none takes the newest versions pyproject.toml allows.
CONSTRAINTS="${GAZEREG_CONSTRAINTS:-constraints.txt}"

log() { printf '[setup] %s\n' "$*"; }

# System packages for headless OpenGL through EGL (Mesa's llvmpipe renders on the CPU). OSMesa
# (libosmesa6) is the fallback MUJOCO_GL=osmesa uses; it is not needed when EGL works.
GL_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri libgles2)
missing=()
if command -v dpkg-query >/dev/null 2>&1; then
  for p in "${GL_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
fi
if ((${#missing[@]})); then
  if [[ $(id -u) == 0 ]] && command -v apt-get >/dev/null 2>&1; then
    log "installing headless rendering libraries: ${missing[*]}"
    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    log "WARNING: headless MuJoCo rendering needs these system packages: ${missing[*]}"
    log "         install them with: sudo apt-get install -y ${missing[*]}"
  fi
fi

if [[ ! -x "$VENV/bin/python" ]]; then
  log "creating virtual environment $VENV with $($PYTHON --version)"
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
fi

stamp="$VENV/.gazereg-installed"
want="$(cat pyproject.toml scripts/setup.sh constraints.txt | sha256sum | cut -c1-16) $EXTRAS $TORCH_SPEC $CONSTRAINTS"
if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
  exit 0
fi

if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  log "installing $TORCH_SPEC"
  "$VENV/bin/python" -m pip install -q "$TORCH_SPEC"
fi
log "installing gazereg[$EXTRAS]"
pin=()
[[ "$CONSTRAINTS" != none ]] && pin=(-c "$CONSTRAINTS")
"$VENV/bin/python" -m pip install -q "${pin[@]}" -e ".[$EXTRAS]"
echo "$want" > "$stamp"
log "done: $("$VENV/bin/python" -c 'import torch, gazereg; print("torch", torch.__version__, "gazereg", gazereg.__version__)')"
