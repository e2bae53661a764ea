"""Are LIBERO's scenes at rest when an episode starts? Fixed initial states against sampled placements.

    bash scripts/libero_env.sh python benchmarks/libero_placements.py --suite libero_spatial --setups 5 \
        --out docs/benchmarks/libero_spatial_placements.json
    python benchmarks/libero_placements.py --markdown docs/benchmarks/libero_spatial_placements.json

For every task of `--suite`, resets `LiberoEnv` (physics only, its default settling) to the fixed initial states
25.. (the evaluation's) and to the sampled placements from `SAMPLED_FROM` on (the validation setups), `--setups`
of each, then steps `--steps` no-op actions (arm still, gripper open) and counts the setups in which a movable
object moved more than `--tolerance` metres: a scene whose objects were placed where nothing holds them (in
mid-air, inside another object) falls or jumps apart in those steps, and an episode on it is not the task the
BDDL describes. Records which objects moved, and the source the env ran (`gazereg` module folder, its git commit
and whether it had uncommitted changes), so that a measurement of an older env states which one it was.

Needs the LIBERO venv; elsewhere prints {"skipped": "..."} and exits 0. `--markdown JSON` measures nothing.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from _timing import emit, machine_info, print_markdown


def task_report(suite: str, task: int, setups: int, steps: int, tolerance: float) -> dict[str, object]:
    """{"task", "instruction", "fixed": {...}, "sampled": {...}} for one task; each kind: n, unsettled (setups
    with a mover), movers (object name -> setups it moved in), max_moved_m."""
    import numpy as np

    from gazereg.envs.libero.env import NOOP_ACTION, LiberoEnv
    from gazereg.envs.libero.setup import SAMPLED_FROM

    env = LiberoEnv(f"{suite}/{task}", cameras=(), max_steps=steps)
    try:
        objects = env.unwrapped_libero.env.objects_dict
        bodies = [env.physics_model.body(o.root_body).id for o in objects.values()]
        out: dict[str, object] = {"task": f"{suite}/{task}", "instruction": env.instruction}
        for kind, first in (("fixed", 25), ("sampled", SAMPLED_FROM)):
            unsettled, movers, worst = 0, {}, 0.0
            for seed in range(first, first + setups):
                env.reset(seed=seed)
                before = env.physics_data.xpos[bodies].copy()
                for _ in range(steps):
                    env.step(NOOP_ACTION)
                moved = np.linalg.norm(env.physics_data.xpos[bodies] - before, axis=1)
                worst = max(worst, float(moved.max()))
                names = [name for name, m in zip(objects, moved, strict=True) if m > tolerance]
                unsettled += bool(names)
                for name in names:
                    movers[name] = movers.get(name, 0) + 1
            out[kind] = {
                "n": setups,
                "unsettled": unsettled,
                "movers": movers,
                "max_moved_m": round(worst, 4),
            }
        return out
    finally:
        env.close()


def source_info() -> dict[str, object]:
    """The gazereg the env was imported from: its folder, git commit and dirtiness."""
    import gazereg
    from gazereg.experiment.pretrain import git_commit

    where = Path(gazereg.__file__).resolve().parent
    return {"gazereg": str(where), **git_commit(where)}


def placements_markdown(result: dict, source: str) -> str:
    """A placements JSON as a line naming the run and a per-task table."""
    m, src = result["machine"], result["source"]
    commit = (src["commit"] or "no git checkout")[:7] + (" with uncommitted changes" if src["dirty"] else "")
    lines = [
        f"Setups of {result['suite']} with an object moving more than {result['tolerance_m'] * 100:.0f} cm in "
        f"{result['steps']} no-op steps after the reset, env at {commit}; {m['cpu_model']}, {m['cores']} cores; "
        f"from `{source}`:",
        "",
        "| task | instruction | fixed states 25.. | sampled placements | objects that moved (sampled) |",
        "|---|---|---|---|---|",
    ]
    for r in result["tasks"]:
        f, s = r["fixed"], r["sampled"]
        movers = ", ".join(f"{k} ({v})" for k, v in sorted(s["movers"].items())) or "none"
        lines.append(
            f"| {r['task']} | {r['instruction']} | {f['unsettled']}/{f['n']} | {s['unsettled']}/{s['n']} | "
            f"{movers} |"
        )
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="libero_spatial")
    ap.add_argument("--setups", type=int, default=5, help="fixed and sampled setups per task")
    ap.add_argument("--steps", type=int, default=40, help="no-op steps after the reset")
    ap.add_argument("--tolerance", type=float, default=0.02, help="metres an object may move")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    ap.add_argument("--markdown", type=Path, default=None, metavar="JSON", help="print a JSON's table")
    args = ap.parse_args()
    if args.markdown is not None:
        return print_markdown(args.markdown, placements_markdown, "libero_placements.py")
    if args.setups < 1 or args.steps < 1 or args.tolerance <= 0:
        ap.error("--setups and --steps must be >= 1 and --tolerance > 0")
    if args.out is not None and not args.out.parent.is_dir():
        ap.error(f"--out: the folder {args.out.parent} does not exist")
    from gazereg.envs.libero.setup import SUITES, import_libero, libero_available, suite_benchmark

    if args.suite not in SUITES:
        ap.error(f"--suite {args.suite}: not a LIBERO suite ({', '.join(SUITES)})")
    ok, why = libero_available()
    if not ok:
        print(json.dumps({"benchmark": "libero_placements", "skipped": why}))
        return 0
    import_libero(None)  # LIBERO's config, without its prompts
    machine, t0 = machine_info(), time.perf_counter()
    tasks = []
    for t in range(len(suite_benchmark(args.suite).get_task_names())):
        tasks.append(task_report(args.suite, t, args.setups, args.steps, args.tolerance))
        print(f"{tasks[-1]['task']}: {tasks[-1]['sampled']}", flush=True)
    result = {
        "benchmark": "libero_placements",
        "machine": machine,
        "source": source_info(),
        "suite": args.suite,
        "steps": args.steps,
        "tolerance_m": args.tolerance,
        "seconds": round(time.perf_counter() - t0, 1),
        "tasks": tasks,
    }
    emit(result, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
