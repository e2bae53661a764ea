"""The environments one worker process keeps open between jobs, the least recently used closed beyond a limit.

    envs = EnvCache(lambda task: MetaWorldEnv(task), size=4)
    env = envs.get("reach-v3")          # made once, reused while it stays among the `size` most recent
    envs.close()

A LIBERO environment holds about 1.2 GB (its scene's textures, the physics and the render copy; measured with
one 128 px camera), and closing one returns only part of it to the system, though the next one reuses it: a
worker that opened one environment per task and condition of LIBERO-Spatial (30) would need tens of GB, one
that keeps `WORKER_ENVS` stays near 5 GB. Meta-World's are small; the limit costs them nothing when jobs come
task by task.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

from gazereg.envs.interface import Env

WORKER_ENVS = 4
"""environments one worker process keeps open"""

K = TypeVar("K", bound=Hashable)


class EnvCache(Generic[K]):
    """Environments by key, made by `make(key)` on first use; beyond `size` the least recently used is closed."""

    def __init__(self, make: Callable[[K], Env], size: int = WORKER_ENVS):
        if size < 1:
            raise ValueError(f"an environment cache holds at least 1 environment, got size {size}")
        self.make, self.size = make, size
        self._envs: OrderedDict[K, Env] = OrderedDict()

    def get(self, key: K) -> Env:
        if key in self._envs:
            self._envs.move_to_end(key)
            return self._envs[key]
        while len(self._envs) >= self.size:
            _, oldest = self._envs.popitem(last=False)
            oldest.close()
        env = self._envs[key] = self.make(key)
        return env

    def __len__(self) -> int:
        return len(self._envs)

    def __contains__(self, key: object) -> bool:
        return key in self._envs

    def close(self) -> None:
        while self._envs:
            self._envs.popitem(last=False)[1].close()
