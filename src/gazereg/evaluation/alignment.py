"""Where a trained policy looks: its attention maps on held-out frames, compared with gaze.

For every frame of the given episodes: the action queries' attention to one camera's patches (mean over
heads, queries and the chosen layers, renormalised), the gaze prior on the same patch grid, and the patches
around the task object's projected position (from the simulator's per-frame extras). Metrics: KL, CC, SIM,
NSS, AUC-Judd against gaze, and the attention mass on the object region next to its chance level.

Whose attention: the action queries', unless the caller names the query set the run trained
(`--gaze.queries language` or `both`: the instruction's real tokens, padding left out, or both sets of rows).
The experiment passes its training config's query set, the same for every arm (the baseline included), so the
arms' alignment compares the same rows; a run trained on the default measures exactly what it did before.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from gazereg.attention.probe import AttentionProbe, QuerySet
from gazereg.data.dataset import EpisodeDataset
from gazereg.data.store import EpisodeStore
from gazereg.metrics import alignment_metrics, mass_in_region


def region_mask(points_uv: np.ndarray, policy: Any, camera: str, radius: int = 1) -> Tensor:
    """(N, 2) normalised stored-frame points -> (N, n_patches) bool: the patch holding each point and its
    neighbours within `radius` patches (a (2r+1)^2 block); all False where the point is missing/outside."""
    geom = policy.geometry(camera)
    gh, gw = geom.grid_hw
    idx = geom.patch_index(torch.as_tensor(np.nan_to_num(points_uv, nan=-1.0), dtype=torch.float32))
    rows, cols = torch.div(idx, gw, rounding_mode="floor"), idx % gw
    r = torch.arange(gh)[None, :, None]
    c = torch.arange(gw)[None, None, :]
    near = ((r - rows[:, None, None]).abs() <= radius) & ((c - cols[:, None, None]).abs() <= radius)
    return (near & (idx >= 0)[:, None, None]).reshape(len(idx), gh * gw)


@torch.no_grad()
def attention_maps(
    policy: Any,
    store: EpisodeStore,
    episodes: Sequence[int],
    camera: str,
    prior: str | None,
    layers: Sequence[int] | None = None,
    object_key: str = "obj_uv",
    batch_size: int = 256,
    queries: QuerySet = QuerySet.ACTION,
) -> dict[str, Tensor]:
    """Attention (N, P), gaze (N, P) + valid (N,) if `prior`, object region (N, P) if the extras have it,
    and the (episode, t) of every row. `queries`: whose attention (module docstring; default the action
    queries, with one spec for every batch; language / both: a spec per batch from its text mask)."""
    policy.eval()
    cfg = policy.config
    ds = EpisodeDataset(
        store,
        list(episodes),
        cfg.cameras,
        cfg.chunk,
        policy.tokenizer,
        gaze_prior=prior,
        gaze_camera=camera if prior else None,
        geometry=policy.geometry(camera) if prior else None,
    )
    queries = QuerySet(queries)
    spec = policy.probe_spec(camera, layers) if queries is QuerySet.ACTION else None
    attn, gaze, valid, ep_t = [], [], [], []
    gen = torch.Generator().manual_seed(0)
    for start in range(0, len(ds), batch_size):
        batch = ds.__getitems__(range(start, min(len(ds), start + batch_size)))
        batch_spec = (
            spec if spec is not None else policy.probe_spec(camera, layers, queries, batch["text_mask"])
        )
        with AttentionProbe(policy, batch_spec, adapter="tap") as probe:
            policy(batch, generator=gen)
        attn.append(probe.distribution().float())
        if prior:
            gaze.append(batch["gaze"])
            valid.append(batch["gaze_valid"])
        ep_t.append(torch.stack([batch["episode"], batch["t"]], -1))
    out = {"attention": torch.cat(attn), "episode_t": torch.cat(ep_t)}
    if prior:
        out["gaze"], out["gaze_valid"] = torch.cat(gaze), torch.cat(valid)
    key = f"{object_key}.{camera}"
    eps = [store.read(i, cameras=[camera]) for i in episodes]
    if all(key in e.extras for e in eps):
        pts = np.concatenate(
            [np.asarray(e.extras[key], dtype=np.float32).reshape(e.length, -1)[:, :2] for e in eps]
        )
        out["object_region"] = region_mask(pts, policy, camera)
    return out


def alignment_report(maps: dict[str, Tensor]) -> dict[str, Any]:
    """Summary metrics of `attention_maps` output (means over frames)."""
    attn = maps["attention"]
    out: dict[str, Any] = {"frames": int(attn.shape[0])}
    if "gaze" in maps:
        out.update(
            {f"gaze_{k}": v for k, v in alignment_metrics(maps["gaze"], attn, maps["gaze_valid"]).items()}
        )
    if "object_region" in maps:
        region = maps["object_region"]
        has = region.any(-1)
        if has.any():
            out["object_mass"] = float(mass_in_region(attn[has], region[has]).mean())
            out["object_mass_chance"] = float(region[has].float().mean(-1).mean())
    return out


def attention_shift(clean: dict[str, Tensor], perturbed: dict[str, Tensor]) -> dict[str, Any]:
    """How a perturbation moves a policy's attention: `attention_maps` of the same frames rendered clean and
    perturbed (same episodes, same actions; frames matched by (episode, t)). Returns each rendering's
    `alignment_report` and the agreement of the two attention maps (KL(clean || perturbed), CC, SIM)."""
    if not torch.equal(clean["episode_t"], perturbed["episode_t"]):
        raise ValueError("attention_shift: the two renderings do not hold the same (episode, t) frames")
    agree = alignment_metrics(clean["attention"], perturbed["attention"])
    return {
        "clean": alignment_report(clean),
        "perturbed": alignment_report(perturbed),
        "agreement": {k: agree[k] for k in ("kl", "cc", "sim") if k in agree},
    }
