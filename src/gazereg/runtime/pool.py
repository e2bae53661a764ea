"""What long simulation jobs share: one worker pool, one resume log, one fingerprint.

    with WorkerPool(functools.partial(RolloutWorker, 150, None, "metaworld", 8), workers=4) as pool:
        for i, group in enumerate(groups):            # a RolloutWorker job: episodes run in lockstep
            pool.submit(group, tag=i)
        for tag, result in pool.results():        # as jobs finish; more may be submitted meanwhile
            log.append(keys[tag], result)

    log = ResumeLog(out / "episodes.jsonl")
    done = log.read()                             # key -> record of every finished job
    fingerprint_files("runs/a/final")             # 16 hex digits: names, sizes, mtimes of a folder's files
    fingerprint_json({"image_size": 96})          # 16 hex digits: a JSON-able value

Pool. `workers` > 1 runs jobs in that many spawned processes (fresh interpreters: MuJoCo, OpenGL and torch
threads are not fork-safe). Each process builds its worker object once, `make_worker()` (a picklable
callable: a class or a `functools.partial` of one), and runs every job it gets with `worker.run(job)`, so
what a worker loads (policies, simulators) is reused across jobs. `workers` <= 1 builds the worker in this
process, when the pool opens, and runs the jobs there in the order they were submitted. Results come back
to the parent as jobs finish (submission order in-process); an exception raised by a job is raised from
`results()`, and leaving the pool on an error (a job's, Ctrl-C, SIGTERM) cancels the jobs not yet started
and ends the spawned workers, the jobs in flight with them (their writes are atomic: a resumed run redoes
them), rather than waiting for those to finish. A spawned worker ends
itself when its parent dies (`exit_with_parent`), so a killed run leaves no worker behind. Progress: the
parent reports jobs done as results come back; a progress bar made inside a worker process
(`gazereg.runtime.progress`, e.g. a training run of the experiment's train stage) writes whole lines every
tenth of its work instead of redrawing one, so workers sharing a terminal do not overwrite each other.

Resume log. An append-only JSON-lines file, one `{"key": str, "record": ...}` per finished job, flushed
and fsynced per line, so a killed job keeps every finished line; `read` maps each key to its latest record
and ignores (with a warning) a line a kill cut short and any line that is not such an entry (such a job
runs again).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from multiprocessing import get_context
from pathlib import Path
from types import TracebackType
from typing import Any, Generic, Protocol, TypeVar

from gazereg.runtime.io import append_jsonl

log = logging.getLogger(__name__)

JobT = TypeVar("JobT")
ResultT = TypeVar("ResultT")
JobT_contra = TypeVar("JobT_contra", contravariant=True)
ResultT_co = TypeVar("ResultT_co", covariant=True)


class Worker(Protocol[JobT_contra, ResultT_co]):
    """Per-process state (loaded models, open simulators) that runs one job at a time."""

    def run(self, job: JobT_contra) -> ResultT_co: ...

    def close(self) -> None: ...


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells, else the CPU count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# ----- the pool ---------------------------------------------------------------------------------------------
# The worker object of a pool's child process, built once by `_start_worker` (the process's initializer).
_child_worker: Worker[Any, Any] | None = None


def exit_with_parent(poll_s: float = 1.0) -> None:
    """In a spawned worker process: end it (exit status 1, a line on stderr) within `poll_s` seconds of its
    parent's death, by a daemon thread that watches the parent's pid. A killed experiment would otherwise leave
    workers in the middle of a training or rollout job, writing on into a run folder that a resumed run then
    shares with them. Writes are atomic, so an abrupt exit loses only the job in flight."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os.write(2, f"gazereg worker {os.getpid()}: its parent {parent} is gone; exiting\n".encode())
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _start_worker(make_worker: Callable[[], Worker[Any, Any]], environ: Mapping[str, str]) -> None:
    global _child_worker
    exit_with_parent()
    for name, value in environ.items():
        os.environ.setdefault(name, value)
    _child_worker = make_worker()


def _run_in_child(job: Any) -> Any:
    if _child_worker is None:
        raise RuntimeError("a pool job ran in a process whose worker was not built")
    return _child_worker.run(job)


