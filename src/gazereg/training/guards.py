"""What `gazereg train` refuses before any data is read or memory allocated (one line each, `UsageError`):

- a batch larger than the training samples (it would repeat samples within a step and allocate for them);
- a gaze prior that does not fit what it would regularize: a gaze camera the store or the policy does not
  have, a prior made for another camera than `--gaze.camera`, or for frames of another size than the store's
  (prior.json's camera and image_hw).
"""

from __future__ import annotations

from typing import Any

from gazereg.data.store import PRIOR_MANIFEST, EpisodeStore
from gazereg.runtime.config import option
from gazereg.runtime.errors import UsageError
from gazereg.training.config import TrainConfig


def check_batch_size(cfg: TrainConfig, store: EpisodeStore, train_eps: list[int], n_val: int) -> None:
    """Refuse a batch larger than the training samples (frames of the training episodes)."""
    n = sum(int(store.meta(i)["length"]) for i in train_eps)
    if cfg.batch_size > n:
        held = f", {n_val} held out for validation" if n_val else ""
        raise UsageError(
            f"{option('batch_size')} {cfg.batch_size} is larger than the {n} training samples of {store.root} "
            f"({len(train_eps)} episodes{held}); use {option('batch_size')} {n} or less"
        )


def gaze_camera_for(cfg: TrainConfig, store: EpisodeStore, episodes: list[int], pcfg: Any) -> str:
    """The camera the gaze prior regularizes: --gaze.camera or the one prior.json records. Refused (one line,
    `UsageError`): a camera the store lacks, one the policy does not see, one other than the prior's, and a
    prior made on frames of another size than the store's."""
    name = cfg.gaze.prior
    assert name is not None
    info = store.prior_info(name)
    manifest = store.prior_dir(name) / PRIOR_MANIFEST
    recorded, asked = info.get("camera"), cfg.gaze.camera
    in_store = sorted(store.meta(episodes[0])["cameras"])
    if asked is not None and asked not in in_store:
        raise UsageError(
            f"{option('gaze.camera')} {asked}: store {store.root} has no camera {asked!r}; it has "
            f"{', '.join(in_store)}"
        )
    if asked is not None and recorded is not None and asked != recorded:
        raise UsageError(
            f"{option('gaze.camera')} {asked}: prior {name!r} was made for camera {recorded!r} ({manifest}) "
            f"and cannot regularize {asked!r}; make priors for it (gazereg priors --camera {asked} --name ...) "
            f"or leave {option('gaze.camera')} out"
        )
    camera = asked or recorded
    if camera is None:
        raise UsageError(f"prior {name!r} records no camera ({manifest}); set {option('gaze.camera')}")
    cameras = tuple(pcfg.cameras)
    if camera not in cameras:
        whose = f"{option('gaze.camera')} {camera}" if asked else f"prior {name!r}'s camera {camera!r}"
        raise UsageError(
            f"{option('policy.cameras')} {' '.join(cameras)}: the policy does not see the gaze camera ({whose}); "
            f"it sees {', '.join(cameras)} of the store's {', '.join(in_store)}: add {camera} to "
            f"{option('policy.cameras')}"
        )
    made_on, have = info.get("image_hw"), tuple(pcfg.camera_hw[cameras.index(camera)])
    if made_on is not None and tuple(made_on) != have:
        raise UsageError(
            f"prior {name!r} was made on {camera!r} frames of {made_on[0]}x{made_on[1]} pixels ({manifest}), "
            f"but the store's {camera!r} frames are {have[0]}x{have[1]}: recompute it with `gazereg priors "
            "--overwrite`"
        )
    return str(camera)
