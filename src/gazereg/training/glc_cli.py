"""`gazereg glc train`: train or fine-tune GLC on an episode store's gaze (`train_glc_on_store`).

    gazereg glc train --store data/demos --camera corner2 --gaze-source visuomotor --out runs/glc
    gazereg glc train --preset finetune-official --init GLC_ego4d.pyth ...          (fine-tune the official model)

Presets (the GLC training recipes): `scratch-small` (the `small` GLC, 96 px, 3.5 M parameters, from scratch)
and `finetune-official` (the `official` 256 px architecture, fine-tuned). Gaze points come from a gaze source (`--gaze-source visuomotor`: the simulated eye tracker),
from recorded `gaze_uv.<camera>` extras (`--gaze-source recorded`), or from the peak of any other source's
maps. Every `--holdout-every`-th episode of each task (or `--holdout`) is held out and, after training,
scored with the GLC paper's metrics against a centre prior and the uniform map (`<out>/eval.json`). The
model lands in `<out>/final/`, which the `glc` gaze source loads (`--source-params checkpoint=<out>/final`);
`<out>/checkpoints/` lets an interrupted run resume.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

from gazereg.gaze.glc.evaluate import format_report
from gazereg.gaze.sources import parse_source_params
from gazereg.runtime.config import parse
from gazereg.training.glc import GLCTrainConfig
from gazereg.training.glc_store import GLCRunSettings, GLCStoreTrainConfig, train_glc_on_store


@dataclass(frozen=True)
class GLCTrainCommand(GLCRunSettings):
    gaze_source: str = "visuomotor"
    """where gaze points come from: recorded (gaze_uv.<camera> extras), visuomotor, or any gaze source"""
    gaze_params: tuple[str, ...] = ()
    """parameters of the gaze source, key=value"""

    def to_config(self) -> GLCStoreTrainConfig:
        """The typed configuration; unknown gaze-source parameters and unreadable values are errors."""
        settings = {f.name: getattr(self, f.name) for f in dataclasses.fields(GLCRunSettings)}
        return GLCStoreTrainConfig(**settings, gaze=parse_source_params(self.gaze_source, self.gaze_params))


def scratch_small() -> GLCTrainCommand:
    """The `small` GLC (96 px) trained from scratch (GLCTrainCommand's defaults)."""
    return GLCTrainCommand()


def finetune_official() -> GLCTrainCommand:
    """The `official` GLC (256 px) fine-tuned: 1,000 steps of batch 4 at learning rate 1e-4."""
    optim = GLCTrainConfig(steps=1000, batch_size=4, lr=1e-4, warmup_steps=100, checkpoint_every=100)
    return GLCTrainCommand(config="official", optim=optim)


def train_presets() -> dict[str, Callable[[], GLCTrainCommand]]:
    """The GLC training recipes, `gazereg glc train --preset NAME`: `scratch-small` (`DEFAULT_PRESET`, the
    default) and `finetune-official`."""
    return {"scratch-small": scratch_small, "finetune-official": finetune_official}


DEFAULT_PRESET = "scratch-small"
"""`gazereg glc train`'s recipe without `--preset`"""


def main(argv: list[str]) -> int:
    cfg = parse(
        train_presets(), argv, prog="gazereg glc train", description=__doc__ or "", default=DEFAULT_PRESET
    ).to_config()
    result = train_glc_on_store(cfg)
    print(
        f"GLC ({cfg.config}) trained to step {result.steps} in {result.train_seconds:.0f} s; "
        f"model written to {result.final}"
    )
    if result.eval_report is not None:
        print(format_report(result.eval_report))
        print(f"evaluation written to {result.eval_path}")
    return 0
