"""The fine-tuning study's gaze-term tuning (scripts/tune_finetune.py, issue 36 item 3): each step's command
lines, a step refused before the previous one has finished, the choice rule (ties to the earlier candidate),
the table recounted from each candidate's archive (its episodes and training metrics), and a candidate run,
archived and recorded. Nothing trains: a candidate's archive is a committed archive (docs/records/paper-abl-b
for the baseline arm, -c for the gaze arm) with the candidate's configuration and validation episodes."""

import gzip
import json
import shutil
from pathlib import Path

import pytest

from gazereg.envs.metaworld.ml45 import ml45_split
from gazereg.experiment.config import PRESETS
from gazereg.experiment.tuning import built_config
from gazereg.runtime.config import parse, to_dict
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
TASKS = ml45_split().test


@pytest.fixture
def tune(tmp_path, monkeypatch, load_script):
    module = load_script("scripts/tune_finetune.py")
    monkeypatch.setattr(module, "ROOT", tmp_path)
    monkeypatch.setattr(module, "DOCS", tmp_path / "docs" / "tuning")
    monkeypatch.setattr(module, "RECORDS", tmp_path / "docs" / "records" / "tune-ft")
    return module


def entry(tune, name):
    return next(e for _, entries, _ in tune.plan() for e in entries if e.candidate.name == name)


def write_gz(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress(text.encode()))


def fake_archive(tune, name, successes, dest=None, command=None):
    """An archive for candidate `name` (its command's configuration unless `command`), whose clean
    validation episodes succeed `successes` times over the 5 tasks x 20 setups (arm@s0)."""
    e = entry(tune, name)
    dest = tune.archive_path(name) if dest is None else dest
    shutil.copytree(ROOT / "docs" / "records" / f"paper-abl-{'c' if e.step.arm == 'gaze' else 'b'}", dest)
    cfg = built_config(tuple(command or e.command))
    (dest / "config.json").write_text(json.dumps(to_dict(cfg), indent=2, sort_keys=True))
    episodes = [
        {"arm": f"{e.step.arm}@s0", "task": task, "condition": "clean", "seed": 1300 + i, "length": 9,
         "success": 20 * t + i < successes}
        for t, task in enumerate(TASKS) for i in range(20)
    ]  # fmt: skip
    write_gz(dest / "eval" / "eval_info.json.gz", json.dumps({"episodes": episodes}))
    return dest


def test_the_commands_of_each_step(tune):
    base = ["gazereg", "experiment", "--preset", "ml45_finetune", "--eval.seed-start", "1300"]
    base += ["--eval.episodes", "20", "--convergence-points", "1", "--heldout-per-task", "1"]
    recipe = entry(tune, "ft-lr1e-3").command
    assert recipe == [
        *base,
        "--arms",
        "baseline",
        "--train.optim.lr",
        "1e-3",
        "--out",
        "runs/tune-ft/ft-lr1e-3",
    ]
    cfg = parse(PRESETS, recipe[2:], prog="test")
    assert (cfg.arms, cfg.train_seeds, cfg.tasks, cfg.demos_per_task) == (("baseline",), (0,), TASKS, 10)
    assert (cfg.eval.seed_start, cfg.eval.episodes, cfg.eval.conditions) == (1300, 20, ("clean",))
    assert (cfg.train.optim.lr, cfg.train.steps, str(cfg.train.init_from)) == (1e-3, 3000, "models/ml45")
    assert (
        cfg.train.policy.depth == 4
    )  # the layers step's early (0), middle (1 2), last (3) and default (2 3)
    assert entry(tune, "w1").overrides is None  # unknown until the recipe step has chosen

    for name, k in (("ft-default", 40), ("ft-lr1e-4", 30), ("ft-lr1e-3", 45), ("ft-steps6k", 45)):
        fake_archive(tune, name, k)
    assert entry(tune, "w1e-2").overrides is None  # unknown until the generalist step has chosen
    assert entry(tune, "g-continued").command[len(base) :] == [
        "--arms", "baseline", "--train.optim.lr", "1e-3", "--train.init-from", "runs/pretrain-continued/policy",
        "--out", "runs/tune-ft/g-continued",
    ]  # fmt: skip
    fake_archive(tune, "g-continued", 45)  # ties the committed generalist's run: it stays
    weight = entry(tune, "w1e-2").command
    assert weight[len(base) :] == ["--arms", "gaze", "--train.optim.lr", "1e-3", "--train.gaze.weight", "1e-2",
                                   "--out", "runs/tune-ft/w1e-2"]  # fmt: skip
    gaze = parse(PRESETS, weight[2:], prog="test").train.gaze
    assert (gaze.weight, gaze.queries, gaze.layers) == (1e-2, "action", (-2, -1))

    for name, k in (("w1e-3", 40), ("w1e-2", 50), ("w1e-1", 50), ("w1", 20), ("w10", 10)):
        fake_archive(tune, name, k)
    both = entry(tune, "q-both").command
    assert both[len(base) + 2 : -2] == ["--train.optim.lr", "1e-3", "--train.gaze.weight", "1e-2",
                                        "--train.gaze.queries", "both"]  # fmt: skip
    assert entry(tune, "w1e-2").candidate.name in [e.candidate.name for e in tune.plan()[4][1]]  # carried
    fake_archive(tune, "q-language", 50)
    fake_archive(tune, "q-both", 51)
    gaze = parse(PRESETS, entry(tune, "l-middle").command[2:], prog="test").train.gaze
    assert (gaze.weight, gaze.queries, gaze.layers) == (1e-2, "both", (1, 2))


