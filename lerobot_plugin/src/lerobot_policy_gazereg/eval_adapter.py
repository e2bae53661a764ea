"""A LeRobot checkpoint as a step-by-step policy for an evaluation that runs in another interpreter.

    python -m lerobot_policy_gazereg.eval_adapter CHECKPOINT_DIR     # serves the policy over stdin/stdout
    python -m lerobot_policy_gazereg.eval_adapter --attention CHECKPOINT_DIR DATASET_ROOT GAZE_KEY OUT.npz

Simulators and LeRobot often live in different virtual environments (Meta-World and MuJoCo in one, lerobot in
another). The evaluation keeps the simulator and starts this module with the lerobot interpreter; each step it
sends one observation and reads back one action, so the checkpoint is run exactly as `lerobot-eval` runs it:
`preprocess_observation`-style tensors -> the checkpoint's saved preprocessor -> `policy.select_action` (its
action queue included) -> the saved postprocessor.

Protocol (binary, on the process's stdin/stdout; every message is an 8-byte little-endian length followed by a
pickle of a dict): {"op": "reset"} -> {"ok": True}; {"op": "act", "images": {key: uint8 (H, W, 3)}, "state":
float32 (S,), "task": str} -> {"action": float32 (A,)}; {"op": "attention", "root": data set, "gaze_key": str,
"camera": str} -> {"maps": attention_maps(...)}; {"op": "close"} ends the loop. Errors come back as
{"error": "one line"}. Everything the policy prints goes to stderr, so stdout carries only the protocol.
Both ends are local processes of one user; pickle is used only between them.

`--attention` (for figures): the checkpoint's action-expert attention to the gaze camera's image tokens on a few
frames of a data set, captured as the gaze loss captures it (`SmolVLACapture`, the default gaze layers), next
to the data set's gaze column mapped onto the same token grid, and KL(gaze || attention) per frame.
"""

from __future__ import annotations

import os
import pickle
import struct
import sys
from pathlib import Path
from typing import IO, Any

import numpy as np


def write_message(stream: IO[bytes], obj: dict[str, Any]) -> None:
    """One length-prefixed pickled dict on `stream`, flushed."""
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(struct.pack("<Q", len(data)) + data)
    stream.flush()


def read_message(stream: IO[bytes]) -> dict[str, Any] | None:
    """The next dict from `stream`, or None at end of stream."""
    head = stream.read(8)
    if len(head) < 8:
        return None
    (n,) = struct.unpack("<Q", head)
    return pickle.loads(stream.read(n))


class LeRobotPolicyAdapter:
    """A saved LeRobot policy (`.../pretrained_model`) acting one step at a time on CPU.

    act(images {"observation.images.<cam>": uint8 (H, W, 3)}, state float32 (S,), task) -> float32 (A,)."""

    def __init__(self, checkpoint: str | Path):
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        path = str(checkpoint)
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        self.policy.eval()
        self.pre, self.post = make_pre_post_processors(
            cfg, pretrained_path=path, preprocessor_overrides={"device_processor": {"device": "cpu"}}
        )

    def reset(self) -> None:
        self.policy.reset()

    def act(self, images: dict[str, np.ndarray], state: np.ndarray, task: str) -> np.ndarray:
        import torch

        batch: dict[str, Any] = {
            key: torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1)[None].float() / 255.0
            for key, img in images.items()
        }
        batch["observation.state"] = torch.as_tensor(np.asarray(state, np.float32))[None]
        batch["task"] = [task]
        with torch.inference_mode():
            action = self.post(self.policy.select_action(self.pre(batch)))
        return action[0].detach().cpu().numpy().astype(np.float32)


ATTENTION_FRAMES = 6


