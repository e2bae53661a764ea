"""Atomic file writes: write to a temporary name in the same folder, then rename.

A reader never sees a half-written file, and a killed job leaves either the old file or the new one (and a
temporary `.NAME.PID.XXXX.tmp` that `sweep_stale_temps` removes once process PID is gone). Files and folders
are created with the permissions an ordinary write would give them (0666 / 0777 less the umask), not the
0600 / 0700 of Python's secure temporaries, so a store or checkpoint can be shared. `read_text` also reads the
compressed copies (NAME.gz, `write_gz_copy`) an archived run folder keeps.
"""

from __future__ import annotations

import gzip
import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

TEMP_NAME = re.compile(r"^\.(?P<name>.+?)\.(?P<pid>\d+)\.[a-z0-9_]+\.tmp$")
"""a temporary of this module: `.NAME.PID.XXXXXXXX.tmp` (PID: the writing process)"""


def current_umask() -> int:
    """The process's umask, read without changing it where /proc allows (Linux), else set and restored."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _temp_prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def sweep_stale_temps(folder: str | Path) -> list[Path]:
    """Remove the temporaries that killed writers left anywhere under `folder` (those whose process is no
    longer running); returns what was removed. Called at the start of the command that owns the folder."""
    removed: list[Path] = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for tmp in sorted(folder.rglob(".*.tmp")):
        m = TEMP_NAME.match(tmp.name)
        if m is None or _alive(int(m["pid"])):
            continue
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        removed.append(tmp)
    return removed


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it is renamed onto `path`, on error removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path), suffix=".tmp", dir=path.parent)
    os.fchmod(fd, 0o666 & ~current_umask())
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside `path`; on success it replaces `path` whole, on error it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(path), suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~current_umask())
    try:
        yield tmp
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def atomic_write_json(path: str | Path, obj: Any) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def append_jsonl(path: str | Path, record: dict[str, Any]) -> None:
    """Append one JSON line (flushed and fsynced, so a killed job keeps every finished line)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(record, sort_keys=True) + "\n")
        f.flush()
        os.fsync(f.fileno())


def gz_path(path: str | Path) -> Path:
    """`path`'s gzip-compressed copy: NAME.gz beside it."""
    path = Path(path)
    return path.with_name(path.name + ".gz")


def read_text(path: str | Path) -> str:
    """The text of `path`, or of its compressed copy `gz_path(path)` when only that exists (an archived run
    folder's, `gazereg.experiment.archive`); FileNotFoundError naming both when neither does."""
    path = Path(path)
    if path.exists() or not gz_path(path).exists():
        try:
            return path.read_text()
        except FileNotFoundError:
            raise FileNotFoundError(f"{path} (or {gz_path(path).name}) does not exist") from None
    with gzip.open(gz_path(path), "rt") as f:
        return f.read()


def exists_or_gz(path: str | Path) -> bool:
    """`path` or its compressed copy exists (see `read_text`)."""
    return Path(path).exists() or gz_path(path).exists()


def write_gz_copy(src: str | Path, dst: str | Path) -> None:
    """Write `src` compressed to `dst` (atomically; `mtime=0` so the same text gives the same bytes)."""
    with (
        atomic_path(dst) as tmp,
        open(src, "rb") as f,
        open(tmp, "wb") as raw,
        gzip.GzipFile(filename="", fileobj=raw, mode="wb", mtime=0) as out,
    ):
        shutil.copyfileobj(f, out)