def test_the_scratch_recipe_step_stands_beside_the_chain(tune, capsys):
    """The same four recipes from random weights (ml45_scratch), runnable at any time, its choice passed on to no
    later step: the gaze steps take the pretrained recipe step's."""
    scratch = entry(tune, "sc-lr1e-3").command
    assert scratch[:4] == ["gazereg", "experiment", "--preset", "ml45_scratch"]
    assert scratch[-4:] == ["--train.optim.lr", "1e-3", "--out", "runs/tune-ft/sc-lr1e-3"]
    cfg = parse(PRESETS, scratch[2:], prog="test")
    assert (cfg.train.init_from, cfg.train.optim.lr, cfg.eval.seed_start, cfg.arms) == (
        None,
        1e-3,
        1300,
        ("baseline",),
    )
    assert cfg.train.policy == parse(PRESETS, entry(tune, "ft-lr1e-3").command[2:], prog="test").train.policy
    assert [e.candidate.name for e in tune.runnable("recipe-scratch", None)] == [
        "sc-default", "sc-lr1e-4", "sc-lr1e-3", "sc-steps6k"
    ]  # fmt: skip
    for name, k in (("ft-default", 30), ("ft-lr1e-4", 31), ("ft-lr1e-3", 20), ("ft-steps6k", 20)):
        fake_archive(tune, name, k)
    for name, k in (("sc-default", 30), ("sc-lr1e-4", 20), ("sc-lr1e-3", 40), ("sc-steps6k", 20)):
        fake_archive(tune, name, k)
    assert [c and c.candidate.name for _, _, c in tune.plan()][:2] == ["ft-lr1e-4", "sc-lr1e-3"]
    fake_archive(tune, "g-continued", 10)  # the committed generalist stays
    assert entry(tune, "w1").overrides == ("--train.optim.lr", "1e-4", "--train.gaze.weight", "1")
    assert "- recipe-scratch: **sc-lr1e-3**, learning rate 1e-3" in tune.table()


