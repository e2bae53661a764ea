"""What `gazereg eval` runs: `EvalConfig`, its presets (the evaluation budgets), the robustness sweep and the
checkpoints to compare.

cfg = presets()["clean-dim-noise-10"]()          # 10 episodes per task: clean, dim:0.7, gaussian_noise:0.5
arms = parse_checkpoints(("baseline=runs/a/final", "runs/b/final"))   # {"baseline": ..., "final": ...}
EvalConfig(episodes=0)                           # UsageError: --episodes must be an integer >= 1, got 0
EvalConfig(episodes=25, robustness_episodes=10).seeds("dim:0.7")   # range(1000, 1010): the first clean setups
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from gazereg.envs.base import SimulatorName, check_simulator, make_collector, simulator
from gazereg.envs.libero.setup import import_libero, libero_available, resolve_task
from gazereg.envs.perturbations import parse_perturbation
from gazereg.runtime.config import Validated, option, require_entries, require_number
from gazereg.runtime.errors import UsageError

# The full robustness sweep: each lighting perturbation and several sensor-noise levels.
ROBUSTNESS_CONDITIONS = (
    "clean",
    "dim:0.7",
    "bright:0.7",
    "tint:1",
    "light_direction:1",
    "gaussian_noise:0.3",
    "gaussian_noise:0.6",
    "salt_pepper:0.5",
)


@dataclass(frozen=True)
class EvalConfig(Validated):
    """Checked when built (`validate`): counts in range, tasks and conditions given once each, every condition
    a perturbation spec, a registered simulator. Whether the checkpoints exist is checked when an evaluation
    starts (`parse_checkpoints`)."""

    checkpoints: tuple[str, ...] = ()
    """policies to evaluate: NAME=DIR or DIR (named after the folder)"""
    tasks: tuple[str, ...] = ("reach-v3",)
    episodes: int = 10
    """episodes per task and condition (setup seeds seed_start .. seed_start + episodes - 1)"""
    seed_start: int = 1000
    conditions: tuple[str, ...] = ("clean",)
    """perturbation specs, e.g. clean, dim:0.7, tint:1, gaussian_noise:0.5, salt_pepper:0.5, dim:0.5+gaussian_noise:0.3"""
    max_steps: int = 150
    workers: int = 2
    """worker processes (one per core); 1 runs in this process"""
    batch: int | None = None
    """environments one worker steps in lockstep with one batched policy call per step (episodes of the same
    checkpoint, task and condition; filmed episodes run alone); 1 steps one episode at a time; None: the
    simulator's default (`lockstep()`). The speed-up is measured by benchmarks/bench_eval.py
    (`rollout_worker_batched_over_single`, docs/benchmarks/)"""
    videos: int = 1
    """episodes per (arm, task, condition) saved as GIFs with the attention overlay (0: none)"""
    out: Path = Path("runs/eval")
    gl_backend: str | None = None
    """MuJoCo OpenGL backend (egl | osmesa | glfw); None: respect MUJOCO_GL, else egl, else osmesa"""
    env: SimulatorName = "metaworld"
    """simulator, a registered name (`gazereg.envs.base.simulator_names()`): metaworld (tasks are Meta-World task
    names), libero (tasks are suites such as libero_spatial or single tasks such as libero_spatial/3; needs the
    LIBERO extra: scripts/libero_env.sh), or one an installed plugin provides"""
    robustness_episodes: int | None = None
    """episodes per task under each condition but clean: the first of the clean setups (seeds seed_start ..),
    so every perturbed episode pairs with a clean one on its setup; None = `episodes`"""

    def validate(self, prefix: str) -> None:
        """UsageError naming the first bad option (`prefix`: "" for `gazereg eval`, "eval." in an experiment)."""
        for name, low in (
            ("episodes", 1),
            ("max_steps", 1),
            ("workers", 1),
            ("videos", 0),
            ("seed_start", 0),
        ):
            require_number(getattr(self, name), prefix + name, low, integer=True)
        for name in ("tasks", "conditions"):
            require_entries(getattr(self, name), prefix + name)
        for condition in self.conditions:
            try:
                parse_perturbation(condition)
            except (KeyError, ValueError) as e:
                reason = e.args[0] if e.args else str(e)
                raise UsageError(f"{option(prefix + 'conditions')}: {condition!r}: {reason}") from None
        check_simulator(self.env, option(prefix + "env"))
        if self.batch is not None:
            require_number(self.batch, prefix + "batch", 1, integer=True)
        if self.robustness_episodes is not None:
            require_number(
                self.robustness_episodes, prefix + "robustness_episodes", 1, self.episodes, integer=True
            )

    def lockstep(self) -> int:
        """Environments stepped together per worker: `batch`, or the simulator's default."""
        return self.batch if self.batch is not None else simulator(self.env).lockstep

    def seeds(self, condition: str) -> range:
        """The setup seeds every task is evaluated on under `condition` (each arm on the same ones)."""
        n = self.episodes
        if condition != "clean" and self.robustness_episodes is not None:
            n = self.robustness_episodes
        return range(self.seed_start, self.seed_start + n)


