"""The long stages other than training report their progress on stderr through gazereg.runtime.progress (under
pytest stderr is not a terminal, so each writes lines, here only its final one): priors, evaluation (resumed
work counted as done) and demonstration collection. Training's: tests/training/test_train_progress.py."""

import re

import pytest

import gazereg.evaluation.rollout as ev
from gazereg.evaluation.config import EvalConfig
from gazereg.gaze.priors import PriorsConfig, make_priors

RATE = r"[0-9.]+ episodes/(s|min)"


def test_priors_write_a_progress_line(tmp_path, capsys, recorded_gaze_store):
    store = recorded_gaze_store(tmp_path / "s")
    make_priors(PriorsConfig(store=store.root, source="recorded", camera="cam", size=(8, 8)))
    line = rf"^priors recorded in {re.escape(str(store.root))}: 3/3 episodes \(100%\), {RATE}, took \d+ s$"
    assert re.search(line, capsys.readouterr().err, re.M)
    make_priors(PriorsConfig(store=store.root, source="recorded", camera="cam", size=(8, 8)))
    assert capsys.readouterr().err == ""  # nothing left to do: no line
    make_priors(
        PriorsConfig(store=store.root, source="recorded", camera="cam", size=(8, 8), overwrite=True),
        progress=False,
    )
    assert capsys.readouterr().err == ""


class Worker:
    def run(self, jobs):
        return [{"arm": j.arm, "task": j.task, "condition": j.condition, "seed": j.seed, "success": True,
                 "length": 1} for j in jobs]  # fmt: skip

    def close(self):
        pass


def test_evaluation_writes_a_progress_line_counting_logged_rollouts_as_done(tmp_path, capsys):
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "model.safetensors").write_bytes(b"w")
    jobs = [ev.Job("a", str(ckpt), "t", "clean", s, None) for s in range(5)]
    cfg, log_path = EvalConfig(workers=1, batch=1, max_steps=3), tmp_path / "episodes.jsonl"
    ev.run_jobs(jobs, cfg, True, log_path, Worker, label="eval runs/x")
    final = rf"^eval runs/x: 5/5 episodes \(100%\), {RATE}, took \d+ s$"
    assert re.search(final, capsys.readouterr().err, re.M)
    log_path.write_text("".join(log_path.read_text().splitlines(True)[:3]))  # killed after 3 rollouts
    ev.run_jobs(jobs, cfg, True, log_path, Worker, label="eval runs/x")
    assert re.search(final, capsys.readouterr().err, re.M)
    ev.run_jobs(jobs, cfg, False, log_path, Worker, label="eval runs/x")
    assert capsys.readouterr().err == ""


@pytest.mark.sim
def test_collection_writes_a_progress_line(tmp_path, capsys):
    pytest.importorskip("metaworld")
    from gazereg.envs.collect import collect
    from gazereg.envs.collect_config import CollectConfig
    from gazereg.envs.render import select_gl_backend

    out = tmp_path / "demos"
    cfg = CollectConfig(
        out=out, tasks=("reach-v3",), episodes=2, image_size=32, workers=1, gl_backend=select_gl_backend()
    )
    assert collect(cfg).complete
    line = rf"^collect {re.escape(str(out))}: 2/2 episodes \(100%\), {RATE}, took \d+ s"
    assert re.search(line, capsys.readouterr().err, re.M)
