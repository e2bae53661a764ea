"""Shared fixtures for the simulation tests: the OpenGL backend (chosen by the env module's own selection
logic, passed explicitly) and a few module-scoped environments (building one takes about a second)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def gl_backend() -> str:
    pytest.importorskip("metaworld")
    from gazereg.envs.render import select_gl_backend

    return select_gl_backend()
