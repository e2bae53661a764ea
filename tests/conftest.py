import importlib.util
import os
from pathlib import Path

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


@pytest.fixture(scope="session")
def script():
    """scripts/update_results.py loaded as a module: the script that writes and checks the docs' blocks."""
    path = Path(__file__).resolve().parents[1] / "scripts" / "update_results.py"
    spec = importlib.util.spec_from_file_location("update_results", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
