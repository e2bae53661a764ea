"""Every command refuses a bad input with one line on stderr that names the problem and exit status 2 (bad
usage) or 1 (a failure); the traceback only with --verbose or GAZEREG_DEBUG=1.

The table drives `gazereg.cli.main` in this process; two rows also run as real processes. `{store}` is a tiny
episode store (camera `cam`, prior `square`, no simulator), `{tmp}` a folder of the test's own.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gazereg import cli
from gazereg.data.store import Episode, EpisodeStore

needs_metaworld = pytest.mark.skipif(importlib.util.find_spec("metaworld") is None, reason="needs Meta-World")

BAD_INPUTS = [
    # gazereg train: options out of range, a missing store, unknown names
    (["train", "--steps", "0"], 2, "--steps must be"),
    (["train", "--steps", "-5"], 2, "--steps must be"),
    (["train", "--batch-size", "0"], 2, "--batch-size must be"),
    (["train", "--save-every", "0"], 2, "--save-every must be"),
    (["train", "--gaze.weight", "nan"], 2, "--gaze.weight must be"),
    (["train", "--gaze.loss-eps", "0"], 2, "--gaze.loss-eps must be"),
    (["train", "--data.store", "{tmp}/none", "--steps", "2"], 2, "is not an episode store"),
    (
        [
            "train",
            "--preset",
            "ci",
            "--data.store",
            "{store}",
            "--run-dir",
            "{tmp}/run",
            "--gaze.prior",
            "nosuch",
            "--batch-size",
            "4",
        ],
        2,
        "nosuch",
    ),
    (["train", "--policy.type", "nosuch"], 2, "--policy.type"),
    (["train", "--preset", "nosuch"], 2, "unknown preset 'nosuch'"),
    (["experiment", "--preset"], 2, "--preset needs a name"),
    # gazereg priors
    (["priors", "--store", "{store}", "--source", "nosuch"], 2, "unknown gaze source 'nosuch'"),
    (["priors", "--store", "{store}", "--source", "uniform", "--camera", "corner2"], 2, "corner2"),
    # gazereg eval
    (["eval", "--episodes", "0"], 2, "--episodes must be"),
    (["eval", "--max-steps", "0"], 2, "--max-steps must be"),
    (["eval", "--workers", "0"], 2, "--workers must be"),
    (["eval", "--batch", "0"], 2, "--batch must be"),
    (["eval", "--videos", "-1"], 2, "--videos must be"),
    (["eval", "--seed-start", "-1"], 2, "--seed-start must be"),
    (["eval", "--conditions", "clean", "fog:0.5"], 2, "unknown perturbation 'fog'"),
    (["eval", "--conditions", "dim:2"], 2, "--conditions: 'dim:2'"),
    (["eval", "--checkpoints", "{tmp}/none", "--out", "{tmp}/eval"], 2, "--checkpoints"),
    (["eval", "--checkpoints", "{tmp}", "--out", "{tmp}/eval"], 2, "not a saved policy folder"),
    pytest.param(
        ["eval", "--tasks", "reach-v3", "nosuch-v3", "--checkpoints", "{tmp}", "--out", "{tmp}/eval"],
        2,
        "--tasks: unknown Meta-World task 'nosuch-v3'; closest: ",
        marks=needs_metaworld,
    ),
    # gazereg collect
    pytest.param(
        ["collect", "--tasks", "juggle-v3", "--out", "{tmp}/demos"], 2, "juggle-v3", marks=needs_metaworld
    ),
    (["collect", "--episodes", "0", "--out", "{tmp}/demos"], 2, "--episodes must be"),
    (["collect", "--image-size", "4", "--out", "{tmp}/demos"], 2, "--image-size must be"),
    (["collect", "--perturbation", "fog:1", "--out", "{tmp}/demos"], 2, "--perturbation 'fog:1'"),
    # gazereg experiment: its own options and its nested train / eval options, named as typed
    (["experiment", "--arms", "baseline", "nosuch"], 2, "--arms: unknown arm 'nosuch'"),
    (["experiment", "--eval.episodes", "0"], 2, "--eval.episodes must be"),
    (["experiment", "--eval.conditions", "fog"], 2, "--eval.conditions: 'fog'"),
    (["experiment", "--train.steps", "0"], 2, "--train.steps must be"),
    (["experiment", "--train-seeds"], 2, "--train-seeds is empty"),
    (["experiment", "--demos-per-task", "0"], 2, "--demos-per-task must be"),
    (["experiment", "--heldout-per-task", "0"], 2, "--heldout-per-task must be"),
    (["experiment", "--heldout-seed-start", "-1"], 2, "--heldout-seed-start must be"),
    (["experiment", "--parallel", "0"], 2, "--parallel must be"),
    (["experiment", "--threads-per-run", "0"], 2, "--threads-per-run must be"),
    (["experiment", "--convergence-points", "0"], 2, "--convergence-points must be"),
    (["experiment", "--threshold", "1"], 2, "--threshold must be"),
    (["experiment", "--figure-frames", "0"], 2, "--figure-frames must be"),
    (["experiment", "--data-from"], 2, "--data-from needs the run folder"),
    (["experiment", "--data-from", "{tmp}", "--out", "{tmp}/new"], 2, "holds no experiment (no config.json)"),
    # options tyro refuses (unknown, of the wrong type, outside a field's choices): one line naming the option
    (["train", "--train.stepz", "10"], 2, "unknown option --train.stepz (did you mean --steps?)"),
    (["train", "--stepz", "10"], 2, "unknown option --stepz (did you mean --steps?)"),
    (["experiment", "--train.stepz", "10"], 2, "unknown option --train.stepz (did you mean --train.steps?)"),
    (["train", "stray"], 2, "unexpected argument 'stray'"),
    (["train", "--steps", "2.5"], 2, "--steps must be an integer, got '2.5'"),
    (["train", "--gaze.weight", "abc"], 2, "--gaze.weight must be a number, got 'abc'"),
    (["train", "--gaze.layers", "1", "x"], 2, "--gaze.layers must be integers, got '1 x'"),
    (["train", "--device", "gpu"], 2, "--device must be one of auto, cpu, cuda, got 'gpu'"),
    (["train", "--optim.betas", "0.9"], 2, "--optim.betas needs 2 value(s)"),
    (["priors", "--aggregation.past", "-1"], 2, "--aggregation.past must be an integer >= 0, got -1"),
    (["priors", "--aggregation.kernel", "box"], 2, "--aggregation.kernel must be one of uniform, gaussian"),
    (["experiment", "--aggregation.past", "-1"], 2, "--aggregation.past must be an integer >= 0, got -1"),
    (
        ["train", "--gaze.queries", "vision"],
        2,
        "--gaze.queries must be one of action, language, both, got 'vision'",
    ),
    (
        ["experiment", "--preset", "smoke", "--out", "{tmp}/exp", "--train.gaze.queries", "text"],
        2,
        "--train.gaze.queries must be one of action, language, both, got 'text'",
    ),
    # layers the policy does not have: refused when the config is built
    (
        ["train", "--preset", "ci", "--gaze.layers", "7"],
        2,
        "--gaze.layers 7 is out of range for a 2-layer policy (--policy.depth 2): layer ids run -2..1",
    ),
    (
        ["experiment", "--preset", "smoke", "--out", "{tmp}/exp", "--train.gaze.layers", "-3"],
        2,
        "--train.gaze.layers -3 is out of range for a 2-layer policy",
    ),
    # an experiment's preflight: tasks and a given GLC checkpoint, before the demos stage
    pytest.param(
        ["experiment", "--preset", "smoke", "--out", "{tmp}/exp", "--tasks", "nosuch-v3"],
        2,
        "--tasks: unknown Meta-World task 'nosuch-v3'; closest: ",
        marks=needs_metaworld,
    ),
    pytest.param(
        ["experiment", "--preset", "smoke", "--out", "{tmp}/exp", "--glc.checkpoint", "{glc_code}"],
        2,
        "--glc.checkpoint {glc_code} holds pickled code, which gazereg never loads; give a safetensors or",
        marks=needs_metaworld,
    ),
    pytest.param(
        [
            "experiment",
            "--preset",
            "smoke",
            "--out",
            "{tmp}/exp",
            "--glc.checkpoint",
            "{glc_other}",
            "--glc.config",
            "small",
        ],
        2,
        "--glc.checkpoint {glc_other} is not a GLC checkpoint: 221 expected weights missing (first: "
        "'blocks.0.attn.norm_k.bias'); 1 unexpected (first: 'head.weight')",
        marks=needs_metaworld,
    ),
    pytest.param(
        ["experiment", "--preset", "smoke", "--out", "{tmp}/exp", "--glc.checkpoint", "{glc_junk}"],
        2,
        "--glc.checkpoint {glc_junk} is not a torch weights file",
        marks=needs_metaworld,
    ),
    pytest.param(
        ["experiment", "--preset", "smoke", "--out", "{tmp}/exp", "--glc.checkpoint", "{tmp}/none.pt"],
        2,
        "--glc.checkpoint {tmp}/none.pt: GLC checkpoint",
        marks=needs_metaworld,
    ),
    pytest.param(  # the preflight runs before --data-from copies anything
        ["experiment", "--preset", "smoke", "--data-from", "{runs}/a", "--out", "{tmp}/exp"]
        + ["--tasks", "nosuch-v3"],
        2,
        "--tasks: unknown Meta-World task 'nosuch-v3'",
        marks=needs_metaworld,
    ),
    (
        ["priors", "--store", "{store}", "--camera", "cam", "--source", "glc"]
        + ["--source-params", "checkpoint={glc_code}"],
        2,
        "{glc_code} holds pickled code, which gazereg never loads",
    ),
    # gazereg glc
    (["glc", "train", "--optim.steps", "0"], 2, "--optim.steps must be"),
    (["glc", "train", "--optim.lr", "0"], 2, "--optim.lr must be"),
    (["glc", "train", "--stride", "0"], 2, "--stride must be"),
    (
        ["glc", "train", "--store", "{store}", "--camera", "cam", "--holdout", "99", "--out", "{tmp}/glc"],
        2,
        "--holdout",
    ),
    (
        [
            "glc",
            "train",
            "--store",
            "{store}",
            "--camera",
            "cam",
            "--holdout",
            "0",
            "1",
            "--out",
            "{tmp}/glc",
        ],
        2,
        "no training episodes left",
    ),
    (["glc", "eval", "--hop", "0"], 2, "--hop must be"),
    # gazereg import, viz, compare
    (["import", "hdf5", "--file", "{tmp}/none.hdf5", "--out", "{tmp}/imported"], 2, "none.hdf5"),
    (["viz", "strip", "--store", "{store}", "--episode", "99", "--out", "{tmp}/s.png"], 2, "no episode 99"),
    (
        ["viz", "strip", "--store", "{store}", "--camera", "side", "--out", "{tmp}/s.png"],
        2,
        "no camera 'side'",
    ),
    (["compare", "{tmp}/a"], 2, "required"),
    (["compare", "{tmp}/a", "{tmp}/b"], 2, "is not a folder"),
    (["compare", "{runs}/a", "{runs}/b"], 2, "share no evaluated episode"),
]


def _write_store(root: Path) -> EpisodeStore:
    """Two 6-frame episodes of 32 px images from camera `cam`, with a uniform prior `square`."""
    store = EpisodeStore(root, create=True)
    rng = np.random.default_rng(0)
    for e in range(2):
        frames = rng.integers(0, 255, (6, 32, 32, 3), dtype=np.uint8)
        state = rng.normal(size=(6, 4)).astype(np.float32)
        action = rng.normal(size=(6, 4)).astype(np.float32)
        store.write(Episode("reach", "reach it", {"cam": frames}, state, action, meta={"seed": e}))
        store.write_prior("square", e, np.full((6, 8, 8), 1 / 64, np.float32), np.ones(6, bool))
    store.write_prior_info("square", {"camera": "cam", "size": [8, 8], "source": {"name": "synthetic"}})
    return store


def _write_run(root: Path, arm: str) -> None:
    """A finished experiment run as `gazereg compare` reads it: config.json, stage records, eval_info.json."""
    (root / "eval").mkdir(parents=True)
    (root / "stages").mkdir()
    for stage in ("demos", "priors", "train", "eval", "converge", "align"):
        (root / "stages" / f"{stage}.json").write_text("{}")
    (root / "config.json").write_text(json.dumps({"arms": [arm]}))
    episode = {"arm": f"{arm}@s0", "task": "reach-v3", "condition": "clean", "seed": 1000, "success": True}
    (root / "eval" / "eval_info.json").write_text(json.dumps({"episodes": [episode]}))


class _Code:
    """Pickles as a call of `print`: a checkpoint file holding code."""

    def __reduce__(self):
        return (print, ("this must not run",))


def _write_glc_files(root: Path) -> dict[str, str]:
    """Files given as GLC checkpoints that are none: pickled code, other weights, bytes of no format."""
    import pickle

    import torch

    root.mkdir(parents=True)
    with open(root / "code.pt", "wb") as f:
        pickle.dump({"model_state": {}, "x": _Code()}, f, protocol=2)
    torch.save({"model_state": {"head.weight": torch.zeros(2)}}, root / "other.pt")
    (root / "junk.pt").write_bytes(b"junk")
    return {f"glc_{name}": str(root / f"{name}.pt") for name in ("code", "other", "junk")}


@pytest.fixture(scope="module")
def places(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("bad_inputs")
    _write_store(root / "store")
    _write_run(root / "runs" / "a", "baseline")
    _write_run(root / "runs" / "b", "gaze")
    glc = _write_glc_files(root / "glc")
    return {"store": str(root / "store"), "runs": str(root / "runs"), **glc}


@pytest.mark.parametrize(
    ("argv", "status", "message"), BAD_INPUTS, ids=lambda v: " ".join(v) if isinstance(v, list) else None
)
def test_a_bad_input_ends_with_one_line_naming_it(
    argv, status, message, places, tmp_path, capsys, monkeypatch
):
    """Exactly one line on stderr (no box, no traceback) that names the problem; and nothing written: a
    command refuses its input before it starts work (`--out` is not created)."""
    monkeypatch.delenv("GAZEREG_DEBUG", raising=False)
    args = [a.format(tmp=tmp_path, **places) for a in argv]
    assert cli.main(args) == status
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"gazereg {args[0]}: error: "), err
    assert message.format(tmp=tmp_path, **places) in lines[0] and "Traceback" not in err
    if status == 2 and "--out" in args:
        assert not Path(args[args.index("--out") + 1]).exists(), "refused only after work started"


def test_an_unknown_command_is_named_before_the_usage(capsys):
    """`gazereg nosuch`: exit 2, the first line names it, the list of commands follows (no traceback)."""
    assert cli.main(["nosuch"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines()[0] == "gazereg: unknown command 'nosuch'" and "Traceback" not in err
    assert "usage: gazereg" in err


def _gazereg(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if k != "GAZEREG_DEBUG"}
    return subprocess.run(
        [sys.executable, "-m", "gazereg.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={**environ, **(env or {})},
    )


def test_a_real_process_exits_2_with_one_line_and_the_traceback_only_when_asked():
    r = _gazereg("experiment", "--arms", "baseline", "nosuch")
    assert r.returncode == 2
    assert r.stderr.splitlines() == [
        "gazereg experiment: error: --arms: unknown arm 'nosuch'; choose from baseline, gaze, perturbed, "
        "location, uniform, other_episode, same_task, blobs, saliency, glc"
    ]
    for verbose in (
        _gazereg("experiment", "--arms", "nosuch", "--verbose"),
        _gazereg("experiment", "--arms", "nosuch", env={"GAZEREG_DEBUG": "1"}),
    ):
        assert verbose.returncode == 2
        assert "Traceback" in verbose.stderr and "unknown arm 'nosuch'" in verbose.stderr.splitlines()[-1]


def test_a_real_process_exits_2_for_an_evaluation_condition_no_simulator_knows(tmp_path):
    r = _gazereg("eval", "--conditions", "clean", "fog:0.5", "--out", str(tmp_path / "eval"))
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1
    assert r.stderr.startswith("gazereg eval: error: --conditions: 'fog:0.5': unknown perturbation 'fog'")
    assert not (tmp_path / "eval").exists()  # refused before anything was written
