#!/usr/bin/env bash
# The LeRobot lane: lerobot 0.6.1 needs Python >= 3.12, so it lives in its own venv, outside the repository
# (reused across runs and clones): $GAZEREG_LEROBOT_VENV, default ~/.cache/gazereg/lerobot-py312.
# Creates/reuses it, installs gazereg (editable, with its dependencies) and the lerobot_policy_gazereg plugin
# (editable) into it, and runs tests_lerobot/. Exits 0 with "skipped: no Python 3.12" where no Python 3.12
# interpreter exists.
#
#   bash scripts/lerobot_lane.sh [pytest args...]
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
VENV=${GAZEREG_LEROBOT_VENV:-$HOME/.cache/gazereg/lerobot-py312}
# metaworld: lerobot's extra (metaworld 3.0.0) for lerobot-eval --env.type=metaworld (tests_lerobot/test_lerobot_eval.py);
# mujoco pinned to 3.3.0 (the main venv's) as metaworld 3.0.0 fails at reset with MuJoCo 4 (eq_data 11 vs 12).
LEROBOT_REQ='lerobot[smolvla,pi,dataset,metaworld]==0.6.1'
start=$(date +%s)

find_py312() {
    if [[ -n "${GAZEREG_PY312:-}" && -x "${GAZEREG_PY312}" ]]; then echo "$GAZEREG_PY312"; return; fi
    local root
    if command -v pyenv >/dev/null 2>&1 && root=$(pyenv root 2>/dev/null); then
        for p in "$root"/versions/3.12*/bin/python; do [[ -x "$p" ]] && { echo "$p"; return; }; done
    fi
    for p in "$HOME"/.pyenv/versions/3.12*/bin/python; do [[ -x "$p" ]] && { echo "$p"; return; }; done
    command -v python3.12 2>/dev/null || true
}

stamp="$VENV/.gazereg-lane"
if [[ -x "$VENV/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$LEROBOT_REQ" ]]; then
    echo "lerobot lane: reusing $VENV"
else
    PY312=$(find_py312)
    if [[ -z "$PY312" ]]; then
        echo "skipped: no Python 3.12 (lerobot >= 0.5 needs Python >= 3.12; set GAZEREG_PY312 or install one with pyenv)"
        exit 0
    fi
    echo "lerobot lane: creating $VENV with $PY312 (about 3 minutes and 5.7 GB)"
    rm -rf "$VENV"
    mkdir -p "$(dirname "$VENV")"
    "$PY312" -m venv "$VENV"
    "$VENV/bin/pip" install -q --upgrade pip
    "$VENV/bin/pip" install -q "$LEROBOT_REQ" mujoco==3.3.0 pytest
    echo "$LEROBOT_REQ" >"$stamp"
fi

# gazereg editable from this checkout with its dependencies (tyro, ...: what its commands need; torch, numpy and
# accelerate are lerobot's, inside gazereg's ranges), then the plugin editable. The plugin's own requirement on
# gazereg is a direct reference to this checkout (lerobot_plugin/setup.py), which pip will not match with an
# editable gazereg in one resolve, so it goes in with --no-deps; its lerobot extras are the stamp's. A user's one
# command, `pip install ./lerobot_plugin`, is tests_lerobot/test_install.py's. Re-run every time (seconds) so the
# venv follows the checkout.
"$VENV/bin/pip" install -q --no-build-isolation -e "$ROOT"
"$VENV/bin/pip" install -q --no-deps --no-build-isolation -e "$ROOT/lerobot_plugin"

set +e
HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 "$VENV/bin/python" -m pytest -q -p no:cacheprovider "$ROOT/tests_lerobot" "$@"
rc=$?
set -e
echo "lerobot lane: pytest exit $rc, wall time $(($(date +%s) - start)) s"
exit $rc
