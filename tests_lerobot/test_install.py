"""The plugin README's one install command, tried as a new LeRobot user would (issue 35 item 6).

A fresh venv sees the lane's lerobot and its dependencies (a folder of links to the lane's site-packages, named in
a .pth file) but not gazereg, the plugin, or the packages only gazereg needs (tyro, docstring-parser, typeguard).
The README's `pip install /path/to/gazereg/lerobot_plugin` runs there as written (the path set to this checkout,
PyPI reachable for those three): it must install the plugin, gazereg's core and its missing dependencies and
nothing of lerobot's (no second torch), and then the documented `gazereg import write-gaze` must run (it failed
with `No module named 'tyro'` after the former `--no-deps` install) and the gaze policy types must register.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

from test_docs import _blocks

ROOT = Path(__file__).resolve().parents[1]
# Distributions the lane has only because of gazereg (hidden from the fresh venv), by normalised name
GAZEREG_ONLY = {"gazereg", "lerobot_policy_gazereg", "tyro", "docstring_parser", "typeguard"}
LEROBOT_OWN = {
    "torch",
    "numpy",
    "lerobot",
    "accelerate",
    "transformers",
    "torchvision",
    "safetensors",
    "einops",
}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def _dist_name(entry: str) -> str:
    """The distribution or module an entry of site-packages belongs to (`tyro-1.0.dist-info` -> `tyro`)."""
    stem = entry.removeprefix("__editable__.").removeprefix("__editable___")
    return _norm(re.split(r"-\d|\.pth$|\.py$|_\d", stem)[0])


def _lerobot_venv(tmp_path: Path) -> Path:
    """A fresh venv (with pip) that sees the lane's packages except GAZEREG_ONLY."""
    venv = tmp_path / "venv"
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(venv)], check=True, timeout=300)
    view = tmp_path / "lerobot_view"
    view.mkdir()
    lane = Path(sysconfig.get_paths()["purelib"])
    for entry in lane.iterdir():
        if (
            _dist_name(entry.name) not in GAZEREG_ONLY
            and entry.name != "pip"
            and not entry.name.startswith("pip-")
        ):
            (view / entry.name).symlink_to(entry)
    site = Path(
        subprocess.run(
            [str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    (site / "lerobot_view.pth").write_text(f"{view}\n")
    return venv


def _installed(venv: Path) -> set[str]:
    site = next((venv / "lib").glob("python3*/site-packages"))
    return {_norm(p.name.split("-")[0]) for p in site.glob("*.dist-info")}


def test_the_readme_install_command_pulls_gazereg_core_into_a_lerobot_venv(tmp_path):
    (block,) = [b for b in _blocks("bash") if "pip install " in b]
    (command,) = [line for line in block.splitlines() if line.startswith("pip install ")]
    assert "--no-deps" not in command and command.split()[-1] == "/path/to/gazereg/lerobot_plugin", command
    command = command.replace("/path/to/gazereg", str(ROOT))
    venv = _lerobot_venv(tmp_path)
    env = {**os.environ, "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("PYTHONPATH", None)
    probe = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import lerobot, torch\ntry:\n import gazereg\nexcept ImportError: pass\n"
         "else: raise SystemExit('gazereg visible before the install')"],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert probe.returncode == 0, probe.stderr[-2000:]
    before = _installed(venv)

    r = subprocess.run(["bash", "-euo", "pipefail", "-c", command], capture_output=True, text=True, env=env,
                       timeout=900, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    new = _installed(venv) - before
    assert {"gazereg", "lerobot_policy_gazereg", "tyro"} <= new, new
    assert not new & LEROBOT_OWN, f"the install replaced lerobot's own packages: {sorted(new & LEROBOT_OWN)}"

    help_ = subprocess.run([str(venv / "bin" / "gazereg"), "import", "write-gaze", "--help"], capture_output=True,
                           text=True, env=env, timeout=300)  # fmt: skip
    assert help_.returncode == 0 and "--store" in help_.stdout, help_.stderr[-3000:]
    types = subprocess.run(
        [str(venv / "bin" / "python"), "-c",
         "from lerobot.configs import PreTrainedConfig\nimport lerobot_policy_gazereg\n"
         "print(*(PreTrainedConfig.get_choice_class(t).__name__ for t in ('smolvla_gaze', 'pi0_gaze', 'pi05_gaze')))"],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert types.returncode == 0, types.stderr[-3000:]
    assert len(types.stdout.split()) == 3, types.stdout
