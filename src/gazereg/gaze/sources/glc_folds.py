"""The `glc_folds` gaze source: cross-fitted GLC, each episode's maps from the GLC that did not train on its task.

    make_gaze_source(GLCFoldsParams(tasks=("a", "b"), checkpoints=(Path("glc/fold0/final"), Path("glc/fold1/final"))))
    gazereg priors --store S --source glc_folds --name glc \
        --source-params tasks=a,b checkpoints=runs/e/glc/fold0/final,runs/e/glc/fold1/final

`tasks[i]` (an episode's `task`, as the store names it) is predicted by the GLC in `checkpoints[i]`; the other
parameters are the `glc` source's inference settings (`gazereg.gaze.sources.glc.GLCParams`), the same for every
fold. An episode whose task is not listed is an error. `describe()` records every fold's tasks and its GLC's
provenance (the weights' hash), so priors made with a retrained fold are refused on resume like any changed
setting (`gazereg.gaze.priors`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from gazereg.data.store import Episode
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.glc import GLCGaze, GLCMode, GLCParams
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.runtime.errors import UsageError


@dataclass(frozen=True)
class GLCFoldsParams(GazeSourceParams):
    """Parameters of the `glc_folds` source.

    tasks: the episode tasks, each once; checkpoints: for each task, the GLC folder that predicts it (a
    folder from `gazereg glc train` / `save_glc`; several tasks share one). stride, mode, hop, batch_size, device,
    temperature: as the `glc` source's, for every fold."""

    name: ClassVar[str] = "glc_folds"
    tasks: tuple[str, ...] = ()
    checkpoints: tuple[Path, ...] = ()
    stride: int = 2
    mode: GLCMode = "average"
    hop: int = 4
    batch_size: int = 8
    device: str = "cpu"
    temperature: float | None = None

    def __post_init__(self) -> None:
        if not self.tasks:
            raise UsageError("the glc_folds source needs tasks=... and one checkpoint per task")
        if len(self.tasks) != len(self.checkpoints):
            raise UsageError(
                f"glc_folds: {len(self.tasks)} tasks but {len(self.checkpoints)} checkpoints; give one per task"
            )
        twice = sorted({t for t in self.tasks if self.tasks.count(t) > 1})
        if twice:
            raise UsageError(f"glc_folds: tasks {twice} are listed more than once")
        self.fold(self.checkpoints[0])  # the inference settings' own checks (GLCParams)

    def fold(self, checkpoint: Path) -> GLCParams:
        """The `glc` source's parameters of the fold GLC in `checkpoint`."""
        return GLCParams(checkpoint=Path(checkpoint), **inference_settings(self))


INFERENCE_FIELDS = ("stride", "mode", "hop", "batch_size", "device", "temperature")
"""the `glc` source's inference settings that `glc_folds` applies to every fold"""


def inference_settings(params: GLCParams | GLCFoldsParams) -> dict[str, object]:
    """The inference settings (`INFERENCE_FIELDS`) of a glc or glc_folds source's parameters."""
    return {name: getattr(params, name) for name in INFERENCE_FIELDS}


@register_gaze_source(GLCFoldsParams)
class GLCFoldsGaze:
    """Gaze maps of each episode from its task's fold GLC (see the module docstring)."""

    name = "glc_folds"

    def __init__(self, params: GLCFoldsParams):
        self.models: dict[Path, GLCGaze] = {}
        for checkpoint in dict.fromkeys(Path(c) for c in params.checkpoints):
            self.models[checkpoint] = GLCGaze(params.fold(checkpoint))
        self.by_task = {t: Path(c) for t, c in zip(params.tasks, params.checkpoints, strict=True)}

    def describe(self) -> dict[str, Any]:
        """Every fold: the tasks it predicts and its GLC's record (`GLCGaze.describe`)."""
        return {
            "name": self.name,
            "folds": [
                {"tasks": [t for t, c in self.by_task.items() if c == checkpoint], **model.describe()}
                for checkpoint, model in self.models.items()
            ],
        }

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        checkpoint = self.by_task.get(episode.task)
        if checkpoint is None:
            raise UsageError(
                f"glc_folds: episode {episode.index}'s task {episode.task!r} is predicted by no fold; "
                f"the folds predict {sorted(self.by_task)}"
            )
        return self.models[checkpoint](episode, camera, size)