def test_the_generalist_step_chooses_which_generalist_the_gaze_steps_fine_tune(tune):
    """After the recipe step: its chosen run (the committed generalist) against the longer-pretrained one at
    the same recipe; the gaze steps fine-tune the one chosen."""
    assert entry(tune, "g-continued").overrides is None  # unknown until the recipe step has chosen
    for name, k in (("ft-default", 30), ("ft-lr1e-4", 31), ("ft-lr1e-3", 20), ("ft-steps6k", 20)):
        fake_archive(tune, name, k)
    cfg = parse(PRESETS, entry(tune, "g-continued").command[2:], prog="test")
    assert (str(cfg.train.init_from), cfg.train.optim.lr, cfg.arms) == (
        "runs/pretrain-continued/policy",
        1e-4,
        ("baseline",),
    )
    carried = tune.plan()[2][1][0]
    assert (carried.carried, carried.candidate.name) == (True, "ft-lr1e-4")
    assert [e.candidate.name for e in tune.runnable(None, None)] == ["sc-default", "sc-lr1e-4", "sc-lr1e-3",
                                                                     "sc-steps6k"]  # fmt: skip
    assert [e.candidate.name for e in tune.runnable("generalist", None)] == ["g-continued"]
    fake_archive(tune, "g-continued", 36)
    assert [c and c.candidate.name for _, _, c in tune.plan()][:3] == ["ft-lr1e-4", None, "g-continued"]
    assert entry(tune, "w1").overrides == (
        "--train.optim.lr", "1e-4", "--train.init-from", "runs/pretrain-continued/policy",
        "--train.gaze.weight", "1",
    )  # fmt: skip
    assert "- generalist: **g-continued**, the longer-pretrained generalist (ml45_continued)" in tune.table()


def test_a_step_waits_for_the_previous_one(tune, capsys):
    fake_archive(tune, "ft-default", 40)
    assert tune.main(["--step", "weight"]) == 2
    assert "step weight runs once the steps before it have finished; not run yet: ft-lr1e-4, ft-lr1e-3, " \
        "ft-steps6k, g-continued" in capsys.readouterr().err  # fmt: skip
    assert tune.main(["--only", "q-both"]) == 2
    assert (
        "not run yet: ft-lr1e-4, ft-lr1e-3, ft-steps6k, g-continued, w1e-3, w1e-2, w1e-1, w1, w10"
        in capsys.readouterr().err
    )
    assert [e.candidate.name for e in tune.runnable(None, None)] == ["ft-lr1e-4", "ft-lr1e-3", "ft-steps6k"]
    assert not tune.RECORDS.joinpath("ft-lr1e-4").exists()  # nothing ran


def test_the_choice_is_the_most_successes_ties_to_the_earlier(tune):
    for name in ("ft-default", "ft-lr1e-4", "ft-lr1e-3", "ft-steps6k"):
        fake_archive(tune, name, 30)  # all tie: the preset
    fake_archive(tune, "g-continued", 30)  # ties: the committed generalist
    for name, k in (("w1e-3", 40), ("w1e-2", 50), ("w1e-1", 49), ("w1", 50), ("w10", 10)):
        fake_archive(tune, name, k)  # w1e-2 and w1 tie: the smaller weight
    fake_archive(tune, "q-language", 49)
    fake_archive(tune, "q-both", 50)  # ties the carried action run: it stays
    for name, k in (("l-early", 50), ("l-middle", 51), ("l-last", 51)):
        fake_archive(tune, name, k)
    chosen = [c and c.candidate.name for _, _, c in tune.plan()]
    assert chosen == [
        "ft-default",
        None,
        "ft-default",
        "w1e-2",
        "w1e-2",
        "l-middle",
    ]  # recipe-scratch not run
    assert entry(tune, "l-middle").overrides == (
        "--train.gaze.weight",
        "1e-2",
        "--train.gaze.layers",
        "1",
        "2",
    )
    text = tune.table()
    assert "**Final choice**: recipe and generalist `the preset, no override` (every arm); gaze term " \
        "`--train.gaze.weight 1e-2 --train.gaze.layers 1 2` (the gaze arm)." in text  # fmt: skip
    assert "| queries | w1e-2 | the action queries (w1e-2's run, not rerun) | 50/100 = 0.50 |" in text


def row_of(text, name):
    return next(line for line in text.splitlines() if line.startswith("| ") and f"| {name} |" in line)


