"""A finished `gazereg pretrain` folder archived (`gazereg archive`: its records only, no demonstrations,
checkpoints or weights), read back by the one reader (`read_pretraining`) the same from the folder and the
archive, and rendered into a docs block (`gazereg.report.pretrain.pretrain_block`, through
scripts/update_results.py) whose success counts are recounted from the episodes and which --check compares
like an experiment's block. One toy pretraining for the module (about 10 s on one core)."""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import pytest

from gazereg import cli
from gazereg.envs.metaworld.instructions import instruction_for
from gazereg.evaluation.stats import wilson
from gazereg.experiment import FinishedPretraining, is_pretraining, read_pretraining, read_run
from gazereg.experiment.archive import archive
from gazereg.report.blockdata import BlockData
from gazereg.report.pretrain import pretrain_block
from gazereg.runtime.errors import UsageError

pytest.importorskip("metaworld")

ROOT = Path(__file__).resolve().parents[1]
RECORDS = {
    "archive.json",
    "config.json",
    "manifest.json",
    "stages/demos.json",
    "stages/eval.json",
    "stages/manifest.json",
    "stages/train.json",
    "train/metrics.jsonl.gz",
    "train/numerics.json",
}
PAGE = "# Pretraining\n<!-- pretrain-ml45:start -->\nold\n<!-- pretrain-ml45:end -->\nend\n"


