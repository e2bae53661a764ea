"""Held-out evaluation of a GLC on an episode store.

* `holdout_split`: which episodes a GLC trains on and which it is evaluated on (deterministic: every
  n-th episode of each task, or an explicit list). Not to be confused with
  `gazereg.data.dataset.split_episodes`, the policy trainer's seeded random validation split.
* `gaze_points_source`: where the true gaze points come from (recorded extras or a gaze source).
* `evaluate_glc`: runs the `glc` gaze source (the same code the priors use) on the held-out episodes and
  scores its maps with the GLC paper's metrics (`gazereg.gaze.glc.metrics`) next to a centre prior fitted on
  the training episodes' gaze and the uniform map; `format_report` renders the result as text.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.store import Episode, EpisodeStore
from gazereg.gaze.glc.data import episode_gaze_points, fixation_mask
from gazereg.gaze.glc.metrics import center_prior_maps, evaluate_gaze, fit_center_prior, uniform_maps
from gazereg.gaze.sources import GazeSource, GazeSourceParams, make_gaze_source
from gazereg.gaze.sources.glc import GLCGaze, GLCParams
from gazereg.gaze.sources.recorded import RecordedParams
from gazereg.runtime.errors import UsageError
from gazereg.runtime.progress import Progress

DEFAULT_CENTRE = ((0.5, 0.5), (0.15, 0.15))
"""`(centre (u, v), sigma (su, sv))` of the centre prior when there are no training episodes"""


@dataclass(frozen=True)
class HoldoutSplit:
    """Store episode indices a GLC trains on and those held out for its evaluation (both ascending)."""

    train: tuple[int, ...]
    heldout: tuple[int, ...]

    def to_dict(self) -> dict[str, list[int]]:
        return {"train": list(self.train), "heldout": list(self.heldout)}


def holdout_split(store: EpisodeStore, holdout_every: int = 5, holdout: Sequence[int] = ()) -> HoldoutSplit:
    """Deterministic train / held-out split by episode index.

    `holdout` lists the held-out indices explicitly; otherwise, within each task (episodes sorted by
    index), every `holdout_every`-th episode is held out (ranks `holdout_every - 1, 2 * holdout_every - 1,
    ...`), so every task with at least `holdout_every` episodes contributes to both sides.
    """
    indices = store.indices()
    if holdout:
        missing = sorted(set(holdout) - set(indices))
        if missing:
            raise UsageError(f"--holdout: held-out episodes {missing} are not in {store.root}")
        held = sorted(set(holdout))
    else:
        if holdout_every < 2:
            raise UsageError(f"--holdout-every must be >= 2, got {holdout_every}")
        by_task: dict[str, list[int]] = {}
        for i in indices:
            by_task.setdefault(store.meta(i)["task"], []).append(i)
        held = sorted(
            i for eps in by_task.values() for r, i in enumerate(eps) if r % holdout_every == holdout_every - 1
        )
    return HoldoutSplit(tuple(i for i in indices if i not in set(held)), tuple(held))


def indices_text(indices: Sequence[int], show: int = 8) -> str:
    """Episode indices for a log line: all of them up to `show`, else their count, first and last
    (`450 episodes, 4..2249`); `no episodes` for none."""
    if not indices:
        return "no episodes"
    if len(indices) <= show:
        return f"episodes {list(indices)}"
    return f"{len(indices)} episodes, {min(indices)}..{max(indices)}"


def gaze_points_source(params: GazeSourceParams, store: EpisodeStore) -> RecordedParams | GazeSource:
    """What `episode_gaze_points` reads the true gaze points of `store`'s episodes from: recorded gaze is
    read as the stored points themselves; any other source is built from `params` and bound to `store`."""
    if isinstance(params, RecordedParams):
        return params
    source = make_gaze_source(params)
    if hasattr(source, "bind"):
        source.bind(store)
    return source


def resolve_glc_folder(checkpoint: str | Path) -> Path | None:
    """The model folder of a `gazereg glc train` run (its `final/`) or a model folder itself; None when
    `checkpoint` is not a folder (an official checkpoint file, or nothing)."""
    p = Path(checkpoint)
    if not p.is_dir():
        return None
    if (p / "final" / "config.json").exists() and not (p / "config.json").exists():
        return p / "final"
    return p


@dataclass
class _EpisodesGaze:
    """Gaze of several episodes, frames concatenated in episode order; episodes are read one at a time and
    not kept (each memory-mapped episode holds open files, and a store holds thousands)."""

    points: list[np.ndarray] = field(
        default_factory=list
    )  # per episode (T, 2), normalised (u, v), NaN = not valid
    valid: list[np.ndarray] = field(default_factory=list)  # per episode (T,)
    tasks: list[str] = field(default_factory=list)  # per episode
    maps: list[np.ndarray] = field(default_factory=list)  # per episode (T, h, w) GLC maps, when predicted
    seconds: float = 0.0  # the model's time for `maps`

    def add(
        self, episode: Episode, camera: str, source: Any, glc: GLCGaze | None, size: tuple[int, int]
    ) -> None:
        """Append `episode`'s gaze points and validity from `source`, and `glc`'s maps of `size` when given."""
        p, v = episode_gaze_points(episode, camera, source)
        self.points.append(p)
        self.valid.append(v)
        self.tasks.append(episode.task)
        if glc is not None:
            t0 = time.perf_counter()
            maps, _ = glc(episode, camera, size)
            self.seconds += time.perf_counter() - t0
            self.maps.append(np.asarray(maps))

    def frame_tasks(self) -> np.ndarray:
        """The task of every frame `(sum T,)`."""
        return np.array([t for t, v in zip(self.tasks, self.valid, strict=True) for _ in range(len(v))])


def _gaze_of(
    store: EpisodeStore,
    indices: Sequence[int],
    camera: str,
    source: Any,
    glc: GLCGaze | None = None,
    size: tuple[int, int] = (0, 0),
) -> _EpisodesGaze:
    """`_EpisodesGaze.add` of `indices`, read one at a time (a progress line: the model takes a while)."""
    out = _EpisodesGaze()
    label = "glc eval: predict" if glc is not None else "glc eval: the training episodes' gaze"
    with Progress(label, len(indices), "episodes") as bar:
        for i in indices:
            out.add(store.read(i, cameras=[camera]), camera, source, glc, size)
            bar.update()
    return out


def _scores(pred: Any, pts: np.ndarray, valid: np.ndarray, mask: np.ndarray) -> dict[str, Any]:
    d = evaluate_gaze(pred, pts, valid=valid, frame_mask=mask).to_dict()
    return {k: d[k] for k in ("f1", "recall", "precision", "threshold", "auc", "n_frames", "f1_curve")}


def _centre_prior(store: EpisodeStore, episodes: Sequence[int], camera: str, source: Any) -> dict[str, Any]:
    """The centre prior fitted on `episodes` of `store` (their points from `source`), else the default one:
    `{"centre": [u, v], "sigma": [su, sv], "fitted_on": {"store", "episodes"} or None}` (normalised units)."""
    if not episodes:
        (u, v), (su, sv) = DEFAULT_CENTRE
        return {"centre": [u, v], "sigma": [su, sv], "fitted_on": None}
    train = _gaze_of(store, episodes, camera, source)
    centre, sigma = fit_center_prior(np.concatenate(train.points), np.concatenate(train.valid))
    fitted_on = {"store": str(store.root), "episodes": len(episodes)}
    return {"centre": list(centre), "sigma": list(sigma), "fitted_on": fitted_on}


def _per_task(
    tasks: np.ndarray, pred: np.ndarray, centre: np.ndarray, pts: np.ndarray, valid: np.ndarray
) -> dict[str, dict[str, Any]]:
    """F1 of GLC and of the centre prior on each task's valid frames (`tasks (N,)`, one per frame)."""
    out = {}
    for task in sorted(set(tasks.tolist())):
        m = valid & (tasks == task)
        if m.any():
            out[task] = {
                "glc_f1": _scores(pred, pts, valid, m)["f1"],
                "centre_prior_f1": _scores(centre, pts, valid, m)["f1"],
                "frames": int(m.sum()),
            }
    return out