def test_the_table_recounts_each_row_from_its_archive(tune):
    fake_archive(tune, "ft-default", 41)
    path = tune.archive_path("ft-default") / "eval" / "eval_info.json.gz"
    row = row_of(tune.table(), "ft-default")
    assert "| 41/100 = 0.41 | bin-picking-v3 20/20, box-close-v3 20/20, hand-insert-v3 1/20, " in row
    assert "| no gaze term |" in row
    info = json.loads(gzip.decompress(path.read_bytes()))
    info["episodes"][-1]["success"] = True  # door-unlock-v3's last setup
    write_gz(path, json.dumps(info))
    assert "| 42/100 = 0.42 |" in row_of(tune.table(), "ft-default")
    assert "door-unlock-v3 1/20 |" in row_of(tune.table(), "ft-default")


def test_the_gaze_scale_is_read_from_the_training_metrics(tune):
    for name in ("ft-default", "ft-lr1e-4", "ft-lr1e-3", "ft-steps6k", "g-continued"):
        fake_archive(tune, name, 30)
    dest = fake_archive(tune, "w1", 50)
    for seed, kl in enumerate((0.2, 0.3, 0.4)):  # the copied archive's three runs: gaze@s0..s2
        last = {"step": 3000, "loss/action": 0.05, "loss/gaze_kl": kl, "gaze/weight": 1.0}
        val = {"step": 3000, "val/loss_action": 9.0}  # no loss/action: not a training record
        write_gz(
            dest / "train" / f"gaze_s{seed}" / "metrics.jsonl.gz", json.dumps(last) + "\n" + json.dumps(val)
        )
    fits = json.loads((dest / "stages" / "align.json").read_text())["alignment"].values()  # the three runs'
    cc, kl = (sum(f[k] for f in fits) / len(fits) for k in ("gaze_cc", "gaze_kl"))
    assert row_of(tune.table(), "w1").endswith(f"| 0.3 (6 x action) | 0.05 | CC {cc:.2f}, KL {kl:.2f} |")
    write_gz(dest / "train" / "gaze_s1" / "metrics.jsonl.gz", json.dumps({"step": 3000, "loss/action": 0.05}))
    with pytest.raises(
        UsageError, match="gaze_s1/metrics.jsonl: no training record with loss/action, loss/gaze_kl"
    ):
        tune.table()


def test_an_archive_of_another_command_is_refused(tune):
    fake_archive(tune, "ft-lr1e-4", 30, command=entry(tune, "ft-default").command)
    with pytest.raises(
        UsageError, match=r"tune-ft/ft-lr1e-4 holds a run with another configuration \(train\.optim"
    ):
        tune.plan()


def test_a_candidate_is_run_archived_and_recorded(tune, tmp_path, monkeypatch):
    ran = []

    def fake_run(command, root):  # the experiment "runs": its folder appears (an archive reads as a run)
        ran.append(command)
        fake_archive(tune, "ft-default", 37, dest=root / "runs" / "tune-ft" / "ft-default")

    monkeypatch.setattr(tune, "run_experiment", fake_run)
    assert tune.main(["--only", "ft-default"]) == 0
    assert ran == [entry(tune, "ft-default").command]
    assert json.loads((tune.archive_path("ft-default") / "archive.json").read_text())["source"].endswith(
        "runs/tune-ft/ft-default"
    )
    record = json.loads(tune.result_path("ft-default").read_text())
    assert record["step"] == "recipe" and record["command"].endswith("--out runs/tune-ft/ft-default")
    assert sum(c[0] for seeds in record["validation"].values() for c in seeds.values()) == 37
    assert (
        "| recipe | ft-default | the preset: lr 5e-4, batch 32, 3,000 steps | 37/100 = 0.37 |"
        in (tune.DOCS / "finetune.md").read_text()
    )


def test_the_committed_table_is_the_archives(load_script):
    assert (
        load_script("scripts/tune_finetune.py", "tune_finetune_real").table()
        == (ROOT / "docs" / "tuning" / "finetune.md").read_text()
    )
