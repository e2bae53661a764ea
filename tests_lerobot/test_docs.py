"""The plugin README's commands run offline as written (so the docs cannot rot), and `lerobot-train --help` shows
the help text of every gaze option.

The README's training command runs with its `VLM_DIR=` / `DATA_ROOT=` lines pointing to a tiny random SmolVLM and
the LeRobot v3 fixture, and with TINY_OVERRIDES appended (draccus keeps the last value of a repeated flag): the
tiny model's geometry, CPU and 2 steps. Everything else, the export command and the Python snippet included, runs
verbatim in a scratch folder.
"""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "lerobot_plugin" / "README.md"
BIN = Path(sys.executable).parent
TINY_OVERRIDES = [
    "--policy.load_vlm_weights=false",  # the tiny VLM folder has no weights file
    "--policy.resize_imgs_with_padding=[64,64]",
    "--policy.num_vlm_layers=4",
    "--policy.chunk_size=5",
    "--policy.n_action_steps=5",
    "--policy.device=cpu",
    "--dataset.video_backend=pyav",
    "--dataset.episodes=[0]",
    "--batch_size=4",
    "--steps=2",
    "--save_freq=2",
    "--log_freq=1",
    "--num_workers=0",
    "--wandb.enable=false",
]


def _blocks(lang: str) -> list[str]:
    """The README's fenced code blocks of language `lang`, in order."""
    return re.findall(rf"^```{lang}\n(.*?)^```", README.read_text(), flags=re.M | re.S)


def _block_with(lang: str, needle: str) -> str:
    found = [b for b in _blocks(lang) if needle in b]
    assert len(found) == 1, f"expected one ```{lang} block with {needle!r} in {README}, found {len(found)}"
    return found[0]


def _tiny_train_script(block: str, vlm_dir: Path, data_root: Path) -> str:
    """The README's training block with the two folders set and the tiny overrides appended."""
    lines = block.replace("\\\n", " ").splitlines()
    out = []
    for line in lines:
        if line.startswith("VLM_DIR="):
            line = f"VLM_DIR={vlm_dir}"
        elif line.startswith("DATA_ROOT="):
            line = f"DATA_ROOT={data_root}"
        elif line.startswith("lerobot-train "):
            line = f"{line} {' '.join(TINY_OVERRIDES)}"
        out.append(line)
    assert sum(line.startswith(("VLM_DIR=", "DATA_ROOT=", "lerobot-train ")) for line in out) == 3, block
    return "\n".join(out)


def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "OMP_NUM_THREADS": "1"}
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1")
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=600, env=env)


def test_readme_commands_run_offline_as_written(tmp_path, tiny_vlm, dataset_root):
    train = _tiny_train_script(_block_with("bash", "--policy.gaze_key=gaze.point"), tiny_vlm, dataset_root)
    r = _run(["bash", "-euo", "pipefail", "-c", train], tmp_path)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    assert "loss/gaze_kl:" in r.stdout + r.stderr

    export = _block_with("bash", "lerobot_policy_gazereg.export")
    r = _run(["bash", "-euo", "pipefail", "-c", export], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "type smolvla_gaze -> smolvla" in r.stdout

    snippet = (
        _block_with("python", "from_pretrained") + "\nprint(type(policy).__name__, policy.config.type)\n"
    )
    r = _run([sys.executable, "-c", snippet], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.splitlines()[-1] == "SmolVLAPolicy smolvla"


def test_readme_download_command_is_valid():
    """The one command that needs the network: its CLI and flag exist (it is not run)."""
    block = _block_with("bash", "hf download")
    assert "--local-dir" in block
    hf = BIN / "hf"
    if not hf.exists():
        pytest.skip("the hf CLI (huggingface_hub) is not in this environment")
    r = _run([str(hf), "download", "--help"], BIN)
    assert r.returncode == 0 and "--local-dir" in r.stdout, r.stderr[-2000:]


@pytest.mark.parametrize("policy_type", ["smolvla_gaze", "pi0_gaze", "pi05_gaze"])
def test_train_help_shows_every_gaze_option(tmp_path, policy_type):
    from lerobot.configs import PreTrainedConfig
    from lerobot_policy_gazereg.gaze_common import GazeOptions

    r = _run([str(BIN / "lerobot-train"), f"--policy.type={policy_type}", "--help"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.splitlines()
    config_class = PreTrainedConfig.get_choice_class(policy_type)
    fields = [f.name for f in dataclasses.fields(config_class) if f.name.startswith("gaze_")]
    assert fields == [f.name for f in dataclasses.fields(GazeOptions)] and len(fields) == 7, fields
    for name in fields:
        at = [i for i, line in enumerate(lines) if line.strip().startswith(f"--policy.{name} ")]
        assert len(at) == 1, f"--policy.{name} not described in --help"
        help_line = lines[at[0] + 1].strip()
        assert help_line.startswith("Gaze: "), f"--policy.{name} has no help text: {help_line!r}"
