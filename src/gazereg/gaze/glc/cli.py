"""`gazereg glc`: train and evaluate the GLC video gaze estimator on an episode store.

    gazereg glc train --store data/demos --camera corner2 --gaze-source visuomotor --out runs/glc
    gazereg glc train --preset full --init GLC_ego4d.pyth ...          (fine-tune the official model)
    gazereg glc eval  --store data/demos --checkpoint runs/glc

`train` learns from any episodes that carry per-frame gaze points: a gaze source's points (`visuomotor`:
the simulated eye tracker), recorded `gaze_uv.<camera>` extras (`--gaze-source recorded`), or the peak of
any other source's maps. Episodes are split deterministically (per task, every `holdout_every`-th is held
out, or `--holdout` lists them); training uses `gazereg.training.glc.train_glc` (resumable from
`<out>/checkpoints`) and writes `<out>/final/` (model.safetensors, config.json, glc_train.json), a folder the
`glc` gaze source loads (`--source-params checkpoint=<out>/final`).

`eval` runs the `glc` gaze source (the same code the priors use) on the held-out episodes and reports the
GLC paper's metrics (F1 / recall / precision at the best threshold, AUC) next to a centre prior fitted on
the training episodes' gaze and the uniform map; it prints a table and writes JSON.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gazereg.training.glc import GLCTrainConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GLCTrainCommand:
    store: Path = Path("data/demos")
    """episode store with frames and per-frame gaze"""
    camera: str = "corner2"
    gaze_source: str = "visuomotor"
    """where gaze points come from: recorded (gaze_uv.<camera> extras), visuomotor, or any gaze source"""
    gaze_params: tuple[str, ...] = ()
    """parameters of the gaze source, key=value"""
    out: Path = Path("runs/glc")
    config: str = "small"
    """GLC architecture: small (96 px, 3.5 M params) | full (official, 256 px, 70 M)"""
    init: str | None = None
    """fine-tune from: a folder from `gazereg glc train` or an official GLC checkpoint; None = random init"""
    stride: int = 2
    """frames between a clip's frames"""
    clip_hop: int = 1
    """a training clip is centred on every clip_hop-th frame of each episode"""
    holdout_every: int = 5
    """within each task, every holdout_every-th episode (by index) is held out for evaluation"""
    holdout: tuple[int, ...] = ()
    """explicit held-out episode indices (overrides holdout_every)"""
    device: str = "cpu"
    threads: int = 0
    """torch CPU threads (0: torch's default)"""
    optim: GLCTrainConfig = field(
        default_factory=lambda: GLCTrainConfig(
            steps=600, batch_size=8, lr=1e-3, warmup_steps=20, checkpoint_every=50, log_every=10
        )
    )
    evaluate: bool = True
    """evaluate on the held-out episodes after training (writes <out>/eval.json)"""
    resume: bool = True


def _train_presets() -> dict[str, Any]:
    return {
        "small": GLCTrainCommand,
        "full": lambda: GLCTrainCommand(
            config="full",
            optim=GLCTrainConfig(steps=1000, batch_size=4, lr=1e-4, warmup_steps=100, checkpoint_every=100),
        ),
    }


@dataclass(frozen=True)
class GLCEvalCommand:
    store: Path = Path("data/demos")
    checkpoint: str = "runs/glc"
    """a folder from `gazereg glc train` (run folder or its final/), or an official checkpoint file"""
    config: str | None = None
    """architecture of an official checkpoint file (full | small)"""
    camera: str | None = None
    """default: the training camera (glc_train.json), else corner2"""
    gaze_source: str | None = None
    """default: the training gaze source, else visuomotor"""
    gaze_params: tuple[str, ...] | None = None
    episodes: tuple[int, ...] = ()
    """episodes to evaluate; default: the held-out episodes of training, else the holdout_every rule"""
    holdout_every: int = 5
    stride: int | None = None
    """default: the training stride, else 2"""
    mode: str = "average"
    """glc source mode: average | centre"""
    hop: int = 4
    batch_size: int = 8
    device: str = "cpu"
    threads: int = 0
    fixation_threshold: float = 0.0
    """if > 0, also score fixation frames only (gaze moved at most this much, normalised units, since the
    previous frame)"""
    out: Path | None = None
    """JSON report; default <checkpoint folder>/eval.json"""


# ---- helpers ------------------------------------------------------------------------------------------