def evaluate_glc(
    store: EpisodeStore,
    model: GLCParams,
    episodes: Sequence[int],
    train_episodes: Sequence[int],
    camera: str,
    gaze_source: RecordedParams | GazeSource,
    fixation_threshold: float = 0.0,
    centre_store: EpisodeStore | None = None,
    centre_source: RecordedParams | GazeSource | None = None,
) -> dict[str, Any]:
    """GLC-paper metrics of the `glc` source built from `model` on `episodes` vs a centre prior (fitted on
    `train_episodes`' gaze) and the uniform map; maps are scored on the model's output grid over the whole
    frame, against the points `gaze_source` (what `gaze_points_source` returns) gives. `train_episodes` are
    episodes of `centre_store` (default `store`: another store when the GLC trained on one and is evaluated
    on another's episodes, e.g. held-out tasks), whose points `centre_source` gives (default `gaze_source`);
    none: the default centre prior (`DEFAULT_CENTRE`), which the report says.

    Returns a JSON-able report: scores per frame subset (`all_valid`, and `fixation` when
    `fixation_threshold > 0`, normalised units per frame) and per method, F1 per task, and timing."""
    if not episodes:
        raise ValueError("no episodes to evaluate")
    source = GLCGaze(model)
    size = tuple(source.cfg.output_shape[1:])
    held = _gaze_of(store, episodes, camera, gaze_source, source, size)
    pred, seconds = np.concatenate(held.maps), held.seconds
    P, V = np.concatenate(held.points), np.concatenate(held.valid)
    if not V.any():
        raise ValueError(f"episodes {list(episodes)} have no valid gaze point for camera {camera!r}")
    centre_prior = _centre_prior(
        store if centre_store is None else centre_store, train_episodes, camera, centre_source or gaze_source
    )
    centre, sigma = centre_prior["centre"], centre_prior["sigma"]
    methods = {
        "glc": pred,
        "centre_prior": center_prior_maps(pred.shape, centre, sigma).numpy(),
        "uniform": uniform_maps(pred.shape).numpy(),
    }
    subsets = {"all_valid": V}
    if fixation_threshold > 0:
        fixations = [
            fixation_mask(p, v, fixation_threshold) for p, v in zip(held.points, held.valid, strict=True)
        ]
        subsets["fixation"] = np.concatenate(fixations)
    scores = {
        sub: {name: _scores(maps, P, V, mask) for name, maps in methods.items()}
        for sub, mask in subsets.items()
    }
    return {
        "source": source.describe(),
        "camera": camera,
        "map_size": list(size),
        "episodes": [int(i) for i in episodes],
        "train_episodes": [int(i) for i in train_episodes],
        "centre_prior": centre_prior,
        "scores": scores,
        "per_task": _per_task(held.frame_tasks(), pred, methods["centre_prior"], P, V),
        "glc_seconds": round(seconds, 3),
        "glc_frames_per_s": round(len(pred) / max(seconds, 1e-9), 3),
    }


def _row(name: str, s: dict[str, Any]) -> str:
    auc = "  -  " if s.get("auc") is None else f"{s['auc']:.3f}"
    return (
        f"  {name:<14} F1 {s['f1']:.3f}  recall {s['recall']:.3f}  precision {s['precision']:.3f}  "
        f"AUC {auc}  (frames {s['n_frames']})"
    )


def format_report(report: dict[str, Any]) -> str:
    """The scores of an `evaluate_glc` report as text: one line per subset and method, one per task."""
    fit = report.get("centre_prior", {}).get("fitted_on")
    lines = [
        f"centre prior fitted on {fit['episodes']} training episodes of {fit['store']}"
        if fit
        else "centre prior: the default (no training episodes to fit it on: --centre-from names a store)"
    ]
    for sub, d in report["scores"].items():
        lines.append(f"{sub} frames of {indices_text(report['episodes'])}:")
        lines += [_row(name, s) for name, s in d.items()]
    for task, d in report["per_task"].items():
        lines.append(
            f"  task {task:<26} GLC F1 {d['glc_f1']:.3f}  centre prior F1 {d['centre_prior_f1']:.3f}  "
            f"({d['frames']} frames)"
        )
    return "\n".join(lines)
