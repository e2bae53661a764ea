"""Shared fixtures for the simulation tests: the OpenGL backend (chosen by the env module's own selection
logic, passed explicitly) and a few module-scoped environments (building one takes about a second); and the
`libero` mark: a test so marked is skipped where the LIBERO extra is missing, the reason naming the module
missing (`libero_available`) and the command that runs its file in the LIBERO venv."""

from __future__ import annotations

import pytest

from gazereg.envs.libero.setup import libero_available


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    available, why = libero_available()
    if available:
        return
    for item in items:
        if item.get_closest_marker("libero") is not None:
            path = item.path.relative_to(config.rootpath).as_posix()
            reason = f"{why}, then: bash scripts/libero_env.sh pytest -m slow {path}"
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture(scope="session")
def gl_backend() -> str:
    pytest.importorskip("metaworld")
    from gazereg.envs.render import select_gl_backend

    return select_gl_backend()
