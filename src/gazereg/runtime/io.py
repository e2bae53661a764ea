"""Atomic file writes: write to a temporary name in the same folder, then rename.

A reader never sees a half-written file, and a killed job leaves either the old file or the new one (and a
temporary `.NAME.PID.XXXX.tmp` that `sweep_stale_temps` removes once process PID is gone). Files and folders
are created with the permissions an ordinary write would give them (0666 / 0777 less the umask), not the
0600 / 0700 of Python's secure temporaries, so a store or checkpoint can be shared. `read_text` also reads the
compressed copies (NAME.gz, `write_gz_copy`) an archived run folder keeps.

Safetensors files go through `save_safetensors` / `load_safetensors`: equal tensors and metadata give equal
bytes (the header's keys sorted; the safetensors library itself writes its metadata in hash order and its
files with mode 0600), the file gets the umask's mode, and a file that cannot be read raises `DamagedFile`
naming it. `disk_full` tells a full disk from other write errors. `file_lock` is an advisory lock (flock)
whose holder's process id is written into the lock file, so the refused process can name it.
"""

from __future__ import annotations

import errno
import fcntl
import gzip
import json
import os
import re
import shutil
import struct
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from gazereg.runtime.errors import UsageError

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


# ----- safetensors ----------------------------------------------------------------------------------------
class DamagedFile(UsageError):
    """A file that exists but cannot be read as what it should be (truncated, corrupted); the message names
    the file, what is wrong and what to do."""


def _canonical_header(path: Path) -> None:
    """Rewrite a safetensors file's JSON header in place with its keys sorted (the same length, padded with
    spaces as the format allows), so equal contents give equal bytes; the tensor data is not touched."""
    with open(path, "r+b") as f:
        (n,) = struct.unpack("<Q", f.read(8))
        header = json.loads(f.read(n))
        text = json.dumps(header, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()
        if len(text) > n:  # cannot happen for a header that only changes order; keep the library's bytes
            return
        f.seek(8)
        f.write(text + b" " * (n - len(text)))


def save_safetensors(
    tensors: Mapping[str, Any], path: str | Path, metadata: Mapping[str, str] | None = None
) -> None:
    """Write `tensors` ({name: contiguous CPU tensor}) and `metadata` to `path` atomically, byte-identical for
    equal tensors and metadata (sorted header keys), with the mode an ordinary write gives (0666 less the
    umask). A full disk raises OSError(ENOSPC) (see `disk_full`)."""
    from safetensors.torch import save_file

    meta = {str(k): str(v) for k, v in sorted((metadata or {}).items())} or None
    with atomic_path(path) as tmp:
        save_file({k: tensors[k] for k in sorted(tensors)}, str(tmp), metadata=meta)
        _canonical_header(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())  # the library's own temporary is 0600


def load_safetensors(
    path: str | Path, device: str = "cpu", advice: str = "re-save or retrain"
) -> dict[str, Any]:
    """The tensors of a safetensors file; `DamagedFile` (one line: the file, what is wrong, `advice`) when it
    cannot be read as one (truncated, not safetensors), FileNotFoundError when it does not exist."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist")
    try:
        return load_file(str(path), device=device)
    except SafetensorError as e:
        what = str(e).replace("Error while deserializing header: ", "safetensors header: ")
        raise DamagedFile(f"{path} is damaged ({what}); {advice}") from e
    except OSError as e:
        raise DamagedFile(f"{path} cannot be read ({e.strerror or e}); {advice}") from e


def disk_full(error: BaseException) -> bool:
    """Whether a write failed because its disk is full: OSError ENOSPC / EDQUOT, or the safetensors library's
    error carrying one (it reports the operating system's error as text)."""
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(error)
    return type(error).__name__ == "SafetensorError" and any(
        s in text for s in ("StorageFull", "code: 28", "No space left", "QuotaExceeded")
    )


# ----- advisory locks -------------------------------------------------------------------------------------
class LockHeld(BlockingIOError):
    """`file_lock` found the lock taken; `holder` is the pid the holder wrote into the lock file (None when it
    wrote none)."""

    def __init__(self, path: Path, holder: int | None):
        super().__init__(errno.EWOULDBLOCK, f"{path} is locked by process {holder or '?'}")
        self.path, self.holder = path, holder


def lock_holder(path: str | Path) -> int | None:
    """The pid recorded in a lock file (None when it is missing or records none)."""
    try:
        text = Path(path).read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


@contextmanager
def file_lock(path: str | Path, shared: bool = False) -> Iterator[None]:
    """Hold an advisory lock (flock, exclusive unless `shared`) on `path` for the block, without waiting:
    `LockHeld` when another process holds a conflicting one. An exclusive holder writes its pid into the file
    and removes the file when done; the lock goes with the process however it ends (a kill included)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666 & ~current_umask())
        try:
            fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise LockHeld(path, lock_holder(path)) from None
        try:  # the file may have been removed (and another made) by a holder that finished meanwhile
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        if not shared:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        try:  # the last holder removes the file (a shared holder only when no other holds it)
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            path.unlink(missing_ok=True)
        except BlockingIOError:
            pass
        finally:
            os.close(fd)
