"""`gazereg experiment --data-from FOLDER`: start a new run folder from another folder's finished demos stage
(its demonstration stores, priors inside, and its GLC) and, when that folder made every prior this one's arms
train on, its priors stage, instead of collecting and training them again. For the seed folders of a preset
run one seed per sitting, and arms added later, pooled with `gazereg pool`:

    gazereg experiment --preset paper --train-seeds 0 --out runs/paper-s0
    gazereg experiment --preset paper --train-seeds 1 --out runs/paper-s1 --data-from runs/paper-s0
    gazereg experiment --preset paper --arms uniform --out runs/paper-uniform --data-from runs/paper-s0

The source must be the same experiment but for its training seeds, arms and what the data stages do not read
(`DATA_FREE`: the training recipe, so the candidates of a tuning share their demonstrations; `gazereg pool`
still asks for the same recipe). When it lacks a prior (here `uniform`), the priors stage runs in the new
folder on the copied demonstrations. The copied stages' records name the source and count 0 s, so a pooled
report's wall time counts the work once.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from gazereg.experiment.arms import glc_dir, trains_glc
from gazereg.experiment.config import ExperimentConfig
from gazereg.experiment.demos import demo_stores
from gazereg.experiment.runner import Experiment
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_dir, atomic_write_json

log = logging.getLogger(__name__)

DATA_STAGES = ("demos", "priors")
DATA_FREE = ("train", "convergence_points", "convergence_episodes", "threshold", "figure_frames")
"""the keys neither data stage reads (the training recipe, the report's): a source may differ in them"""


def data_dirs(cfg: ExperimentConfig) -> list[Path]:
    """Every folder the demos and priors stages write under `cfg.out`: the stores (priors inside) and GLCs."""
    return [*demo_stores(Path(cfg.out)).values(), glc_dir(cfg)]


def take_data_from(argv: Sequence[str]) -> tuple[Path | None, list[str]]:
    """Remove `--data-from FOLDER` from argv: (the folder or None, the rest)."""
    rest, source = list(argv), None
    if "--data-from" in rest:
        at = rest.index("--data-from")
        if at + 1 >= len(rest) or rest[at + 1].startswith("--"):
            raise UsageError("--data-from needs the run folder whose demos and priors to copy")
        source = Path(rest[at + 1])
        del rest[at : at + 2]
    return source, rest


def check_source(exp: Experiment, source: Path) -> tuple[dict[str, dict], list[str]]:
    """(the source's finished demos and priors stage records, what of the priors `exp`'s arms need it lacks);
    refused (UsageError) unless it is the same experiment with its demos stage finished."""
    src = exp.sibling(source, "--data-from", DATA_FREE)
    records = {stage: r for stage in DATA_STAGES if (r := src.done(stage)) is not None}
    if "demos" not in records:
        raise UsageError(f"--data-from: {source} has not finished its demos stage")
    if "priors" not in records:
        return records, ["every prior (its priors stage is not finished)"]
    made = records["priors"]["priors"]
    missing = [p.name for p in exp.priors_needed() if f"demos/{p.name}" not in made]
    if trains_glc(exp.cfg) and records["priors"].get("glc") is None:
        missing.append("its GLC")
    return records, missing


def _moved(value: Any, source: Path, out: Path) -> Any:
    """A stage record with the GLC checkpoint paths under `source` moved under `out` and its durations 0."""
    if isinstance(value, dict):
        return {k: _moved_item(k, v, source, out) for k, v in value.items()}
    if isinstance(value, list):
        return [_moved(v, source, out) for v in value]
    return value


def _moved_item(key: str, value: Any, source: Path, out: Path) -> Any:
    if key == "seconds":
        return 0.0
    if key == "checkpoint" and isinstance(value, str):
        try:
            return str(out / Path(value).resolve().relative_to(source.resolve()))
        except ValueError:  # a GLC from outside the folder (--glc.checkpoint) stays where it is
            return value
    return _moved(value, source, out)


def reuse_data(cfg: ExperimentConfig, preset: str, source: Path) -> None:
    """Copy `source`'s demonstrations (and its priors stage when it has every prior needed) into `cfg.out`;
    nothing to do once `cfg.out` has its demos stage. Stage records are written last, so a killed copy
    leaves its stages unfinished."""
    exp, out = Experiment(cfg, preset), Path(cfg.out)
    if source.resolve() == out.resolve():
        raise UsageError(f"--data-from {source} is --out itself: name another folder")
    if exp.done("demos") is not None:
        log.info("--data-from: %s has its demonstrations already; nothing copied", out)
        return
    records, missing = check_source(exp, source)
    found = [d.name for d in data_dirs(cfg) if d.exists()]
    if found:
        raise UsageError(
            f"--data-from: {out} already holds {', '.join(found)} without finished stages (a killed run?); "
            "delete them or choose a new --out"
        )
    exp.check_resumable()
    for src_dir, dst_dir in zip(data_dirs(replace(cfg, out=source)), data_dirs(cfg)):
        if src_dir.exists():
            with atomic_dir(dst_dir) as tmp:
                shutil.copytree(src_dir, tmp, dirs_exist_ok=True)
    copied = ["demos"] if missing else list(DATA_STAGES)
    if missing:
        log.info("--data-from: the priors stage runs here; %s lacks %s", source, ", ".join(missing))
    for stage in copied:
        record = {**_moved(records[stage], source, out), "copied_from": str(source)}
        atomic_write_json(exp.marker(stage), record)
