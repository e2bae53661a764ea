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