def _make_source(name: str, params: Sequence[str], store: Any) -> Any:
    """`"recorded"` (read `gaze_uv.<camera>` extras) or a gaze source object bound to `store`."""
    from gazereg.gaze.priors import parse_params
    from gazereg.gaze.sources import make_gaze_source

    if name == "recorded" and not params:
        return "recorded"
    source = make_gaze_source(name, **parse_params(tuple(params)))
    if hasattr(source, "bind"):
        source.bind(store)
    return source


def _resolve_folder(checkpoint: str) -> Path | None:
    p = Path(checkpoint)
    if p.is_dir():
        return (
            p / "final" if (p / "final" / "config.json").exists() and not (p / "config.json").exists() else p
        )
    return None


def _load_init(model: Any, init: str) -> None:
    from gazereg.gaze.glc.checkpoint import load_glc, load_glc_checkpoint

    folder = _resolve_folder(init)
    if folder is not None:
        src = load_glc(folder)
        if src.cfg != model.cfg:
            raise ValueError(f"--init {init}: its architecture differs from --config")
        model.load_state_dict(src.state_dict(), strict=True)
    else:
        if not Path(init).exists():
            raise FileNotFoundError(f"--init {init} does not exist")
        load_glc_checkpoint(model, init)


def _gaze_of(
    store: Any, indices: Sequence[int], camera: str, source: Any
) -> tuple[np.ndarray, np.ndarray, list]:
    from gazereg.gaze.glc.data import episode_gaze_points

    pts, valid, eps = [], [], []
    for i in indices:
        ep = store.read(i, cameras=[camera])
        p, v = episode_gaze_points(ep, camera, source)
        pts.append(p)
        valid.append(v)
        eps.append(ep)
    return pts, valid, eps


def _row(name: str, s: dict[str, Any]) -> str:
    auc = "  -  " if s.get("auc") is None else f"{s['auc']:.3f}"
    return f"  {name:<14} F1 {s['f1']:.3f}  recall {s['recall']:.3f}  precision {s['precision']:.3f}  AUC {auc}  (frames {s['n_frames']})"


def _scores(pred: Any, pts: np.ndarray, valid: np.ndarray, mask: np.ndarray) -> dict[str, Any]:
    from gazereg.gaze.glc.metrics import evaluate_gaze

    d = evaluate_gaze(pred, pts, valid=valid, frame_mask=mask).to_dict()
    return {k: d[k] for k in ("f1", "recall", "precision", "threshold", "auc", "n_frames", "f1_curve")}


# ---- evaluation ---------------------------------------------------------------------------------------


