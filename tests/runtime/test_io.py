import os
import subprocess
import sys

import pytest

from gazereg.runtime.io import atomic_dir, atomic_path, atomic_write_text, current_umask, sweep_stale_temps


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_files_and_folders_honour_the_umask(tmp_path, umask_022):
    atomic_write_text(tmp_path / "a.json", "{}")
    with atomic_dir(tmp_path / "ckpt") as d:
        (d / "x").write_text("1")
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "ckpt").stat().st_mode & 0o777 == 0o755
    os.umask(0o077)
    atomic_write_text(tmp_path / "b.json", "{}")
    assert (tmp_path / "b.json").stat().st_mode & 0o777 == 0o600
    assert current_umask() == 0o077


def test_a_killed_writer_leaves_a_temporary_that_the_next_run_sweeps(tmp_path):
    code = (
        "import os, sys\n"
        "from gazereg.runtime.io import atomic_path, atomic_dir\n"
        "p = atomic_path(sys.argv[1] + '/a.json'); t = p.__enter__(); t.write_text('half')\n"
        "d = atomic_dir(sys.argv[1] + '/step_000010'); d.__enter__()\n"
        "os._exit(0)\n"  # dies inside both writes: no cleanup runs
    )
    subprocess.run([sys.executable, "-c", code, str(tmp_path)], check=True)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert len(left) == 2 and all(n.endswith(".tmp") for n in left), left
    with atomic_path(tmp_path / "live.json") as live:  # this process's own temporary is kept
        live.write_text("x")
        removed = sweep_stale_temps(tmp_path)
        assert live.exists()
    assert sorted(p.name for p in removed) == left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.json"]


def test_a_compressed_copy_reads_as_the_file_and_is_the_same_bytes_for_the_same_text(tmp_path):
    from gazereg.runtime.io import gz_path, read_text, write_gz_copy
    from gazereg.training.logger import read_metrics

    src = tmp_path / "metrics.jsonl"
    src.write_text('{"step": 1, "loss": 0.5}\n{"step": 2, "loss": 0.25}\n')
    kept = tmp_path / "kept" / "metrics.jsonl"
    write_gz_copy(src, gz_path(kept))
    first = gz_path(kept).read_bytes()
    write_gz_copy(src, gz_path(kept))
    assert gz_path(kept).read_bytes() == first and not kept.exists()
    assert read_text(kept) == src.read_text()
    assert [r["step"] for r in read_metrics(kept)] == [1, 2]
    assert read_metrics(tmp_path / "none.jsonl") == []
    with pytest.raises(FileNotFoundError, match=r"none\.json \(or none\.json\.gz\) does not exist"):
        read_text(tmp_path / "none.json")