class WorkerPool(Generic[JobT, ResultT]):
    """Jobs run by per-process worker objects (see the module docstring). A context manager.

    make_worker: builds a process's worker (picklable when workers > 1).
    workers: processes; <= 1 runs every job in this process.
    child_environ: environment variables set (unless already set) in each child before its worker is built.
    """

    def __init__(
        self,
        make_worker: Callable[[], Worker[JobT, ResultT]],
        workers: int,
        child_environ: Mapping[str, str] | None = None,
    ):
        self.make_worker = make_worker
        self.workers = int(workers)
        self.child_environ = dict(child_environ or {})
        self._local: Worker[JobT, ResultT] | None = None
        self._queue: deque[tuple[Hashable, JobT]] = deque()
        self._executor: ProcessPoolExecutor | None = None
        self._futures: dict[Future[ResultT], Hashable] = {}

    @property
    def in_process(self) -> bool:
        return self.workers <= 1

    def __enter__(self) -> WorkerPool[JobT, ResultT]:
        if self.in_process:
            self._local = self.make_worker()
        else:
            self._executor = ProcessPoolExecutor(
                self.workers,
                mp_context=get_context("spawn"),
                initializer=_start_worker,
                initargs=(self.make_worker, self.child_environ),
            )
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._executor is not None:
            if exc_type is None:
                self._executor.shutdown(wait=True)
            else:  # an error, Ctrl-C or SIGTERM: end the jobs in flight too (a training job runs for hours)
                processes = list((getattr(self._executor, "_processes", None) or {}).values())
                self._executor.shutdown(wait=False, cancel_futures=True)
                for process in processes:
                    process.terminate()
                for process in processes:
                    process.join(timeout=30)
            self._executor = None
        if self._local is not None:
            self._local.close()
            self._local = None
        self._queue.clear()
        self._futures.clear()

    def submit(self, job: JobT, tag: Hashable) -> None:
        """Queue `job`; `results()` yields its result with `tag`."""
        if self._executor is not None:
            self._futures[self._executor.submit(_run_in_child, job)] = tag
        elif self._local is not None:
            self._queue.append((tag, job))
        else:
            raise RuntimeError("submit to a WorkerPool outside its `with` block")

    @property
    def pending(self) -> int:
        """Jobs submitted whose result has not been yielded yet."""
        return len(self._queue) + len(self._futures)

    def results(self) -> Iterator[tuple[Hashable, ResultT]]:
        """(tag, result) of every submitted job as it finishes, until none is pending; jobs submitted while
        iterating are included."""
        while self._queue:
            tag, job = self._queue.popleft()
            yield tag, self._local.run(job)  # type: ignore[union-attr]
        while self._futures:
            finished, _ = wait(self._futures, return_when=FIRST_COMPLETED)
            for future in finished:
                tag = self._futures.pop(future)
                yield tag, future.result()


# ----- resume log and fingerprints --------------------------------------------------------------------------
class ResumeLog:
    """An append-only JSON-lines log of finished jobs: key -> record (see the module docstring)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def read(self) -> dict[str, Any]:
        """Every logged key with its latest record; {} when there is no log yet."""
        done: dict[str, Any] = {}
        if not self.path.exists():
            return done
        for line in self.path.read_text().splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                log.warning("resume log %s: ignoring an unfinished line", self.path)
                continue
            if not (isinstance(entry, dict) and "key" in entry and "record" in entry):
                log.warning("resume log %s: ignoring a line without key and record", self.path)
                continue
            done[entry["key"]] = entry["record"]
        return done

    def append(self, key: str, record: Any) -> None:
        append_jsonl(self.path, {"key": key, "record": record})


def fingerprint_json(value: Any) -> str:
    """16 hex digits of the SHA-256 of `value` as JSON (keys sorted): equal values, equal fingerprints."""
    return hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()[:16]


def fingerprint_files(folder: str | Path) -> str:
    """Fingerprint of the names, sizes and modification times (ns) of a folder's files (not recursive):
    changes when a file in it is rewritten."""
    files = sorted(f for f in Path(folder).iterdir() if f.is_file())
    return fingerprint_json([(f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files])