def evaluate_glc(
    store: Any,
    checkpoint: str,
    episodes: Sequence[int],
    train_episodes: Sequence[int],
    camera: str,
    gaze_source: Any,
    *,
    config: str | None = None,
    stride: int = 2,
    mode: str = "average",
    hop: int = 4,
    batch_size: int = 8,
    device: str = "cpu",
    fixation_threshold: float = 0.0,
) -> dict[str, Any]:
    """GLC-paper metrics of the `glc` source on `episodes` vs a centre prior (fitted on `train_episodes`'
    gaze) and the uniform map; maps are scored on the model's output grid over the whole frame."""
    from gazereg.gaze.glc.data import fixation_mask
    from gazereg.gaze.glc.metrics import center_prior_maps, fit_center_prior, uniform_maps
    from gazereg.gaze.sources.glc import GLCGaze

    if not episodes:
        raise ValueError("no episodes to evaluate")
    source = GLCGaze(
        checkpoint=checkpoint,
        config=config,
        stride=stride,
        mode=mode,
        hop=hop,
        batch_size=batch_size,
        device=device,
    )
    size = tuple(source.cfg.output_shape[1:])
    pts, valid, eps = _gaze_of(store, episodes, camera, gaze_source)
    preds, seconds, n_frames = [], 0.0, 0
    for ep in eps:
        t0 = time.perf_counter()
        maps, _ = source(ep, camera, size)
        seconds += time.perf_counter() - t0
        n_frames += ep.length
        preds.append(maps)
    pred = np.concatenate(preds)
    P, V = np.concatenate(pts), np.concatenate(valid)
    if not V.any():
        raise ValueError(f"episodes {list(episodes)} have no valid gaze point for camera {camera!r}")
    if train_episodes:
        train_pts, train_valid, _ = _gaze_of(store, train_episodes, camera, gaze_source)
        centre, sigma = fit_center_prior(np.concatenate(train_pts), np.concatenate(train_valid))
    else:
        centre, sigma = (0.5, 0.5), (0.15, 0.15)
    baselines = {
        "centre_prior": center_prior_maps(pred.shape, centre, sigma).numpy(),
        "uniform": uniform_maps(pred.shape).numpy(),
    }
    subsets = {"all_valid": V}
    if fixation_threshold > 0:
        subsets["fixation"] = np.concatenate(
            [fixation_mask(p, v, fixation_threshold) for p, v in zip(pts, valid, strict=True)]
        )
    results: dict[str, Any] = {}
    for sub, mask in subsets.items():
        results[sub] = {"glc": _scores(pred, P, V, mask)}
        for name, maps in baselines.items():
            results[sub][name] = _scores(maps, P, V, mask)
    # per task (all valid frames): GLC vs centre prior
    tasks = [ep.task for ep in eps for _ in range(ep.length)]
    per_task = {}
    for task in sorted(set(tasks)):
        m = V & (np.array(tasks) == task)
        if m.any():
            per_task[task] = {
                "glc_f1": _scores(pred, P, V, m)["f1"],
                "centre_prior_f1": _scores(baselines["centre_prior"], P, V, m)["f1"],
                "frames": int(m.sum()),
            }
    return {
        "source": source.describe(),
        "camera": camera,
        "map_size": list(size),
        "episodes": [int(i) for i in episodes],
        "train_episodes": [int(i) for i in train_episodes],
        "centre_prior": {"centre": list(centre), "sigma": list(sigma)},
        "scores": results,
        "per_task": per_task,
        "glc_seconds": round(seconds, 3),
        "glc_frames_per_s": round(n_frames / max(seconds, 1e-9), 3),
    }


def _print_report(rep: dict[str, Any]) -> None:
    for sub, d in rep["scores"].items():
        print(f"{sub} frames of episodes {rep['episodes']}:")
        for name, s in d.items():
            print(_row(name, s))
    for task, d in rep["per_task"].items():
        print(
            f"  task {task:<26} GLC F1 {d['glc_f1']:.3f}  centre prior F1 {d['centre_prior_f1']:.3f}  ({d['frames']} frames)"
        )


# ---- commands -------------------------------------------------------------------------------------------


def train_command(cfg: GLCTrainCommand) -> dict[str, Any]:
    from gazereg.data.store import EpisodeStore
    from gazereg.gaze.glc.checkpoint import save_glc
    from gazereg.gaze.glc.data import StoreClipDataset, split_episodes
    from gazereg.gaze.glc.model import GLC
    from gazereg.gaze.sources.glc import CONFIGS
    from gazereg.runtime.config import to_dict
    from gazereg.runtime.io import atomic_write_json
    from gazereg.training.glc import train_glc

    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    if cfg.config not in CONFIGS:
        raise ValueError(f"unknown --config {cfg.config!r}; use one of {sorted(CONFIGS)}")
    store = EpisodeStore(cfg.store)
    split = split_episodes(store, cfg.holdout_every, cfg.holdout)
    if not split["train"]:
        raise ValueError(f"no training episodes left in {cfg.store} after holding out {split['heldout']}")
    torch.manual_seed(cfg.optim.seed)
    model = GLC(CONFIGS[cfg.config]())
    if cfg.init:
        _load_init(model, cfg.init)
    model.to(cfg.device)
    source = _make_source(cfg.gaze_source, cfg.gaze_params, store)
    t0 = time.perf_counter()
    ds = StoreClipDataset(
        store,
        split["train"],
        cfg.camera,
        model.cfg.crop_size,
        model.cfg.num_frames,
        cfg.stride,
        cfg.clip_hop,
        source,
    )
    gaze, gvalid = ds.gaze()
    load_s = time.perf_counter() - t0
    log.info(
        "glc train: %d clips from %d episodes (%.1f s to load), held out %s",
        len(ds),
        len(split["train"]),
        load_s,
        split["heldout"],
    )
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = {
        "command": to_dict(cfg),
        "split": split,
        "camera": cfg.camera,
        "gaze_source": cfg.gaze_source,
        "gaze_params": list(cfg.gaze_params),
        "stride": cfg.stride,
        "train_clips": len(ds),
        "train_frames_with_gaze": int(gvalid.sum()),
    }
    atomic_write_json(out / "run.json", settings)
    t1 = time.perf_counter()
    result = train_glc(model, ds, cfg.optim, out, resume=cfg.resume)
    train_s = time.perf_counter() - t1
    final = save_glc(model, model.cfg, out / "final")
    losses = [v for _, v in result["losses"]]
    info = {
        **settings,
        "steps": result["step"],
        "train_seconds_this_run": round(train_s, 1),
        "first_loss": losses[0] if losses else None,
        "last_loss_mean10": float(np.mean(losses[-10:])) if losses else None,
    }
    atomic_write_json(final / "glc_train.json", info)
    print(f"GLC ({cfg.config}) trained to step {result['step']} in {train_s:.0f} s; model written to {final}")
    if cfg.evaluate and split["heldout"]:
        rep = evaluate_glc(
            store,
            str(final),
            split["heldout"],
            split["train"],
            cfg.camera,
            source,
            stride=cfg.stride,
            device=cfg.device,
        )
        atomic_write_json(out / "eval.json", rep)
        _print_report(rep)
        print(f"evaluation written to {out / 'eval.json'}")
        info["eval"] = str(out / "eval.json")
    return info


