"""LeRobot v3 import: NaN/inf in an extra feature is refused with its row; a truncated video says so."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("av")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from gazereg.data.errors import DataImportError  # noqa: E402
from gazereg.data.formats.lerobot_v3 import LeRobotImportConfig, import_lerobot  # noqa: E402
from gazereg.data.formats.video import iso_truncation  # noqa: E402
from gazereg.data.store import EpisodeStore  # noqa: E402

FIXTURE = (
    Path(os.environ.get("GAZEREG_FIXTURES", Path(__file__).resolve().parents[3] / "shared" / "fixtures"))
    / "lerobot_v3_tiny"
)
if not FIXTURE.exists():
    FIXTURE = Path("/work/shared/fixtures/lerobot_v3_tiny")
pytestmark = pytest.mark.skipif(not FIXTURE.exists(), reason="LeRobot v3 fixture not available")

DATA = "data/chunk-000/file-000.parquet"
VIDEO = "videos/observation.images.front/chunk-000/file-000.mp4"


@pytest.fixture
def copy(tmp_path):
    dst = tmp_path / "ds"
    shutil.copytree(FIXTURE, dst, copy_function=shutil.copyfile)
    for d, _, _ in os.walk(dst):
        os.chmod(d, 0o755)
    return dst


def cfg(root, out, **kw):
    return LeRobotImportConfig(root=Path(root), out=Path(out), progress=False, **kw)


def test_non_finite_extra_feature_is_refused_with_its_row(copy, tmp_path):
    t = pq.read_table(copy / DATA)
    effort = np.zeros(t.num_rows, np.float32)
    rows = np.flatnonzero(t.column("episode_index").to_numpy() == 1)
    effort[rows[3]] = np.nan  # episode 1, frame 3
    pq.write_table(t.append_column("observation.effort", pa.array(effort)), copy / DATA)
    info = json.loads((copy / "meta/info.json").read_text())
    info["features"]["observation.effort"] = {"dtype": "float32", "shape": [1], "names": None}
    (copy / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(
        DataImportError,
        match=r"episode 1: column 'observation.effort' has 1 NaN/inf value\(s\), the first at row 3 \(nan\)",
    ):
        import_lerobot(cfg(copy, tmp_path / "s"))
    import_lerobot(cfg(copy, tmp_path / "s", nonfinite_ok=("observation.effort",)))
    assert np.isnan(EpisodeStore(tmp_path / "s").read(1).extras["observation.effort"][3])


@pytest.mark.parametrize("keep", [0.1, 0.6])
def test_a_truncated_video_is_named_truncated(copy, tmp_path, keep):
    video = copy / VIDEO
    assert iso_truncation(video) is None  # the intact file
    data = video.read_bytes()
    video.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(
        DataImportError, match=r"episode 0, camera 'front': video file .*file-000\.mp4 is truncated: its"
    ):
        import_lerobot(cfg(copy, tmp_path / "s"))
    assert not (tmp_path / "s").exists()  # a first import that wrote no episode leaves no store
