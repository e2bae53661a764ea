"""Gaze regularization of a transformers VLA in a few lines: transformers' native PI0 (a tiny random config,
no download), two cameras, gaze points -> patch distributions on each camera's patch grid -> the KL between
gaze and the action expert's attention added to PI0's flow-matching loss. Runs offline in seconds on a CPU.

    python examples/transformers_gaze_recipe.py [--family pi0|paligemma|idefics3|smolvlm|llava] [--steps 30]

With a real checkpoint, build the model and batches as usual (PI0Processor / AutoProcessor) and keep the lines
marked "gaze".
"""

from __future__ import annotations

import argparse

import torch

from gazereg import heatmaps_from_points, patch_distribution
from gazereg.integrations.tiny import tiny_batch, tiny_model
from gazereg.integrations.transformers import GazeRegularizer, camera_geometry

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--family", default="pi0", choices=["pi0", "paligemma", "idefics3", "smolvlm", "llava"])
parser.add_argument("--steps", type=int, default=30)
parser.add_argument("--weight", type=float, default=1.0)
args = parser.parse_args()
torch.manual_seed(0)
torch.set_num_threads(
    1
)  # tiny tensors: thread overhead dominates, and one thread is steadier on a shared CPU

# A tiny random model and one batch of 4 samples with 2 cameras (stands in for your model and data loader).
model = tiny_model(args.family, n_layers=2).train()
batch = tiny_batch(model, batch=4, n_cameras=2)
cameras = ("front", "wrist")

# gaze: each camera's geometry as this model sees it (input size, patch size, pixel shuffle, resize/padding).
# The stored frames are 48x64 (h, w); the model's processor fits/stretches/crops them to its input.
geometries = {cam: camera_geometry(model, src_hw=(48, 64)) for cam in cameras}

# gaze: per-frame gaze points (u right, v down, normalised) -> heatmaps -> patch distributions. In practice they
# come precomputed from `gazereg` priors (GLC predictions aggregated over time) stored with the data set.
points = {
    "front": torch.tensor([[0.25, 0.3], [0.3, 0.35], [0.7, 0.6], [0.75, 0.7]]),
    "wrist": torch.rand(4, 2),
}
gaze, valid = {}, {}
for cam in cameras:
    heat, ok = heatmaps_from_points(points[cam], size=(48, 64), sigma=3.0)
    gaze[cam], valid[cam] = patch_distribution(heat, geometries[cam], ok)

# gaze: the regularizer (layers: indices of the action expert's layers for PI0, language-model layers for VLMs).
reg = GazeRegularizer(model, geometries, layers=[1], weight=args.weight)

opt = torch.optim.AdamW(model.parameters(), lr=2e-3)
first = None
for step in range(args.steps):
    with reg:  # gaze: capture attention during this forward (the model's outputs are unchanged)
        out = model(**batch)
    gaze_term, info = reg.loss(gaze, valid)  # gaze: weight * KL(gaze || attention), mean over cameras
    loss = out.loss + gaze_term  # gaze: added to the model's own loss
    opt.zero_grad()
    loss.backward()
    opt.step()
    first = info["loss/gaze_kl"] if first is None else first
    if step % 10 == 0 or step == args.steps - 1:
        print(
            f"step {step:3d}  loss/action {out.loss.item():.4f}  loss/gaze_kl {info['loss/gaze_kl']:.4f}  "
            f"gaze/patch_mass {info['gaze/patch_mass']:.3f}"
        )
print(f"{type(model).__name__}: KL(gaze||attention) {first:.4f} -> {info['loss/gaze_kl']:.4f}")