@pytest.fixture(scope="module")
def pretrained(tmp_path_factory) -> Path:
    """A finished toy pretraining folder."""
    out = tmp_path_factory.mktemp("pretrain") / "pt"
    assert cli.main(["pretrain", "--preset", "toy", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def archived(pretrained, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("records") / "pretrain-toy"
    assert cli.main(["archive", str(pretrained), "--out", str(out)]) == 0
    return out


def files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}


def flip_first_episode(archive_dir: Path) -> dict:
    """Flip the first evaluation episode's success in an archive (its plain or compressed eval_info.json);
    returns the flipped episode."""
    path = archive_dir / "eval" / "eval_info.json"
    info = json.loads(path.read_text())
    info["episodes"][0]["success"] = not info["episodes"][0]["success"]
    path.write_text(json.dumps(info))
    return info["episodes"][0]


def test_the_archive_keeps_exactly_the_records_and_no_weights_or_demos(pretrained, archived, tmp_path):
    assert {"policy/model.safetensors", "demos/store.json"} <= files(pretrained)
    assert any(p.startswith("train/checkpoints/") for p in files(pretrained))
    assert files(archived) == RECORDS | {"eval/eval_info.json"}  # small: kept as it is
    assert (archived / "config.json").read_bytes() == (pretrained / "config.json").read_bytes()
    metrics = gzip.decompress((archived / "train" / "metrics.jsonl.gz").read_bytes())
    assert metrics == (pretrained / "train" / "metrics.jsonl").read_bytes()
    attempts = json.loads((pretrained / "manifest.json").read_text())["training_attempts"]
    recorded = json.loads((archived / "train" / "numerics.json").read_text())["attempts"]
    assert attempts == recorded and len(attempts) == 1 and attempts[0]["start_step"] == 0
    squeezed = archive(pretrained, tmp_path / "gz", gzip_above=0)  # a large evaluation is compressed
    assert files(squeezed) == RECORDS | {"eval/eval_info.json.gz"}
    again = archive(squeezed, tmp_path / "again")  # an archive of an archive keeps it so
    assert files(again) == files(squeezed)


def test_the_folder_and_its_archives_read_the_same(pretrained, archived, tmp_path):
    run = read_pretraining(pretrained)
    assert isinstance(run, FinishedPretraining) and not run.archived and is_pretraining(pretrained)
    assert run.episodes and run.metrics and list(run.stages) == ["demos", "train", "eval", "manifest"]
    squeezed = archive(pretrained, tmp_path / "gz", gzip_above=0)
    for folder in (archived, squeezed):
        kept = read_pretraining(folder)
        assert kept.archived and is_pretraining(folder)
        assert (kept.manifest, kept.config, kept.stages) == (run.manifest, run.config, run.stages)
        assert (kept.episodes, kept.metrics, kept.date) == (run.episodes, run.metrics, run.date)
        assert kept.block() == run.block()
    assert not is_pretraining(ROOT / "docs" / "records" / "paper-abl-a")  # an experiment's archive


def test_the_block_recounts_success_from_the_episodes(pretrained, archived, tmp_path):
    run = read_pretraining(pretrained)
    block = run.block()
    for task in run.tasks:
        k = sum(e["success"] for e in run.episodes if e["task"] == task)
        n = sum(e["task"] == task for e in run.episodes)
        lo, hi = wilson(k, n)
        assert f"| {task} | {instruction_for(task)} | {k}/{n} | [{lo:.2f}, {hi:.2f}] |" in block
    rows = [
        line.split(" | ")[0][2:] for line in block.splitlines() if line.startswith("| ") and "-v3" in line
    ]
    assert rows == sorted(run.tasks)
    # a flipped episode changes the pooled count though the manifest's summary still says the old one
    copy = shutil.copytree(archived, tmp_path / "flipped")
    flipped = flip_first_episode(copy)
    changed = read_pretraining(copy)
    k = sum(e["success"] for e in changed.episodes)
    n = len(changed.episodes)
    assert k != changed.manifest["evaluation"]["pooled"]["successes"]
    lo, hi = wilson(k, n)
    assert f"**{k}/{n} = {k / n:.2f}** [{lo:.2f}, {hi:.2f}] (Wilson 95%)" in changed.block()
    data = BlockData.read(changed.block())
    assert data is not None and data.success == {"pretrained": {"clean": (k, n)}}
    assert data.numerics is not None and data.numerics.to_dict() == changed.manifest["numerics"]
    assert flipped["task"] in changed.block()


def test_pretrain_block_from_plain_data(pretrained):
    """The renderer takes plain data: three tasks, rows sorted by name, k/n per task and pooled."""
    manifest = read_pretraining(pretrained).manifest
    episodes = [
        {"arm": "pretrained", "condition": "clean", "task": t, "seed": 101000 + i, "success": s}
        for t, results in (("reach-v3", [1, 1, 0]), ("door-open-v3", [0, 0, 0]), ("push-v3", [1, 0, 1]))
        for i, s in enumerate(results)
    ]
    metrics = [{"step": 3, "loss/action": 0.5}, {"step": 6, "loss/action": 0.25, "val/loss_action": 0.3}]
    block = pretrain_block(
        manifest, {"demos": 60.0, "train": 120.0}, episodes, metrics, "2026-01-01 00:00 UTC"
    )
    lines = block.splitlines()
    assert lines[0].startswith("Latest `toy` pretraining: 2026-01-01 00:00 UTC, ")
    assert "wall time 3.0 min (demos 1.0, train 2.0 min)" in lines[0] and "gazereg pretrain" in lines[0]
    table = [line for line in lines if line.startswith("| ") and "-v3" in line]
    assert [row.split(" | ")[0] for row in table] == ["| door-open-v3", "| push-v3", "| reach-v3"]
    assert [row.split(" | ")[2] for row in table] == ["0/3", "2/3", "2/3"]
    assert "**4/9 = 0.44**" in block and "final action loss 0.2500 (validation 0.3000) at step 6" in block
    assert (
        f"`{manifest['policy']['model_sha256'][:16]}`" in block and manifest["data"]["fingerprint"] in block
    )
    assert BlockData.read(block).success == {"pretrained": {"clean": (4, 9)}}
    with pytest.raises(ValueError, match="one arm x condition"):
        pretrain_block(manifest, {}, [*episodes, {**episodes[0], "condition": "dim:0.7"}], metrics, "d")


def test_update_results_writes_the_block_and_checks_it(script, archived, tmp_path, capsys):
    repo = tmp_path / "repo"
    (repo / "docs").mkdir(parents=True)
    (repo / "docs" / "pretraining.md").write_text(PAGE)
    args = ["--marker", "pretrain-ml45", "--root", str(repo)]
    assert script.main([str(archived), *args]) == 0
    block = read_pretraining(archived).block()
    page = (repo / "docs" / "pretraining.md").read_text()
    assert page == PAGE.replace("old\n", block)
    assert script.main([str(archived), *args, "--check"]) == 0
    assert "reproduces" in capsys.readouterr().out
    flipped = shutil.copytree(archived, tmp_path / "flipped")
    flip_first_episode(flipped)
    assert script.main([str(flipped), *args, "--check"]) == 1
    assert "does not reproduce" in capsys.readouterr().out
    assert (repo / "docs" / "pretraining.md").read_text() == page  # --check writes nothing
    # a page made under other numerics: the same Fisher agreement as an experiment's block (one flip agrees)
    here, there = ("no", "bf16") if '"precision":"no"' in page else ("bf16", "no")  # "auto": bf16 on AMX
    other = page.replace(f'"precision":"{here}"', f'"precision":"{there}"')
    assert other != page
    (repo / "docs" / "pretraining.md").write_text(other)
    assert script.main([str(flipped), *args, "--check"]) == 0
    out = capsys.readouterr().out
    assert f"numerics differ: precision: {there} vs {here}" in out and "agrees with" in out


def test_an_unfinished_pretraining_is_refused_in_one_line(pretrained, script, tmp_path, capsys):
    unfinished = tmp_path / "unfinished"
    (unfinished / "stages").mkdir(parents=True)
    shutil.copyfile(pretrained / "config.json", unfinished / "config.json")
    for stage in ("demos", "train"):
        shutil.copyfile(pretrained / "stages" / f"{stage}.json", unfinished / "stages" / f"{stage}.json")
    assert is_pretraining(unfinished)
    assert cli.main(["archive", str(unfinished), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has not finished its eval stage" in err and "gazereg archive" in err
    assert not (tmp_path / "out").exists()
    repo = tmp_path / "repo"
    (repo / "docs").mkdir(parents=True)
    (repo / "docs" / "pretraining.md").write_text(PAGE)
    assert script.main([str(unfinished), "--marker", "pretrain-ml45", "--root", str(repo)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("update_results.py: error: ") and err.count("\n") == 1
    with pytest.raises(UsageError, match="neither a pretraining folder"):
        read_pretraining(ROOT / "docs" / "records" / "paper-abl-a")


def test_an_experiment_archive_is_archived_as_before(tmp_path):
    """The experiment path of `gazereg archive` is unchanged: an archive of a committed experiment archive
    holds the same files and reads the same (`read_run`)."""
    source = ROOT / "docs" / "records" / "paper-abl-a"
    kept = archive(source, tmp_path / "again")
    assert files(kept) == files(source)
    a, b = read_run(source), read_run(kept)
    assert (a.stages, a.date, a.episodes()) == (b.stages, b.date, b.episodes())
