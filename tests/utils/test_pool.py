"""The worker pool (in-process and spawned), the resume log and the fingerprints."""

from __future__ import annotations

import functools
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gazereg.runtime.pool import ResumeLog, WorkerPool, fingerprint_files, fingerprint_json


class CountingWorker:
    """Tells which process and which worker object ran a job, and how many jobs that object ran before."""

    built = 0  # in this process

    def __init__(self, offset: int = 0):
        CountingWorker.built += 1
        self.offset, self.jobs, self.closed = offset, 0, False

    def run(self, job: int) -> dict:
        if job < 0:
            raise ValueError(f"bad job {job}")
        self.jobs += 1
        return {"value": job + self.offset, "pid": os.getpid(), "worker": id(self), "before": self.jobs - 1}

    def close(self) -> None:
        self.closed = True


def test_in_process_pool_builds_one_worker_and_runs_in_submission_order():
    CountingWorker.built = 0
    seen = []
    with WorkerPool(functools.partial(CountingWorker, 100), workers=1) as pool:
        assert CountingWorker.built == 1  # built when the pool opens, before any job
        worker = pool._local
        for job in (3, 1, 2):
            pool.submit(job, tag=f"t{job}")
        for tag, result in pool.results():
            seen.append((tag, result["value"]))
            if tag == "t3":
                pool.submit(7, tag="t7")  # submitted while iterating: run after the others
            assert result["pid"] == os.getpid()
    assert seen == [("t3", 103), ("t1", 101), ("t2", 102), ("t7", 107)]
    assert CountingWorker.built == 1 and worker.closed and worker.jobs == 4


def test_in_process_pool_raises_a_jobs_error():
    with pytest.raises(ValueError, match="bad job -1"), WorkerPool(CountingWorker, workers=0) as pool:
        pool.submit(-1, tag=0)
        list(pool.results())


@pytest.mark.slow
def test_spawned_pool_reuses_one_worker_per_process():
    with WorkerPool(functools.partial(CountingWorker, 10), workers=2) as pool:
        for job in range(6):
            pool.submit(job, tag=job)
        results = dict(pool.results())
        pool.submit(-1, tag="bad")
        with pytest.raises(ValueError, match="bad job -1"):
            list(pool.results())
    assert {tag: r["value"] for tag, r in results.items()} == {j: j + 10 for j in range(6)}
    assert all(r["pid"] != os.getpid() for r in results.values())
    for pid in {r["pid"] for r in results.values()}:
        mine = [r for r in results.values() if r["pid"] == pid]
        assert len({r["worker"] for r in mine}) == 1  # one worker object per process, kept across jobs
        assert sorted(r["before"] for r in mine) == list(range(len(mine)))


def test_submit_outside_the_pool_is_refused():
    with pytest.raises(RuntimeError, match="outside its `with` block"):
        WorkerPool(CountingWorker, workers=1).submit(1, tag=1)


def test_resume_log_maps_keys_to_their_latest_record_and_skips_a_cut_line(tmp_path):
    log = ResumeLog(tmp_path / "sub" / "log.jsonl")
    assert log.read() == {}
    log.append("a", {"n": 1})
    log.append("b", [1, 2])
    log.append("a", {"n": 2})
    with log.path.open("a") as f:
        f.write('{"task": "reach-v3", "seed": 3}\n')  # not an entry (an older log's line): skipped
        f.write('{"key": "c", "rec')  # a kill cut the last line short
    assert log.read() == {"a": {"n": 2}, "b": [1, 2]}
    lines = log.path.read_text().splitlines()
    assert json.loads(lines[0]) == {"key": "a", "record": {"n": 1}}


def test_fingerprints(tmp_path):
    assert fingerprint_json({"a": 1, "b": [2]}) == fingerprint_json({"b": [2], "a": 1})
    assert fingerprint_json({"a": 1}) != fingerprint_json({"a": 2})
    assert len(fingerprint_json(None)) == 16
    (tmp_path / "model.safetensors").write_bytes(b"weights")
    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "sub").mkdir()  # folders do not count
    first = fingerprint_files(tmp_path)
    # The formula episode logs and stores written before the pool existed carry.
    stats = [
        (f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in sorted(tmp_path.iterdir()) if f.is_file()
    ]
    assert first == hashlib.sha256(json.dumps(stats).encode()).hexdigest()[:16]
    (tmp_path / "model.safetensors").write_bytes(b"other weights")
    assert fingerprint_files(tmp_path) != first


SLEEPING_WORKER = """
import os, sys, time
from pathlib import Path
from gazereg.runtime.pool import WorkerPool

class SleepingWorker:
    def run(self, job):  # its pid into the file `job`, 300 s asleep, then `job`.done
        Path(job).write_text(str(os.getpid()))
        time.sleep(300)
        Path(job + ".done").write_text("")

    def close(self):
        pass
"""

PARENT = (
    SLEEPING_WORKER
    + """
if __name__ == "__main__":
    with WorkerPool(SleepingWorker, workers=2) as pool:
        pool.submit(sys.argv[1], tag=0)
        for _ in pool.results():
            pass
"""
)


def _alive(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie (an orphan's zombie waits for a reaper)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
def test_a_spawned_worker_ends_when_its_parent_is_killed(tmp_path):
    """A killed run must not leave a worker behind in the middle of a job (it would go on writing into the
    run folder that a resumed run shares)."""
    (tmp_path / "parent.py").write_text(PARENT)
    marker = tmp_path / "worker.pid"
    parent = subprocess.Popen([sys.executable, str(tmp_path / "parent.py"), str(marker)], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 120
        while not marker.exists() or not marker.read_text():
            assert time.monotonic() < deadline and parent.poll() is None, "the worker never started its job"
            time.sleep(0.1)
        worker = int(marker.read_text())
        assert _alive(worker)
        parent.send_signal(signal.SIGKILL)  # no clean-up in the parent: only the worker's own watch can act
        parent.wait(timeout=30)
        deadline = time.monotonic() + 30
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker), f"worker {worker} outlived its killed parent"
    finally:
        parent.kill()
        if marker.exists() and marker.read_text() and _alive(int(marker.read_text())):
            os.kill(int(marker.read_text()), signal.SIGKILL)  # the failure's orphan


LEAVING_ON_AN_ERROR = (
    SLEEPING_WORKER
    + """
if __name__ == "__main__":
    with WorkerPool(SleepingWorker, workers=2) as pool:
        pool.submit(sys.argv[1], tag=0)
        while not Path(sys.argv[1]).exists() or not Path(sys.argv[1]).read_text():
            time.sleep(0.05)
        raise SystemExit(3)  # as Ctrl-C or SIGTERM would, while the job runs
"""
)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
def test_leaving_the_pool_on_an_error_ends_the_job_in_flight(tmp_path):
    """Ctrl-C or SIGTERM in the train stage must stop the run, not wait for a training job of hours to end."""
    (tmp_path / "parent.py").write_text(LEAVING_ON_AN_ERROR)
    marker = tmp_path / "worker.pid"
    parent = subprocess.Popen([sys.executable, str(tmp_path / "parent.py"), str(marker)], cwd=tmp_path)
    try:
        assert parent.wait(timeout=240) == 3  # the job alone would sleep 300 s
        worker = int(marker.read_text())
        assert not _alive(worker), f"worker {worker} ran on after the pool was left"
        assert not (tmp_path / "worker.pid.done").exists()
    finally:
        parent.kill()
        if marker.exists() and marker.read_text() and _alive(int(marker.read_text())):
            os.kill(int(marker.read_text()), signal.SIGKILL)
