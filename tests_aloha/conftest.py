"""The Gym-Aloha lane's tests (scripts/aloha_lane.sh runs them in its venv with MUJOCO_GL=egl). Every test here
needs gym-aloha; where it is missing the whole folder is skipped with the reason."""

from __future__ import annotations

import pytest

from gazereg.envs.aloha.setup import aloha_available


def pytest_collection_modifyitems(config, items):
    ok, why = aloha_available()
    if not ok:
        skip = pytest.mark.skip(reason=why)
        for item in items:
            item.add_marker(skip)
