"""The plugin README's priors commands run offline as written (issue 35 item 6): `gazereg import lerobot`,
`gazereg priors --camera`, `gazereg import write-gaze` and `lerobot-train` on the version it writes.

The block runs with its folder variables pointing at the LeRobot v3 fixture, a tiny random SmolVLM and scratch
folders (every other line as written, `CAMERA=front` included: the fixture's camera), and test_docs'
TINY_OVERRIDES appended to `lerobot-train`, less its `--dataset.video_backend=pyav`: the README's own flag must
keep the second block of torchcodec's fallback tracebacks out of the log. Every bash block of the README is run by some test: this
one checks that none is left out.
"""

from __future__ import annotations

import json
from pathlib import Path

from test_docs import TINY_OVERRIDES, _blocks, _run

# Which test runs each bash block of the README, by a string only that block holds.
RUN_BY = {
    "pip install ": "test_install.py::test_the_readme_install_command_pulls_gazereg_core_into_a_lerobot_venv",
    "hf download ": "test_docs.py::test_readme_download_command_is_valid (checked, not run: it needs the network)",
    "--policy.gaze_key=gaze.point": "test_docs.py::test_readme_commands_run_offline_as_written",
    "lerobot_policy_gazereg.export": "test_docs.py::test_readme_commands_run_offline_as_written",
    "gazereg import lerobot ": "test_readme_commands.py::test_readme_priors_commands_run_offline_as_written",
}


PYAV = "--dataset.video_backend=pyav"
OVERRIDES = [flag for flag in TINY_OVERRIDES if flag != PYAV]


def _priors_script(block: str, values: dict[str, Path]) -> str:
    lines = block.replace("\\\n", " ").splitlines()
    out, set_ = [], set()
    for line in lines:
        name = line.split("=", 1)[0]
        if name in values:
            line = f"{name}={values[name]}"
            set_.add(name)
        elif line.startswith("lerobot-train "):
            line = f"{line} {' '.join(OVERRIDES)}"
        out.append(line)
    assert set_ == set(values), f"the priors block no longer sets {sorted(set(values) - set_)}: {block}"
    return "\n".join(out)


def test_every_readme_bash_block_is_run_by_a_test():
    for block in _blocks("bash"):
        owners = [key for key in RUN_BY if key in block]
        assert len(owners) == 1, f"a README bash block is run by {len(owners)} tests (want 1): {block}"
        for command in block.replace("\\\n", " ").splitlines():
            if command.startswith("lerobot-train "):
                assert PYAV in command, f"a README lerobot-train without {PYAV}: {command}"


def test_readme_priors_commands_run_offline_as_written(tmp_path, tiny_vlm, dataset_root):
    (block,) = [b for b in _blocks("bash") if "gazereg import lerobot " in b]
    values = {
        "VLM_DIR": tiny_vlm,
        "DATA_ROOT": dataset_root,
        "STORE": tmp_path / "store",
        "GAZE_ROOT": tmp_path / "gaze_root",
    }
    script = _priors_script(block, values)
    assert "CAMERA=front" in script  # the fixture's camera, as the README writes it
    r = _run(["bash", "-euo", "pipefail", "-c", script], tmp_path)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-4000:]
    info = json.loads((values["GAZE_ROOT"] / "meta" / "info.json").read_text())
    assert {"gaze.front.heatmap", "gaze.front.valid"} <= set(info["features"])
    assert "loss/gaze_kl:" in out
    # --dataset.video_backend=pyav: where torchcodec cannot load FFmpeg, lerobot prints its ~100-line loading
    # traceback once while parsing the command line (any flags); without the flag a second one follows
    assert out.count("[start of libtorchcodec loading traceback]") <= 1, out[-4000:]