def clean_10() -> EvalConfig:
    """10 episodes per task of 150 steps, clean (EvalConfig's defaults; reach-v3)."""
    return EvalConfig()


def clean_dim_2() -> EvalConfig:
    """CI: 2 episodes per task of 20 steps, clean and dim:0.7, in this process."""
    return EvalConfig(episodes=2, max_steps=20, workers=1, videos=1, conditions=("clean", "dim:0.7"))


def clean_dim_noise_10() -> EvalConfig:
    """10 episodes per task of 150 steps, clean, dim:0.7 and gaussian_noise:0.5."""
    return EvalConfig(episodes=10, conditions=("clean", "dim:0.7", "gaussian_noise:0.5"))


def libero_suite_25(suite: str, max_steps: int) -> EvalConfig:
    """A LIBERO suite's 10 tasks one by one on initial states 25..49 (clean, `max_steps` steps), leaving 0..24 to
    `gazereg collect --env libero`; one worker per core."""
    return EvalConfig(
        env="libero",
        tasks=tuple(f"{suite}/{k}" for k in range(10)),
        episodes=25,
        seed_start=25,
        max_steps=max_steps,
        workers=os.cpu_count() or 2,
    )


def libero_spatial_25() -> EvalConfig:
    """LIBERO-Spatial task by task on initial states 25..49 (220 steps, clean), leaving 0..24 to
    `gazereg collect --env libero`; one worker per core."""
    return libero_suite_25("libero_spatial", 220)


def libero_object_25() -> EvalConfig:
    """LIBERO-Object task by task on initial states 25..49 (280 steps, the standard evaluations' length, clean),
    leaving 0..24 to `gazereg collect --env libero`; one worker per core."""
    return libero_suite_25("libero_object", 280)


def libero_goal_25() -> EvalConfig:
    """LIBERO-Goal task by task on initial states 25..49 (300 steps, the standard evaluations' length, clean),
    leaving 0..24 to `gazereg collect --env libero`; one worker per core."""
    return libero_suite_25("libero_goal", 300)


def libero_10_25() -> EvalConfig:
    """LIBERO-10 task by task on initial states 25..49 (520 steps, the standard evaluations' length, clean),
    leaving 0..24 to `gazereg collect --env libero`; one worker per core."""
    return libero_suite_25("libero_10", 520)


ALOHA_TASKS = ("AlohaTransferCube-v0", "AlohaInsertion-v0")
"""Gym-Aloha's two tasks, as LeRobot's `aloha` env names them (`gazereg.envs.aloha.setup.TASKS`)"""


def aloha_50() -> EvalConfig:
    """Gym-Aloha's two tasks on setups 1000..1049 (the env's 400 steps, clean; the Aloha lane); one worker per
    core."""
    return EvalConfig(
        env="aloha",
        tasks=ALOHA_TASKS,
        episodes=50,
        seed_start=1000,
        max_steps=400,
        workers=os.cpu_count() or 2,
    )


