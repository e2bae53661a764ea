"""A killed evaluation resumes from its episode log; a rewritten checkpoint is evaluated afresh; bad settings
are refused when the config is built."""

import os
import subprocess
import sys

import pytest

import gazereg.evaluation.rollout as ev
from gazereg.evaluation.config import EvalConfig, parse_checkpoints, presets
from gazereg.runtime.errors import UsageError


class FakeWorker:
    """Records the jobs it runs; a job whose seed is in `fail_on` is killed."""

    def __init__(self, calls, fail_on):
        self.calls, self.fail_on = calls, fail_on

    def run(self, jobs):
        (job,) = jobs  # batch 1
        if job.seed in self.fail_on:
            raise KeyboardInterrupt("killed")
        self.calls.append((job.arm, job.seed))
        return [
            {
                "arm": job.arm,
                "task": job.task,
                "condition": job.condition,
                "seed": job.seed,
                "success": job.seed % 2 == 0,
                "length": 7,
            }
        ]

    def close(self):
        pass


@pytest.fixture
def fake_rollouts():
    calls: list[tuple[str, int]] = []
    fail_on: set[int] = set()
    return calls, fail_on, lambda: FakeWorker(calls, fail_on)


def _run(jobs, max_steps, log_path, make_worker):
    cfg = EvalConfig(max_steps=max_steps, workers=1, batch=1)
    return ev.run_jobs(jobs, cfg, progress=False, log_path=log_path, make_worker=make_worker)


def _jobs(ckpt, seeds):
    return [ev.Job("a", str(ckpt), "reach-v3", "clean", s, None) for s in seeds]


def test_killed_evaluation_resumes_from_log(tmp_path, fake_rollouts):
    calls, fail_on, worker = fake_rollouts
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "model.safetensors").write_bytes(b"weights")
    log_path = tmp_path / "eval" / "episodes.jsonl"
    jobs = _jobs(ckpt, range(4))

    fail_on.add(3)
    with pytest.raises(KeyboardInterrupt):
        _run(jobs, 10, log_path, worker)
    assert calls == [("a", 0), ("a", 1), ("a", 2)]
    with log_path.open("a") as f:
        f.write('{"key": "cut sho')  # a line the kill cut short

    fail_on.clear()
    calls.clear()
    records = _run(jobs, 10, log_path, worker)
    assert calls == [("a", 3)]
    assert [r["seed"] for r in records] == [0, 1, 2, 3]
    assert [r["success"] for r in records] == [True, False, True, False]

    # Same jobs with other max_steps, or a rewritten checkpoint: nothing is reused.
    calls.clear()
    _run(jobs[:1], 11, log_path, worker)
    assert calls == [("a", 0)]
    calls.clear()
    (ckpt / "model.safetensors").write_bytes(b"other weights")
    _run(jobs[:2], 10, log_path, worker)
    assert calls == [("a", 0), ("a", 1)]


def test_libero_preset_avoids_demo_states_and_video_names_are_flat(tmp_path):
    from dataclasses import replace

    cfg = replace(presets()["libero-spatial-25"](), out=tmp_path, videos=1)
    assert cfg.env == "libero" and len(cfg.tasks) == 10
    assert all((cfg.seed_start + i) % 50 >= 25 for i in range(cfg.episodes))  # initial states 25..49
    jobs = ev.make_jobs(cfg, {"gaze": tmp_path / "ckpt"})
    videos = [j.video for j in jobs if j.video]
    assert len(videos) == 10 and all(v.startswith(str(tmp_path / "videos") + "/") for v in videos)
    assert all("/" not in v.rsplit("videos/", 1)[1] for v in videos)


def _dead_pid() -> int:
    """The PID of a process that has exited."""
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    return int(done.stdout)


def test_evaluation_sweeps_what_killed_writers_left_in_its_folder(tmp_path, monkeypatch):
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "config.json").write_text("{}")
    out = tmp_path / "eval"
    (out / "videos").mkdir(parents=True)
    stale = [
        out / f".eval_info.json.{_dead_pid()}.abcd1234.tmp",
        out / "videos" / f".a.gif.{_dead_pid()}.x1.tmp",
    ]
    for path in stale:
        path.write_text("half")
    live = out / f".episodes.jsonl.{os.getpid()}.abcd1234.tmp"  # a writer still running: kept
    live.write_text("x")
    worker = FakeWorker([], set())
    monkeypatch.setattr(ev, "RolloutWorker", lambda *args: worker)
    cfg = EvalConfig(checkpoints=(f"a={ckpt}",), episodes=2, workers=1, batch=1, videos=0, out=out)
    info = ev.evaluate(cfg, progress=False)
    assert [e["seed"] for e in info["episodes"]] == [1000, 1001]
    assert not any(path.exists() for path in stale) and live.exists()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"episodes": 0}, "--episodes must be an integer >= 1, got 0"),
        ({"max_steps": -1}, "--max-steps must be an integer >= 1, got -1"),
        ({"workers": 0}, "--workers must be"),
        ({"batch": 0}, "--batch must be an integer >= 1, got 0"),
        ({"videos": -1}, "--videos must be"),
        ({"seed_start": -5}, "--seed-start must be"),
        ({"tasks": ()}, "--tasks is empty"),
        ({"conditions": ("clean", "clean")}, "--conditions lists 'clean' more than once"),
        ({"conditions": ("clean", "fog:0.5")}, "--conditions: 'fog:0.5': unknown perturbation 'fog'"),
        ({"conditions": ("dim:1.5",)}, "--conditions: 'dim:1.5': severity must be in"),
        ({"env": "gazebo"}, "--env: unknown simulator 'gazebo'"),
    ],
)
def test_a_bad_evaluation_setting_is_refused_when_the_config_is_built(changes, message):
    with pytest.raises(UsageError) as refused:
        EvalConfig(**changes)
    assert message in str(refused.value)


def test_checkpoints_that_are_not_saved_policies_are_refused_by_option(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(UsageError, match="--checkpoints: checkpoint '.*none' \\(none\\) does not exist"):
        parse_checkpoints((str(tmp_path / "none"),))
    with pytest.raises(UsageError, match="--checkpoints: '.*empty' \\(empty\\) is not a saved policy folder"):
        parse_checkpoints((str(tmp_path / "empty"),))
    with pytest.raises(UsageError, match="no checkpoints to evaluate"):
        parse_checkpoints(())
