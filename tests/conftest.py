import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import settings

# Deterministic, CI-sized property tests.
settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
torch.set_num_threads(1)


@pytest.fixture
def rng():
    return torch.Generator().manual_seed(0)


@pytest.fixture(scope="session")
def finished_experiment(tmp_path_factory):
    """A finished smoke experiment folder (baseline and gaze, one seed, 3 clean setups per task), shared by
    the tests of the scripts that read one; they write only into new subfolders of it or elsewhere."""
    from gazereg import cli

    out = tmp_path_factory.mktemp("finished") / "exp"
    args = [
        "--preset",
        "smoke",
        "--arms",
        "baseline",
        "gaze",
        "--eval.conditions",
        "clean",
        "--parallel",
        "1",
    ]
    assert cli.main(["experiment", *args, "--eval.episodes", "3", "--out", str(out)]) == 0
    return out


ROOT = Path(__file__).resolve().parents[1]


def _recorded_gaze_store(root, levels=(90, 91, 92), gaze=None, hw=(16, 16)):
    """A new EpisodeStore at `root` with one episode per grey level: episode k has T = 5 + k flat frames of
    that level (hw pixels, camera "cam", uint8), zero state and action (T, 2), task "t", and recorded gaze
    `gaze_uv.cam` (T, 2) fixed at (u, v) = (0.25, 0.75) unless gaze[k] is False (then no gaze at all)."""
    from gazereg.data.store import Episode, EpisodeStore

    gaze = (True,) * len(levels) if gaze is None else gaze
    store = EpisodeStore(root, create=True)
    for k, (level, looked) in enumerate(zip(levels, gaze, strict=True)):
        T = 5 + k
        uv = np.tile(np.array([0.25, 0.75], np.float32), (T, 1))
        store.write(
            Episode(
                task="t",
                instruction="look",
                frames={"cam": np.full((T, *hw, 3), level, np.uint8)},
                state=np.zeros((T, 2), np.float32),
                action=np.zeros((T, 2), np.float32),
                extras={"gaze_uv.cam": uv} if looked else {},
            )
        )
    return store


def _candidate_archive(dest, command, episodes):
    """A tuning candidate's archive at `dest`: a real archive (docs/records/paper-abl-b) whose configuration is
    the one the `gazereg experiment` command line `command` builds and whose evaluation records are
    `episodes`; returns `dest`."""
    import gzip
    import json
    import shutil

    from gazereg.experiment.tuning import built_config
    from gazereg.runtime.config import to_dict

    shutil.copytree(ROOT / "docs" / "records" / "paper-abl-b", dest)
    (dest / "config.json").write_text(
        json.dumps(to_dict(built_config(tuple(command))), indent=2, sort_keys=True)
    )
    path = dest / "eval" / "eval_info.json.gz"
    path.write_bytes(gzip.compress(json.dumps({"episodes": episodes}).encode()))
    return dest


@pytest.fixture(scope="session")
def candidate_archive():
    """`candidate_archive(dest, command, episodes)`: a tuning candidate's archive made here
    (`_candidate_archive`), for the tests of the tuning scripts."""
    return _candidate_archive


@pytest.fixture(scope="session")
def recorded_gaze_store():
    """`recorded_gaze_store(root, levels=(90, 91, 92), gaze=None, hw=(16, 16))`: a small store whose episodes
    carry recorded gaze, for the tests of the priors pipeline (`_recorded_gaze_store`)."""
    return _recorded_gaze_store


def _load_script(relative: str, name: str | None = None):
    """The repository's file `relative` (`scripts/tune_finetune.py`) executed as a fresh module `name` (default
    its stem), registered in `sys.modules` (dataclasses look their module up there)."""
    path = ROOT / relative
    name = name or path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def load_script():
    """Loads a script of the repository as a module: `load_script("scripts/x.py", name=None)` (another `name`
    gives another, fresh module)."""
    return _load_script


@pytest.fixture(scope="session")
def script():
    """scripts/update_results.py loaded as a module: the script that writes and checks the docs' blocks."""
    return _load_script("scripts/update_results.py")


def _forget_accelerate() -> None:
    """Forget accelerate's process-wide state, as a new `gazereg train` process starts without it."""
    from accelerate.state import AcceleratorState, GradientState

    AcceleratorState._reset_state(reset_partial_state=True)
    GradientState._reset_state()


@pytest.fixture
def reset_accelerate():
    """`_forget_accelerate`, for a test that trains twice in one process as two processes would."""
    return _forget_accelerate


@pytest.fixture(autouse=True)
def _fresh_accelerate():
    """Each test starts with accelerate's process-wide state forgotten, as a new `gazereg train` process does:
    accelerate keeps one mixed precision per process and refuses an Accelerator with another, so a test that
    trained under "auto" (bf16 on a CPU with native bf16) must not decide the precision of a later test in the
    same worker (tests that pin float32 failed after one on an AMX CPU)."""
    _forget_accelerate()
    yield
