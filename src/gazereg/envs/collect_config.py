"""What `gazereg collect` runs: its settings, presets (the collection budgets), their checks, and what fixes an
episode's index.

CollectConfig(episodes=0)                            # UsageError: --episodes must be an integer >= 1, got 0
cfg = resolve(CollectConfig(tasks=("reach-v3",)))   # the simulator's defaults filled in, tasks canonical
fingerprint(cfg)                                      # changes with the settings that change an episode
episode_index(slot=1, seed=5, seed_base=0)            # 1005
collect_seeds(CollectConfig(episodes=25, max_failures=0))   # range(0, 25): the setups it may roll out
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from gazereg.envs.base import SimulatorName, check_simulator, make_collector
from gazereg.envs.perturbations import parse_perturbation
from gazereg.runtime.config import Validated, option, require_entries, require_number
from gazereg.runtime.errors import UsageError
from gazereg.runtime.pool import fingerprint_json

INDEX_STRIDE = 1000  # episode indices per task slot
MAX_INDEX = 999_999  # the store names episodes with 6 digits
# Settings that change what an episode contains; episodes made with other values are not mixed in one store.
FINGERPRINT_FIELDS = ("cameras", "image_size", "action_noise", "max_steps", "goal_marker_radius")


class CollectError(UsageError):
    """A collection that cannot run as configured (unknown task, a store made with other settings, ...)."""


@dataclass(frozen=True)
class CollectConfig(Validated):
    """Expert demonstrations in simulation (Meta-World or LIBERO), written to an episode store.

    Checked when built (`validate`); what needs the simulator (task names, its step limit) when resolved."""

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
    """Render under this perturbation (gazereg.envs.perturbations spec, e.g. dim:0.7): the same
    setups and expert actions, seen under other light or with sensor noise; empty = clean."""
    workers: int = 0
    """Worker processes; 0 = one per available core."""
    gl_backend: str = ""
    """OpenGL backend (egl, osmesa); empty = MUJOCO_GL if set, else egl, else osmesa."""
    progress: bool = True
    """Show a progress bar."""
    env: SimulatorName = "metaworld"
    """Simulator: a registered name (`gazereg.envs.base.simulator_names()`): metaworld, libero (needs the LIBERO
    venv: bash scripts/libero_env.sh gazereg collect ...), or one an installed plugin provides."""

    def validate(self, prefix: str) -> None:
        """UsageError (CollectError for names) naming the first bad option, as `gazereg collect` spells it."""
        check_simulator(self.env, option(prefix + "env"), error=CollectError)
        for name in ("tasks", "cameras"):
            require_entries(getattr(self, name), prefix + name, non_empty=False, error=CollectError)
        require_entries(self.tasks, prefix + "tasks", noun="task", error=CollectError)
        require_number(self.episodes, prefix + "episodes", 1, INDEX_STRIDE, integer=True)
        require_number(
            self.max_failures, prefix + "max_failures", 0, INDEX_STRIDE - self.episodes, integer=True
        )
        for name in ("seed_base", "max_steps", "workers"):
            require_number(getattr(self, name), prefix + name, 0, integer=True)
        require_number(self.image_size, prefix + "image_size", 8, integer=True)
        require_number(self.action_noise, prefix + "action_noise", 0)
        require_number(self.goal_marker_radius, prefix + "goal_marker_radius", 0)
        if self.perturbation:
            flag = option(prefix + "perturbation")
            try:
                parse_perturbation(self.perturbation)
            except (KeyError, ValueError) as e:
                reason = e.args[0] if e.args else str(e)
                raise CollectError(f"{flag} {self.perturbation!r}: {reason}") from None


def demos_3x30() -> CollectConfig:
    """3 Meta-World tasks x 30 successful demonstrations at 96 px (CollectConfig's defaults)."""
    return CollectConfig()


def demos_2x2() -> CollectConfig:
    """CI: 2 Meta-World tasks x 2 demonstrations at 64 px, at most 150 steps each."""
    return CollectConfig(
        out=Path("runs/smoke/demos"),
        tasks=("reach-v3", "pick-place-v3"),
        episodes=2,
        max_failures=4,
        image_size=64,
        max_steps=150,
    )


def demos_10x50() -> CollectConfig:
    """10 Meta-World tasks x 50 demonstrations from 2 cameras at 128 px, at most 300 steps each."""
    return CollectConfig(
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
    )


PRESETS = {"demos-3x30": demos_3x30, "demos-2x2": demos_2x2, "demos-10x50": demos_10x50}
"""the collection budgets, `gazereg collect --preset NAME` (`gazereg presets`)"""
DEFAULT_PRESET = "demos-3x30"
"""`gazereg collect`'s budget without `--preset`"""


def fingerprint(cfg: CollectConfig) -> str:
    """Hash of the settings that change what an episode contains (of a resolved config)."""
    d: dict[str, object] = {k: getattr(cfg, k) for k in FINGERPRINT_FIELDS}
    d["cameras"] = list(cfg.cameras)
    if cfg.env != "metaworld":  # Meta-World stores made before there was a choice keep their fingerprint
        d["env"] = cfg.env
    if cfg.perturbation:  # likewise clean stores
        d["perturbation"] = cfg.perturbation
    return fingerprint_json(d)


def collect_seeds(cfg: CollectConfig) -> range:
    """The setup seeds a collection may roll out for each task: `episodes` from `seed_base` on and up to
    `max_failures` more that replace failed rollouts (the Scheduler tries them in this order and no others)."""
    return range(cfg.seed_base, cfg.seed_base + cfg.episodes + cfg.max_failures)


def episode_index(slot: int, seed: int, seed_base: int) -> int:
    """The store index of the episode of the task in position `slot` on setup `seed`."""
    return slot * INDEX_STRIDE + (seed - seed_base)


def resolve(cfg: CollectConfig) -> CollectConfig:
    """Fill the simulator's defaults (cameras, max_steps) and canonical task names; CollectError names the
    option the simulator refuses (an unknown task, more steps than it allows, a simulator not installed)."""
    try:
        sim = make_collector(cfg.env)
    except (KeyError, ValueError) as e:
        raise CollectError(f"{option('env')} {cfg.env}: {e.args[0] if e.args else e}") from None
    try:
        tasks = sim.tasks(cfg.tasks)
    except (KeyError, ValueError) as e:
        raise CollectError(f"{option('tasks')}: {e.args[0] if e.args else e}") from None
    if len(tasks) * INDEX_STRIDE - 1 > MAX_INDEX:
        raise CollectError(f"{option('tasks')}: at most {(MAX_INDEX + 1) // INDEX_STRIDE} tasks per store")
    limit = sim.max_steps_limit
    if cfg.max_steps > limit:
        raise CollectError(f"{option('max_steps')} must be <= {limit} for {cfg.env}, got {cfg.max_steps}")
    return dataclasses.replace(
        cfg,
        tasks=tasks,
        cameras=tuple(cfg.cameras) or sim.default_cameras,
        max_steps=cfg.max_steps or sim.default_max_steps,
    )