def robustness_50() -> EvalConfig:
    """50 episodes per task of 200 steps under every condition of ROBUSTNESS_CONDITIONS; one worker per core."""
    return EvalConfig(
        episodes=50,
        max_steps=200,
        workers=os.cpu_count() or 2,
        conditions=ROBUSTNESS_CONDITIONS,
    )


def presets() -> dict[str, Callable[[], EvalConfig]]:
    """The evaluation budgets, `gazereg eval --preset NAME` (`DEFAULT_PRESET` without it; `gazereg presets`)."""
    return {
        "clean-10": clean_10,
        "clean-dim-2": clean_dim_2,
        "clean-dim-noise-10": clean_dim_noise_10,
        "libero-spatial-25": libero_spatial_25,
        "libero-object-25": libero_object_25,
        "libero-goal-25": libero_goal_25,
        "libero-10-25": libero_10_25,
        "aloha-50": aloha_50,
        "robustness-50": robustness_50,
    }


DEFAULT_PRESET = "clean-10"
"""`gazereg eval`'s budget without `--preset`"""


def check_tasks(env: str, tasks: Sequence[str], flag: str = "--tasks") -> None:
    """Refuse, before any work starts, a task simulator `env` does not register: a UsageError naming `flag`,
    one line. Meta-World: against its v3 tasks, with the three closest names; LIBERO: each spec resolved by
    LIBERO (a suite, `suite/index` or `suite/name`); another simulator: its collector's `tasks`. Also a UsageError
    when the simulator is not installed."""
    if env == "metaworld":
        try:  # Meta-World's own registry (gazereg.envs.metaworld.env reads the same); an optional extra
            from metaworld.env_dict import ALL_V3_ENVIRONMENTS
        except ImportError as e:
            raise UsageError(f"--env metaworld: Meta-World is not installed ({e})") from None
        known = list(ALL_V3_ENVIRONMENTS)
        for task in tasks:
            if task not in known:
                close = ", ".join(difflib.get_close_matches(task, known, n=3, cutoff=0.0))
                raise UsageError(
                    f"{flag}: unknown Meta-World task {task!r}; closest: {close} ({len(known)} v3 tasks)"
                )
    elif env == "libero":
        ok, why = libero_available()
        if not ok:
            raise UsageError(f"--env libero: {why}")
        import_libero(None)
        for task in tasks:
            try:
                resolve_task(task)
            except (KeyError, ValueError) as e:
                reason = " ".join(str(e.args[0] if e.args else e).split())
                raise UsageError(f"{flag}: {task!r}: {reason[:300]}") from None
    else:  # another registered simulator: its collector knows its tasks
        try:
            make_collector(env).tasks(tuple(tasks))
        except (KeyError, ValueError) as e:
            raise UsageError(f"{flag}: {e.args[0] if e.args else e}") from None


def parse_checkpoints(items: Sequence[str], option: str = "--checkpoints") -> dict[str, Path]:
    """NAME=DIR or DIR (named after the folder) -> {name: folder}; UsageError (naming `option`) for
    duplicates, folders that do not exist or are not saved policies (no config.json) and an empty list."""
    arms: dict[str, Path] = {}
    for item in items:
        name, _, path = item.rpartition("=") if "=" in item else (Path(item).name, "", item)
        if name in arms:
            raise UsageError(f"{option}: two checkpoints named {name!r}; name them NAME=DIR")
        if not Path(path).is_dir():
            raise UsageError(f"{option}: checkpoint {path!r} ({name}) does not exist")
        if not (Path(path) / "config.json").exists():
            raise UsageError(f"{option}: {path!r} ({name}) is not a saved policy folder (no config.json)")
        arms[name] = Path(path)
    if not arms:
        raise UsageError(f"no checkpoints to evaluate: pass {option} NAME=DIR ...")
    return arms
