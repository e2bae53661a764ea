"""A failed import leaves nothing it created, a frame_index gap is named where it is, and a store says once
what it skips (issue 33, items 7 and 8)."""

import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
pytest.importorskip("av")

from gazereg.cli import main as gazereg_main  # noqa: E402
from gazereg.data.errors import DataImportError  # noqa: E402
from gazereg.data.formats.lerobot_v3 import LeRobotImportConfig, import_lerobot  # noqa: E402
from gazereg.data.store import Episode, EpisodeStore  # noqa: E402
from gazereg.gaze.priors import PriorsConfig, make_priors  # noqa: E402

FIXTURE = Path(os.environ.get("GAZEREG_FIXTURES", "/work/shared/fixtures")) / "lerobot_v3_tiny"
if not FIXTURE.exists():
    FIXTURE = Path(__file__).resolve().parents[3] / "shared" / "fixtures" / "lerobot_v3_tiny"
DATA = "data/chunk-000/file-000.parquet"
LENGTHS = (20, 22, 24)  # the fixture's episodes


@pytest.fixture
def copy(tmp_path):
    if not FIXTURE.exists():
        pytest.skip("LeRobot v3 fixture not available")
    dst = tmp_path / "ds"
    shutil.copytree(FIXTURE, dst, copy_function=shutil.copyfile)
    for d, _, _ in os.walk(dst):
        os.chmod(d, 0o755)
    return dst


def set_frame_index(root: Path, episode: int, row: int, value: int) -> None:
    """Give the `row`-th frame of `episode` in the data file another frame_index."""
    t = pq.read_table(root / DATA)
    ep, fi = t.column("episode_index").to_numpy(), t.column("frame_index").to_numpy().copy()
    fi[np.flatnonzero(ep == episode)[row]] = value
    pos = t.schema.get_field_index("frame_index")
    pq.write_table(t.set_column(pos, "frame_index", pa.array(fi, pa.int64())), root / DATA)


def cfg(root, out, **kw):
    return LeRobotImportConfig(root=Path(root), out=Path(out), progress=False, **kw)


# ----- item 7 -------------------------------------------------------------------------------------------------
def test_a_failed_first_import_leaves_no_store_at_out(copy, tmp_path, capsys):
    p = copy / DATA
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    out = tmp_path / "s"
    assert gazereg_main(["import", "lerobot", "--root", str(copy), "--out", str(out), "--no-progress"]) == 1
    assert "could not be read" in capsys.readouterr().err
    assert not out.exists()
    out.mkdir()  # a folder made for it beforehand stays, empty
    with pytest.raises(DataImportError):
        import_lerobot(cfg(copy, out))
    assert out.is_dir() and list(out.iterdir()) == []


def test_a_frame_index_gap_names_the_episode_and_where_it_breaks(copy, tmp_path):
    set_frame_index(copy, episode=1, row=7, value=8)  # frames 0..6, 8, 8, 9, ...: 7 is missing
    with pytest.raises(DataImportError) as e:
        import_lerobot(cfg(copy, tmp_path / "s", episodes=(1,)))
    assert str(e.value) == (
        f"{copy / DATA}, episode 1: frame_index must run 0..21 but breaks after 6: expected 7, got 8 "
        "(a missing or repeated frame)"
    )
    set_frame_index(copy, episode=1, row=0, value=3)  # no frame 0
    with pytest.raises(DataImportError, match=r"episode 1: frame_index must run 0\.\.21 but starts at 1$"):
        import_lerobot(cfg(copy, tmp_path / "s", episodes=(1,)))


def test_a_failed_import_keeps_the_episodes_it_wrote_and_says_so(copy, tmp_path, caplog):
    set_frame_index(copy, episode=2, row=3, value=2)
    out = tmp_path / "s"
    with caplog.at_level(logging.WARNING), pytest.raises(DataImportError, match="episode 2: frame_index"):
        import_lerobot(cfg(copy, out))
    assert EpisodeStore(out).indices() == [0, 1]
    assert f"the 2 episode(s) imported before the error are kept in {out}; rerun the import" in caplog.text


# ----- item 8 -------------------------------------------------------------------------------------------------
def small_store(root, n):
    store = EpisodeStore(root, create=True)
    for k in range(n):
        frames = {"cam": np.full((3, 8, 8, 3), k, np.uint8)}
        store.write(Episode("t", "go", frames, np.zeros((3, 2), np.float32), np.zeros((3, 2), np.float32)))
    return store


def warnings_of(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_episode_folders_without_meta_are_warned_about_once(tmp_path, caplog):
    store = small_store(tmp_path / "s", 9)
    for i in (1, 2, 3, 4, 5, 7, 8):
        (store.root / "episodes" / f"ep_{i:06d}" / "meta.json").unlink()
    with caplog.at_level(logging.WARNING):
        assert store.indices() == [0, 6]
        assert EpisodeStore(store.root).indices() == [0, 6] and len(EpisodeStore(store.root)) == 2
    assert warnings_of(caplog) == [
        f"store {store.root}: 7 episode folder(s) have no meta.json and are skipped (ep_000001, ep_000002, "
        "ep_000003, ep_000004, ep_000005, ... (2 more)): a damaged or partial copy; delete them or copy them again"
    ]


def test_a_deleted_episode_a_prior_was_made_for_is_warned_about_once(tmp_path, caplog):
    store = small_store(tmp_path / "s", 3)
    make_priors(PriorsConfig(store=store.root, source="uniform", camera="cam", size=(4, 4)), progress=False)
    shutil.rmtree(store.root / "episodes" / "ep_000001")
    with caplog.at_level(logging.WARNING):
        for _ in range(3):
            EpisodeStore(store.root).prior_info("uniform")
    assert warnings_of(caplog) == [
        f"store {store.root}: 1 episode(s) that priors 'uniform' were made for are gone (ep_000001); they are "
        "skipped"
    ]
