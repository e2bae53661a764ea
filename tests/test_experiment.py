"""The whole pipeline end to end at smoke size (real Meta-World rendering, real training and evaluation)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from gazereg import cli
from gazereg.envs.metaworld.instructions import instruction_for
from gazereg.experiment import STAGES, main
from gazereg.runtime.hardware import NumericsKey

pytestmark = pytest.mark.sim


def test_smoke_experiment_end_to_end_and_resume(tmp_path, capsys):
    out = tmp_path / "exp"
    assert main(["--preset", "smoke", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    arms = {"baseline", "gaze", "perturbed", "glc"}
    assert set(report["success"]) == arms
    for arm in report["success"].values():
        assert set(arm) == {"clean", "dim:0.7"} and arm["clean"]["n"] == 2
    assert set(report["alignment"]) == arms
    glc = json.loads((out / "stages" / "priors.json").read_text())["glc"]  # trained here: no checkpoint given
    assert glc["steps"] == 3 and (out / "glc" / "final" / "model.safetensors").exists()
    assert report["glc"]["eval"]["heldout"]
    assert "gaze_kl" in report["alignment"]["gaze"]
    for fig in report["figures"].values():
        assert (out / fig).stat().st_size > 1000
    assert report["videos"] and all((out / v).exists() for v in report["videos"])
    assert (out / "report.md").read_text().startswith("# gazereg experiment")
    said = instruction_for("reach-v3")
    assert report["demos"]["instructions"] == {"reach-v3": said}  # the store's, in the task table
    assert f"| reach-v3 | {said} |" in (out / "report.md").read_text()
    assert set(report["train"]["gaze_arms"]) == arms - {"baseline"}
    # the precision every run trained in, as its trainer resolved "auto", and the machine's numerics key (#33)
    precisions = {json.loads(p.read_text())["mixed_precision"] for p in (out / "train").glob("*/config.json")}
    assert precisions == {report["machine"]["precision"]} and report["machine"]["precision"] in ("no", "bf16")
    assert report["machine"]["numerics"] == NumericsKey.here(report["machine"]["precision"]).to_dict()
    eval_info = json.loads((out / "eval" / "eval_info.json").read_text())
    seeds = {
        (e["arm"], e["condition"]): sorted(
            x["seed"]
            for x in eval_info["episodes"]
            if (x["arm"], x["condition"]) == (e["arm"], e["condition"])
        )
        for e in eval_info["episodes"]
    }
    assert len({tuple(v) for v in seeds.values()}) == 1  # every arm and condition on the same setups
    assert all(0 <= e["min_distance"] <= e["final_distance"] for e in eval_info["episodes"])
    assert (
        set(report["distance"]["table"]) == arms
        and "gaze vs baseline | clean" in report["distance"]["paired"]
    )
    # the gaze arm against its own perturbed-gaze control, and no other arm (glc's would be a shuffled GLC prior)
    for table in (report["paired"], report["distance"]["paired"]):
        assert "gaze vs perturbed | clean" in table
        assert not any(k.startswith("glc vs perturbed") for k in table)
    assert (out / "eval" / "episodes.jsonl").read_text().count("\n") == len(eval_info["episodes"])
    assert not list((out / "stages").glob("*.clock.json"))  # finished stages keep their time in the marker
    assert report["wall_time_s"] == pytest.approx(sum(report["stage_times_s"].values()))
    # the attention-under-perturbation analysis runs on a finished experiment
    script = Path(__file__).parents[1] / "scripts" / "attention_under_perturbation.py"
    subprocess.run([sys.executable, str(script), str(out), "--condition", "dim:0.7"], check=True)
    shift = json.loads((out / "attention-dim_0.7.json").read_text())
    assert set(shift["runs"]) == {f"{a}@s0" for a in arms}
    assert 0 < shift["runs"]["gaze@s0"]["perturbed"]["frames"] == shift["runs"]["gaze@s0"]["clean"]["frames"]
    assert all(v > 0 for v in shift["runs"]["gaze@s0"]["action_loss"].values())
    assert (out / "attention-dim_0.7.md").read_text().startswith("## Attention under dim:0.7")
    # several folders: one --out for their table, and each run id in one folder only
    for extra, message in (([], b"need --out"), (["--out", str(out / "both.md")], b"more than one folder")):
        bad = subprocess.run([sys.executable, str(script), str(out), str(out), *extra], capture_output=True)
        assert bad.returncode != 0 and message in bad.stderr
    markers = {s: (out / "stages" / f"{s}.json").stat().st_mtime_ns for s in STAGES}
    capsys.readouterr()
    assert main(["--preset", "smoke", "--out", str(out)]) == 0  # rerun: finished stages are skipped
    for s in STAGES[:-1]:
        assert (out / "stages" / f"{s}.json").stat().st_mtime_ns == markers[s]
    # a changed setting would reuse stages made without it: refused, naming the setting
    capsys.readouterr()
    assert cli.main(["experiment", "--preset", "smoke", "--out", str(out), "--train.steps", "13"]) == 2
    assert "train.steps: 12 -> 13" in capsys.readouterr().err
    assert main(["--preset", "smoke", "--out", str(out), "--parallel", "1"]) == 0  # how it runs may change


def test_every_experiment_makes_the_gaze_prior_that_alignment_measures_against(tmp_path):
    from dataclasses import replace

    from gazereg.experiment import Experiment
    from gazereg.experiment.config import smoke

    def needed(*arms):
        return [prior.name for prior in Experiment(replace(smoke(), arms=arms, out=tmp_path)).priors_needed()]

    assert needed("baseline") == ["visuomotor"]  # nothing to train on, but the align stage reads it
    assert needed("baseline", "gaze", "perturbed") == ["visuomotor", "visuomotor-shuffled"]
    assert needed("baseline", "blobs") == ["visuomotor", "blobs"]


def test_glc_arm_uses_a_given_checkpoint_or_the_one_it_trains(tmp_path):
    from dataclasses import replace

    from gazereg.experiment.arms import arm_prior, trains_glc
    from gazereg.experiment.config import smoke
    from gazereg.gaze.sources.glc import GLCParams
    from gazereg.gaze.sources.perturbed import PerturbedParams

    cfg = replace(smoke(), out=tmp_path)
    assert trains_glc(cfg) and arm_prior("glc", cfg).source == GLCParams(
        checkpoint=tmp_path / "glc" / "final"
    )
    given = replace(cfg, glc=GLCParams(checkpoint=tmp_path / "mine", stride=1))
    assert not trains_glc(given) and arm_prior("glc", given).source == given.glc
    assert arm_prior("perturbed", cfg).source == PerturbedParams(mode="shuffle", base="visuomotor")
    assert arm_prior("baseline", cfg) is None
    with pytest.raises(KeyError, match="unknown arm 'nope'"):
        arm_prior("nope", cfg)


def _dead_pid() -> int:
    """The PID of a process that has exited."""
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    return int(done.stdout)


def test_a_run_sweeps_what_killed_writers_left_in_its_folder(tmp_path, monkeypatch):
    import os
    from dataclasses import replace

    import gazereg.experiment.runner as runner
    from gazereg.experiment import Experiment
    from gazereg.experiment.config import smoke

    stale = tmp_path / "train" / "gaze_s0" / "checkpoints" / f".step_000010.{_dead_pid()}.abcd1234.tmp"
    stale.mkdir(parents=True)
    live = tmp_path / f".config.json.{os.getpid()}.abcd1234.tmp"
    live.write_text("x")
    monkeypatch.setattr(runner, "STAGES", ())  # no stage runs: only what a run does first
    assert Experiment(replace(smoke(), out=tmp_path)).run() == {}
    assert not stale.exists() and live.exists()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"arms": ("baseline", "nosuch")}, "--arms: unknown arm 'nosuch'; choose from baseline, gaze"),
        ({"arms": ("gaze", "gaze")}, "--arms lists gaze more than once"),
        ({"arms": ()}, "--arms is empty"),
        ({"train_seeds": ()}, "--train-seeds is empty"),
        ({"tasks": ()}, "--tasks is empty"),
        ({"demos_per_task": 0}, "--demos-per-task must be an integer >= 1, got 0"),
        ({"heldout_per_task": 0}, "--heldout-per-task must be"),
        ({"glc_steps": 0}, "--glc-steps must be"),
        ({"parallel": 0}, "--parallel must be"),
        ({"threads_per_run": 0}, "--threads-per-run must be"),
        ({"convergence_points": 0}, "--convergence-points must be"),
        ({"convergence_episodes": 0}, "--convergence-episodes must be"),
        ({"threshold": 0.0}, "--threshold must be a finite number in (0, 1), got 0.0"),
        ({"threshold": 1.0}, "--threshold must be"),
        ({"figure_frames": 0}, "--figure-frames must be"),
        ({"prior_size": (0, 64)}, "--prior-size must be"),
        ({"image_size": 4}, "--image-size must be"),
    ],
)
def test_a_bad_experiment_setting_is_refused_when_the_config_is_built(changes, message):
    from dataclasses import replace

    from gazereg.experiment.config import smoke
    from gazereg.runtime.errors import UsageError

    with pytest.raises(UsageError) as refused:
        replace(smoke(), **changes)
    assert message in str(refused.value)


def test_nested_settings_are_named_with_their_path_on_the_command_line():
    from gazereg.experiment.config import PRESETS
    from gazereg.runtime.config import parse
    from gazereg.runtime.errors import UsageError

    for args, message in (
        (["--eval.episodes", "0"], "--eval.episodes must be an integer >= 1, got 0"),
        (["--eval.conditions", "clean", "fog"], "--eval.conditions: 'fog': unknown perturbation 'fog'"),
        (["--train.batch-size", "0"], "--train.batch-size must be"),
    ):
        with pytest.raises(UsageError) as refused:
            parse(PRESETS, ["--preset", "smoke", *args], prog="gazereg experiment")
        assert message in str(refused.value)
