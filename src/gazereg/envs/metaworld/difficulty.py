"""Meta-World's difficulty groups as LeRobot names them (`lerobot-eval --env.task=easy`), and a task draw
from them that is fixed before any result is seen.

    draw_tasks({"easy": 4, "medium": 2, "hard": 2}, exclude=("reach-v3",), seed=0)

The groups are LeRobot 0.6.1's `DIFFICULTY_TO_TASKS` (lerobot/envs/metaworld_config.json; the LeRobot lane's
tests_lerobot/test_metaworld_groups.py checks this copy against it): 28 easy, 11 medium, 6 hard and 5 very hard v3 tasks.
"""

from __future__ import annotations

import random
from collections.abc import Iterable, Mapping

DIFFICULTY: dict[str, tuple[str, ...]] = {
    "easy": (
        "button-press-v3",
        "button-press-topdown-v3",
        "button-press-topdown-wall-v3",
        "button-press-wall-v3",
        "coffee-button-v3",
        "dial-turn-v3",
        "door-close-v3",
        "door-lock-v3",
        "door-open-v3",
        "door-unlock-v3",
        "drawer-close-v3",
        "drawer-open-v3",
        "faucet-close-v3",
        "faucet-open-v3",
        "handle-press-v3",
        "handle-press-side-v3",
        "handle-pull-v3",
        "handle-pull-side-v3",
        "lever-pull-v3",
        "plate-slide-v3",
        "plate-slide-back-v3",
        "plate-slide-back-side-v3",
        "plate-slide-side-v3",
        "reach-v3",
        "reach-wall-v3",
        "window-close-v3",
        "window-open-v3",
        "peg-unplug-side-v3",
    ),
    "medium": (
        "basketball-v3",
        "bin-picking-v3",
        "box-close-v3",
        "coffee-pull-v3",
        "coffee-push-v3",
        "hammer-v3",
        "peg-insert-side-v3",
        "push-wall-v3",
        "soccer-v3",
        "sweep-v3",
        "sweep-into-v3",
    ),
    "hard": (
        "assembly-v3",
        "hand-insert-v3",
        "pick-out-of-hole-v3",
        "pick-place-v3",
        "push-v3",
        "push-back-v3",
    ),
    "very_hard": (
        "shelf-place-v3",
        "disassemble-v3",
        "stick-pull-v3",
        "stick-push-v3",
        "pick-place-wall-v3",
    ),
}


def difficulty_of(task: str) -> str:
    """The difficulty group of a Meta-World v3 task; KeyError naming the task if it is in none."""
    for group, tasks in DIFFICULTY.items():
        if task in tasks:
            return group
    raise KeyError(f"{task!r} is in no Meta-World difficulty group ({', '.join(DIFFICULTY)})")


def draw_tasks(counts: Mapping[str, int], exclude: Iterable[str] = (), seed: int = 0) -> tuple[str, ...]:
    """`counts[group]` tasks drawn without replacement from each group (in the order of `counts`), leaving out
    `exclude`: one `random.Random(seed)` samples each group's sorted remaining tasks in turn, so the draw
    depends on nothing but these arguments."""
    rng, skip, drawn = random.Random(seed), set(exclude), []
    for group, k in counts.items():
        if group not in DIFFICULTY:
            raise KeyError(f"unknown difficulty group {group!r}; choose from {', '.join(DIFFICULTY)}")
        pool = sorted(set(DIFFICULTY[group]) - skip)
        if not 0 <= k <= len(pool):
            raise ValueError(f"cannot draw {k} of the {len(pool)} {group} tasks left")
        drawn.extend(rng.sample(pool, k))
    return tuple(drawn)
