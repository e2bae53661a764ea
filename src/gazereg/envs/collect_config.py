"""What `gazereg collect` runs: its settings, presets, their checks, and what fixes an episode's index.

cfg = resolve(CollectConfig(tasks=("reach-v3",)))   # the simulator's defaults filled in, tasks canonical
validate(cfg)                                         # CollectError naming what is wrong
fingerprint(cfg)                                      # changes with the settings that change an episode
episode_index(slot=1, seed=5, seed_base=0)            # 1005
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from gazereg.envs.base import UnknownSimulator, make_collector
from gazereg.envs.perturbations import parse_perturbation
from gazereg.runtime.pool import fingerprint_json

INDEX_STRIDE = 1000  # episode indices per task slot
MAX_INDEX = 999_999  # the store names episodes with 6 digits
# Settings that change what an episode contains; episodes made with other values are not mixed in one store.
FINGERPRINT_FIELDS = ("cameras", "image_size", "action_noise", "max_steps", "goal_marker_radius")


class CollectError(ValueError):
    """A collection that cannot run as configured (unknown task, a store made with other settings, ...)."""


@dataclass(frozen=True)
class CollectConfig:
    """Expert demonstrations in simulation (Meta-World or LIBERO), written to an episode store."""

    out: Path = Path("runs/quick/demos")
    """The episode store (created if missing)."""
    tasks: tuple[str, ...] = ("reach-v3", "button-press-topdown-v3", "pick-place-v3")
    """Meta-World v3 task names, or LIBERO tasks with --env libero (commas or spaces between them)."""
    episodes: int = 30
    """Successful episodes wanted per task."""
    seed_base: int = 0
    """First setup seed; seeds 0-49 are Meta-World's 50 MT1 setups of benchmark seed 0."""
    max_failures: int = 20
    """Extra seeds tried per task to replace failed rollouts."""
    cameras: tuple[str, ...] = ()
    """Cameras to render; empty = the simulator's default (Meta-World: corner2; LIBERO: agentview_rgb
    eye_in_hand_rgb). Meta-World: corner, corner2, corner3, corner4, topview, behindGripper, gripperPOV."""
    image_size: int = 96
    """Square image side in pixels."""
    action_noise: float = 0.0
    """Std of Gaussian noise added to the expert's actions (action units; actions are clipped to [-1, 1])."""
    max_steps: int = 0
    """A rollout that has not succeeded after this many steps is a failure; 0 = the simulator's default
    (Meta-World 200, LIBERO 220, the LIBERO-Spatial evaluation length)."""
    goal_marker_radius: float = 0.03
    """Radius (m) of the rendered goal sphere (rendering only); 0 keeps Meta-World's own marker."""
    perturbation: str = ""
    """Meta-World: render under this perturbation (gazereg.envs.perturbations spec, e.g. dim:0.7): the same
    setups and expert actions, seen under other light or with sensor noise; empty = clean."""
    workers: int = 0
    """Worker processes; 0 = one per available core."""
    gl_backend: str = ""
    """OpenGL backend (egl, osmesa); empty = MUJOCO_GL if set, else egl, else osmesa."""
    progress: bool = True
    """Show a progress bar."""
    env: Literal["metaworld", "libero"] = "metaworld"
    """Simulator: metaworld, or libero (needs the LIBERO venv: bash scripts/libero_env.sh gazereg collect ...)."""


PRESETS = {
    "quick": lambda: CollectConfig(),
    "smoke": lambda: CollectConfig(
        out=Path("runs/smoke/demos"),
        tasks=("reach-v3", "pick-place-v3"),
        episodes=2,
        max_failures=4,
        image_size=64,
        max_steps=150,
    ),
    "paper": lambda: CollectConfig(
        out=Path("runs/paper/demos"),
        tasks=(
            "reach-v3",
            "push-v3",
            "pick-place-v3",
            "door-open-v3",
            "drawer-open-v3",
            "drawer-close-v3",
            "button-press-topdown-v3",
            "peg-insert-side-v3",
            "window-open-v3",
            "window-close-v3",
        ),
        episodes=50,
        max_failures=50,
        cameras=("corner2", "corner3"),
        image_size=128,
        max_steps=300,
    ),
}


def fingerprint(cfg: CollectConfig) -> str:
    """Hash of the settings that change what an episode contains (of a resolved config)."""
    d: dict[str, object] = {k: getattr(cfg, k) for k in FINGERPRINT_FIELDS}
    d["cameras"] = list(cfg.cameras)
    if cfg.env != "metaworld":  # Meta-World stores made before there was a choice keep their fingerprint
        d["env"] = cfg.env
    if cfg.perturbation:  # likewise clean stores
        d["perturbation"] = cfg.perturbation
    return fingerprint_json(d)


def episode_index(slot: int, seed: int, seed_base: int) -> int:
    """The store index of the episode of the task in position `slot` on setup `seed`."""
    return slot * INDEX_STRIDE + (seed - seed_base)


def resolve(cfg: CollectConfig) -> CollectConfig:
    """Fill the simulator's defaults (cameras, max_steps) and canonical task names; CollectError if invalid."""
    try:
        sim = make_collector(cfg.env)
        tasks = sim.tasks(cfg.tasks)
    except UnknownSimulator as e:
        raise CollectError(str(e)) from None
    except (KeyError, ValueError) as e:
        raise CollectError(str(e.args[0]) if e.args else str(e)) from None
    return dataclasses.replace(
        cfg,
        tasks=tasks,
        cameras=tuple(cfg.cameras) or sim.default_cameras,
        max_steps=cfg.max_steps or sim.default_max_steps,
    )


def validate(cfg: CollectConfig) -> None:
    """Check a resolved config (see `resolve`); CollectError names the problem."""
    limit = make_collector(cfg.env).max_steps_limit
    if not cfg.tasks:
        raise CollectError("no tasks given")
    if len(set(cfg.tasks)) != len(cfg.tasks):
        raise CollectError(f"duplicate tasks in {cfg.tasks}")
    if cfg.episodes < 1 or cfg.max_failures < 0 or cfg.episodes + cfg.max_failures > INDEX_STRIDE:
        raise CollectError(f"need 1 <= episodes and episodes + max_failures <= {INDEX_STRIDE}")
    if len(cfg.tasks) * INDEX_STRIDE - 1 > MAX_INDEX:
        raise CollectError(f"at most {(MAX_INDEX + 1) // INDEX_STRIDE} tasks per store")
    if cfg.seed_base < 0:
        raise CollectError("seed_base must be >= 0")
    if not 1 <= cfg.max_steps <= limit:
        raise CollectError(f"max_steps must be in [1, {limit}]")
    if cfg.image_size < 8 or not cfg.cameras:
        raise CollectError("need at least one camera and image_size >= 8")
    if cfg.perturbation:
        if cfg.env != "metaworld":
            raise CollectError(f"perturbation={cfg.perturbation!r}: only the metaworld simulator renders one")
        try:
            parse_perturbation(cfg.perturbation)
        except (KeyError, ValueError) as e:
            raise CollectError(f"perturbation={cfg.perturbation!r}: {e}") from None
