"""Does a rendering perturbation move where an experiment's policies look?

Renders the experiment's held-out setups again under `--condition` (the same expert actions, only the light
or the sensor differs), then for every final checkpoint compares its attention on the clean and the
perturbed frames: attention mass on the task object (next to chance) for each, the agreement of the two
maps, and the action loss against the expert's actions on each (the same flow noise on both), which shows
whether what the policy reads changes where it looks does not. Writes RUN/attention-<condition>.json and .md,
or with several folders (each renders its own held-out setups) one table of all their runs to --out.

python scripts/attention_under_perturbation.py runs/paper8k --condition dim:0.7
python scripts/attention_under_perturbation.py runs/a runs/b --condition tint:1 --out runs/attention-tint.md
"""

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import torch

from gazereg.data.dataset import EpisodeDataset
from gazereg.data.store import EpisodeStore
from gazereg.envs.collect import collect
from gazereg.envs.collect_config import CollectConfig
from gazereg.evaluation.alignment import attention_maps, attention_shift
from gazereg.experiment.demos import demo_stores
from gazereg.experiment.finished import FinishedRun, read_run
from gazereg.policies import load_policy
from gazereg.runtime.errors import UsageError, report_errors
from gazereg.runtime.io import atomic_write_json, atomic_write_text


def slug(condition: str) -> str:
    """A perturbation spec as a file-name part: dim:0.7 -> dim_0.7."""
    return condition.replace(":", "_").replace("+", "-")


def render_heldout(run: FinishedRun, condition: str) -> Path:
    """The experiment's held-out store collected again with the settings it was collected with (its
    collection config: setups, camera, size, steps), rendered under `condition`."""
    saved = run.collect_config("heldout")
    names = {f.name for f in dataclasses.fields(CollectConfig)}
    clean = CollectConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in saved.items() if k in names}
    )
    out = run.path / f"heldout-{slug(condition)}"
    report = collect(dataclasses.replace(clean, out=out, perturbation=condition, progress=False))
    if not report.complete:
        raise SystemExit(f"{out}: the expert did not solve every held-out setup under {condition}")
    return out


def same_trajectories(clean: EpisodeStore, perturbed: EpisodeStore) -> list[int]:
    """The episodes both stores hold with identical states and actions (only the rendering differs). The
    expert may fail a setup in one rendering and not the other (a replacement setup then takes its place), and
    LIBERO's physics is not bit-reproducible from one collection to the next; such episodes are left out,
    with a line saying which."""
    common = sorted(set(clean.indices()) & set(perturbed.indices()))
    same = []
    for i in common:
        a, b = clean.read(i, cameras=[]), perturbed.read(i, cameras=[])
        if a.state.shape == b.state.shape and (a.state == b.state).all() and (a.action == b.action).all():
            same.append(i)
    left = sorted(set(clean.indices()) - set(same))
    if left:
        print(f"left out (not the same trajectory in both renderings): episodes {left}", flush=True)
    if not same:
        raise SystemExit("no held-out episode has the same trajectory in both renderings")
    return same


@torch.no_grad()
def action_loss(policy: Any, store: EpisodeStore, episodes: list[int], batch_size: int = 256) -> float:
    """The policy's training loss on every frame of `episodes`, with flow noise drawn from a fixed seed (so
    two stores with the same frames in the same order get the same draws)."""
    policy.eval()
    cfg = policy.config
    ds = EpisodeDataset(store, episodes, cfg.cameras, cfg.chunk, policy.tokenizer)
    gen, total = torch.Generator().manual_seed(0), 0.0
    for start in range(0, len(ds), batch_size):
        idx = range(start, min(len(ds), start + batch_size))
        loss, _ = policy(ds.__getitems__(idx), generator=gen)
        total += float(loss) * len(idx)
    return total / len(ds)


def markdown(runs: str, condition: str, rows: dict[str, dict[str, Any]]) -> str:
    lines = [
        f"## Attention under {condition}: {runs}",
        "",
        "Same held-out frames rendered clean and perturbed. Object mass: attention on the task object's patches "
        "(chance: the region's share of patches). Agreement: CC and KL(clean || perturbed) of the two maps. "
        "Action loss: the policy's loss against the expert's actions on each rendering.",
        "",
        "| run | object mass clean | object mass perturbed | chance | CC | KL | action loss clean | perturbed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        c, p, a = r["clean"], r["perturbed"], r["agreement"]
        lines.append(
            f"| {name} | {c.get('object_mass', float('nan')):.3f} | {p.get('object_mass', float('nan')):.3f} | "
            f"{c.get('object_mass_chance', float('nan')):.3f} | {a['cc']:.3f} | {a['kl']:.3f} | "
            f"{r['action_loss']['clean']:.4f} | {r['action_loss']['perturbed']:.4f} |"
        )
    return "\n".join(lines) + "\n"


def analyse(run: FinishedRun, condition: str) -> tuple[list[int], dict[str, dict[str, Any]]]:
    """(the held-out episodes compared, {run id: attention shift and action losses}) for `run`'s final
    checkpoints under `condition`."""
    ckpts = run.final_checkpoints()
    stores = EpisodeStore(demo_stores(run.path)["heldout"]), EpisodeStore(render_heldout(run, condition))
    episodes = same_trajectories(*stores)
    rows = {}
    for name, ckpt in ckpts.items():
        policy = load_policy(ckpt)
        clean, pert = (
            attention_maps(policy, s, episodes, run.camera, None, list(run.gaze_layers)) for s in stores
        )
        rows[str(name)] = attention_shift(clean, pert)
        rows[str(name)]["action_loss"] = dict(
            zip(("clean", "perturbed"), (action_loss(policy, s, episodes) for s in stores))
        )
        print(name, rows[str(name)]["agreement"], rows[str(name)]["action_loss"], flush=True)
    return episodes, rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dirs", type=Path, nargs="+", help="finished `gazereg experiment` folders")
    ap.add_argument("--condition", default="dim:0.7", help="a perturbation spec, as in `gazereg eval`")
    ap.add_argument(
        "--out", type=Path, help="the markdown (JSON beside it); default RUN/attention-<condition>.md"
    )
    args = ap.parse_args(argv)
    if args.out is None and len(args.run_dirs) > 1:
        raise UsageError("several run folders need --out (where the one table goes)")
    out = args.out or args.run_dirs[0] / f"attention-{slug(args.condition)}.md"
    runs = [read_run(run) for run in args.run_dirs]
    names = [str(n) for run in runs for n in run.final_checkpoints()]
    if len(set(names)) < len(names):
        raise UsageError(f"a run id is in more than one folder: {sorted(names)}")
    episodes, rows = {}, {}
    for path, run in zip(args.run_dirs, runs):
        episodes[str(path)], found = analyse(run, args.condition)
        rows.update(found)
    atomic_write_json(
        out.with_suffix(".json"), {"condition": args.condition, "episodes": episodes, "runs": rows}
    )
    text = markdown(", ".join(map(str, args.run_dirs)), args.condition, rows)
    atomic_write_text(out, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(report_errors("attention_under_perturbation", main, sys.argv[1:], verbose=False))
