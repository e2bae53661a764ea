"""A killed evaluation resumes from its episode log; a rewritten checkpoint is evaluated afresh."""

import pytest

import gazereg.evaluation.rollout as ev
from gazereg.evaluation.config import EvalConfig, presets


class FakeWorker:
    """Records the jobs it runs; a job whose seed is in `fail_on` is killed."""

    def __init__(self, calls, fail_on):
        self.calls, self.fail_on = calls, fail_on

    def run(self, job):
        if job.seed in self.fail_on:
            raise KeyboardInterrupt("killed")
        self.calls.append((job.arm, job.seed))
        return {
            "arm": job.arm,
            "task": job.task,
            "condition": job.condition,
            "seed": job.seed,
            "success": job.seed % 2 == 0,
            "length": 7,
        }

    def close(self):
        pass


@pytest.fixture
def fake_rollouts():
    calls: list[tuple[str, int]] = []
    fail_on: set[int] = set()
    return calls, fail_on, lambda: FakeWorker(calls, fail_on)


def _run(jobs, max_steps, log_path, make_worker):
    cfg = EvalConfig(max_steps=max_steps, workers=1)
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

    cfg = replace(presets()["libero"](), out=tmp_path, videos=1)
    assert cfg.env == "libero" and len(cfg.tasks) == 10
    assert all((cfg.seed_start + i) % 50 >= 25 for i in range(cfg.episodes))  # initial states 25..49
    jobs = ev.make_jobs(cfg, {"gaze": tmp_path / "ckpt"})
    videos = [j.video for j in jobs if j.video]
    assert len(videos) == 10 and all(v.startswith(str(tmp_path / "videos") + "/") for v in videos)
    assert all("/" not in v.rsplit("videos/", 1)[1] for v in videos)
