"""Fixtures for the GLC tests: the official reference data in `data/`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

REF_DIR = Path(__file__).parent / "data"  # copies of the shared reference files (see data/README.md)
STATE_DICT_JSON = REF_DIR / "glc_official_state_dict.json"
SYNTHETIC_IO = REF_DIR / "glc_ego4d_synthetic_io.npz"


@pytest.fixture(scope="session")
def official_state_dict() -> dict:
    if not STATE_DICT_JSON.exists():
        pytest.fail(f"reference file {STATE_DICT_JSON} not present")
    return json.loads(STATE_DICT_JSON.read_text())


@pytest.fixture(scope="session")
def synthetic_io() -> dict[str, np.ndarray]:
    if not SYNTHETIC_IO.exists():
        pytest.fail(f"reference file {SYNTHETIC_IO} not present")
    with np.load(SYNTHETIC_IO) as d:
        return {k: d[k] for k in d.files}