def attention_maps(
    ad: LeRobotPolicyAdapter, root: str | Path, gaze_key: str, camera: str
) -> dict[str, np.ndarray]:
    """The policy of `ad` on ATTENTION_FRAMES evenly spaced frames of the data set at `root`: {"index": (F,),
    "image": uint8 (F, H, W, 3), "attention" / "gaze": float32 (F, gh, gw) over the token grid, "valid": bool
    (F,), "kl": float32 (F,) KL(gaze || attention)}."""
    import torch
    from lerobot.datasets import LeRobotDataset
    from torch.utils.data import default_collate

    from gazereg.losses import gaze_kl
    from lerobot_policy_gazereg.capture import SmolVLACapture
    from lerobot_policy_gazereg.gaze_targets import gaze_distribution, gaze_valid_flag, smolvla_geometry

    cfg, model = ad.policy.config, ad.policy.model
    meta_ds = LeRobotDataset("local/attention", root=root, video_backend="pyav")
    dt = {"action": [i / meta_ds.fps for i in range(cfg.chunk_size)]}
    ds = LeRobotDataset("local/attention", root=root, delta_timestamps=dt, video_backend="pyav")
    index = np.linspace(0, len(ds) - 1, ATTENTION_FRAMES).round().astype(int)
    raw = default_collate([ds[int(i)] for i in index])
    src_hw = tuple(int(x) for x in raw[camera].shape[-2:])
    vcfg = model.vlm_with_expert.config
    geom, flip = smolvla_geometry(
        src_hw, cfg.resize_imgs_with_padding, vcfg.vision_config.patch_size, vcfg.scale_factor
    )
    gaze, valid = gaze_distribution(
        raw[gaze_key],
        geom,
        flip,
        getattr(cfg, "gaze_sigma", 0.05),
        src_hw,
        valid=gaze_valid_flag(raw, gaze_key),
    )
    cap = SmolVLACapture(model, getattr(cfg, "gaze_layers", None))
    present = [k for k in cfg.image_features if k in raw]
    torch.manual_seed(0)
    with torch.no_grad(), cap.capture(present.index(camera)):
        ad.policy.forward(ad.pre(raw))
    attention = cap.attention().float()
    grid = tuple(geom.grid_hw)
    return {
        "index": index,
        "image": (raw[camera].permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8),
        "attention": attention.reshape(-1, *grid).numpy(),
        "gaze": gaze.float().reshape(-1, *grid).numpy(),
        "valid": valid.numpy(),
        "kl": gaze_kl(gaze.float(), attention).numpy().astype(np.float32),
    }


def serve(checkpoint: str | Path, inp: IO[bytes], out: IO[bytes]) -> None:
    """Answer protocol messages from `inp` on `out` until "close" or end of stream."""
    adapter = LeRobotPolicyAdapter(checkpoint)
    write_message(out, {"ok": True, "ready": True})
    while (msg := read_message(inp)) is not None and msg.get("op") != "close":
        try:
            if msg["op"] == "reset":
                adapter.reset()
                write_message(out, {"ok": True})
            elif msg["op"] == "attention":
                maps = attention_maps(adapter, msg["root"], msg["gaze_key"], msg["camera"])
                write_message(out, {"maps": maps})
            else:
                write_message(out, {"action": adapter.act(msg["images"], msg["state"], msg["task"])})
        except Exception as e:  # noqa: BLE001 - reported to the client as one line
            write_message(out, {"error": f"{type(e).__name__}: {e}".splitlines()[0]})


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) == 6 and args[0] == "--attention":
        np.savez(args[5], **attention_maps(LeRobotPolicyAdapter(args[1]), *args[2:5]))
        return 0
    if len(args) != 1:
        print(
            "usage: python -m lerobot_policy_gazereg.eval_adapter CHECKPOINT_DIR | --attention CHECKPOINT_DIR "
            "DATASET_ROOT GAZE_KEY CAMERA_KEY OUT.npz",
            file=sys.stderr,
        )
        return 2
    out = os.fdopen(os.dup(1), "wb")  # the protocol's channel; fd 1 itself now goes to stderr
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    serve(args[0], sys.stdin.buffer, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