def eval_command(cfg: GLCEvalCommand) -> dict[str, Any]:
    from gazereg.data.store import EpisodeStore
    from gazereg.gaze.glc.data import split_episodes
    from gazereg.runtime.io import atomic_write_json

    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    store = EpisodeStore(cfg.store)
    folder = _resolve_folder(cfg.checkpoint)
    if folder is None and not Path(cfg.checkpoint).exists():
        raise FileNotFoundError(f"--checkpoint {cfg.checkpoint} does not exist")
    info: dict[str, Any] = {}
    if folder is not None and (folder / "glc_train.json").exists():
        info = json.loads((folder / "glc_train.json").read_text())
    camera = cfg.camera or info.get("camera", "corner2")
    gaze_name = cfg.gaze_source or info.get("gaze_source", "visuomotor")
    gaze_params = cfg.gaze_params if cfg.gaze_params is not None else tuple(info.get("gaze_params", ()))
    stride = cfg.stride or info.get("stride", 2)
    if cfg.episodes:
        episodes = sorted(set(cfg.episodes))
        train_eps = info.get("split", {}).get("train") or [
            i for i in store.indices() if i not in set(episodes)
        ]
    elif info.get("split"):
        episodes, train_eps = info["split"]["heldout"], info["split"]["train"]
    else:
        split = split_episodes(store, cfg.holdout_every)
        episodes, train_eps = split["heldout"], split["train"]
    train_eps = [i for i in train_eps if i in store and i not in set(episodes)]
    rep = evaluate_glc(
        store,
        str(folder) if folder is not None else cfg.checkpoint,
        episodes,
        train_eps,
        camera,
        _make_source(gaze_name, gaze_params, store),
        config=cfg.config,
        stride=stride,
        mode=cfg.mode,
        hop=cfg.hop,
        batch_size=cfg.batch_size,
        device=cfg.device,
        fixation_threshold=cfg.fixation_threshold,
    )
    rep["gaze_source"] = {"name": gaze_name, "params": list(gaze_params)}
    out = cfg.out or ((folder or Path(cfg.checkpoint).parent) / "eval.json")
    atomic_write_json(Path(out), rep)
    _print_report(rep)
    print(f"evaluation written to {out}")
    return rep


USAGE = """usage: gazereg glc {train,eval} [--preset NAME] [options]

  train   train / fine-tune GLC on an episode store's gaze (see `gazereg glc train --help`)
  eval    GLC metrics on held-out episodes vs centre-prior and uniform baselines
"""


def main(argv: list[str] | None = None) -> int:
    from gazereg.runtime.config import parse

    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE + "\n" + (__doc__ or ""))
        return 0
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    sub, rest = argv[0], argv[1:]
    if sub == "train":
        train_command(parse(_train_presets(), rest, prog="gazereg glc train", description=__doc__ or ""))
    elif sub == "eval":
        eval_command(
            parse({"default": GLCEvalCommand}, rest, prog="gazereg glc eval", description=__doc__ or "")
        )
    else:
        print(f"gazereg glc: unknown subcommand {sub!r}\n\n{USAGE}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
