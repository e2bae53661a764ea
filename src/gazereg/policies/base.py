"""The Policy interface: what training (`gazereg.training`) and evaluation (`gazereg.evaluation`) rely on.

A policy is a pair of classes:

- a frozen dataclass config, a subclass of `PolicyConfig`, whose class attribute `type` is the name the
  policy is registered and chosen under (`gazereg train --policy.type NAME`, `"type"` in config.json);
- a `torch.nn.Module`, a subclass of `Policy`, with `config_class` set to that config class.

Life cycle as the trainer drives it:

    data = describe_store(store, episodes, config.cameras)     # gazereg.data.dataset.StoreInfo
    policy = PolicyClass.from_data(config, data)              # tokenizer + resolved config + seeded init
    policy.set_normalization(**train_set.stats())             # state/action mean and std
    policy.geometry(camera), policy.resolve_layers(layers)    # where gaze goes, which layers are probed
    loss, info = policy(batch, generator=g, shift=px)         # training loss
    policy.write_pretrained(folder) / Policy.from_pretrained(folder)

and evaluation: `from_pretrained`, `reset()` at every episode start, `select_action(observation,
instruction)`, `gaze_probe_spec(camera)` and `geometry(camera)` for attention overlays. Whose attention is
read (`--gaze.queries`, a `QuerySet`) goes through `probe_spec`, which refuses a query set the policy does not
list in `gaze_query_sets` (every policy gives the action queries).

The data contract (`gazereg.data.dataset.EpisodeDataset`): a batch holds `image.<camera>` uint8
(B, H, W, 3) stored frames for every camera in `config.cameras`, `state` float32 (B, S), `action` float32
(B, K, A) raw actions t .. t+K-1 with K = `config.chunk`, `action_pad` bool (B, K) (True past the episode
end), `text_ids` long (B, L) and `text_mask` bool (B, L) from the policy's own tokenizer, and with a gaze
prior `gaze` (B, N) on the patch grid of `geometry(camera)` with `gaze_valid` bool (B,).

A saved policy is a folder: `model.safetensors` (parameters and buffers, normalisation included),
`config.json` (the resolved config with its `type`) and `tokenizer.json` (the tokenizer's `to_dict()`).
"""

from __future__ import annotations

import dataclasses
import json
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np
import torch
from torch import Tensor, nn

from gazereg.attention.probe import ProbeSpec, QuerySet
from gazereg.data.dataset import StoreInfo
from gazereg.patches import PatchGeometry
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_dir, load_safetensors, save_safetensors

MODEL_FILE, CONFIG_FILE, TOKENIZER_FILE = "model.safetensors", "config.json", "tokenizer.json"

C = TypeVar("C", bound="PolicyConfig")
P = TypeVar("P", bound="Policy")


class UnknownCamera(UsageError, KeyError):
    """A camera the policy does not see (asked for its geometry, patches or attention); one line naming it and
    the policy's cameras."""

    __str__ = BaseException.__str__  # the message as given, not KeyError's quoted repr


class PolicyTokenizer(Protocol):
    """A policy's text processor: instructions -> token ids (B, L) long and mask (B, L) bool (True = a real
    token); `to_dict()` is what `tokenizer.json` stores (the policy class's `load_tokenizer` reads it)."""

    def __call__(self, texts: str | Sequence[str]) -> tuple[Tensor, Tensor]: ...

    def to_dict(self) -> dict[str, Any]: ...


@dataclass(frozen=True)
class PolicyConfig:
    """Base of every policy config: the fields training and evaluation read, filled from the training data
    by `resolve` (a subclass adds its architecture fields and may add data-dependent ones of its own)."""

    type: ClassVar[str] = ""
    """the registered policy name (`--policy.type`), set by each subclass"""

    cameras: tuple[str, ...] = ()
    """camera names the policy sees, in token order (empty: every camera of the store, sorted)"""
    camera_hw: tuple[tuple[int, int], ...] = ()
    """stored frame size (H, W) of each camera, aligned with `cameras` (filled from the data)"""
    state_dim: int = 0
    """S, proprioceptive state values (filled from the data)"""
    action_dim: int = 0
    """A, action values (filled from the data)"""
    chunk: int = 1
    """K: actions per training sample (t .. t+K-1) and per prediction"""

    def __post_init__(self) -> None:
        if self.camera_hw and len(self.camera_hw) != len(self.cameras):
            raise ValueError(f"camera_hw {self.camera_hw} must align with cameras {self.cameras}")
        if self.chunk < 1:
            raise ValueError(f"chunk must be at least 1, got {self.chunk}")

    @property
    def resolved(self) -> bool:
        """Whether every data-dependent field is filled (the parameter shapes are then fixed)."""
        return (
            bool(self.cameras)
            and len(self.camera_hw) == len(self.cameras)
            and self.state_dim > 0
            and self.action_dim > 0
        )

    def check_resolved(self) -> None:
        if not self.resolved:
            raise ValueError(
                f"the {self.type} policy config is not resolved: its data-dependent fields come from the training "
                f"data (Policy.from_data); got {self.data_fields()}"
            )

    def data_fields(self) -> dict[str, Any]:
        """The data-dependent fields, for error messages."""
        return {
            "cameras": self.cameras,
            "camera_hw": self.camera_hw,
            "state_dim": self.state_dim,
            "action_dim": self.action_dim,
        }

    def resolve(self: C, data: StoreInfo) -> C:
        """This config with cameras, frame sizes and state/action dimensions taken from the training data."""
        return dataclasses.replace(
            self,
            cameras=data.cameras,
            camera_hw=data.camera_hw,
            state_dim=data.state_dim,
            action_dim=data.action_dim,
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able fields (tuples become lists), without the type (see `Policy.write_pretrained`)."""

        def plain(x: Any) -> Any:
            return [plain(v) for v in x] if isinstance(x, tuple) else x

        return {k: plain(v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls: type[C], d: Mapping[str, Any]) -> C:
        """Inverse of `to_dict` (a "type" key is ignored; JSON arrays become tuples); unknown keys are an error."""
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - fields - {"type"})
        if unknown:
            raise ValueError(f"unknown {cls.type} config field(s) {unknown}")

        def frozen(x: Any) -> Any:
            return tuple(frozen(v) for v in x) if isinstance(x, list) else x

        return cls(**{k: frozen(v) for k, v in d.items() if k in fields})


class Policy(nn.Module, ABC):
    """A trainable, gaze-regularizable policy (see the module docstring for the life cycle).

    Subclasses set `config_class` and implement the abstract methods; `__init__(config, tokenizer)` builds
    the parameters of a resolved config (drawing initial values from torch's global RNG)."""

    config_class: ClassVar[type[PolicyConfig]] = PolicyConfig
    gaze_query_sets: ClassVar[frozenset[QuerySet]] = frozenset({QuerySet.ACTION})
    """the query sets `gaze_probe_spec` can build (`--gaze.queries`); a policy that gives more lists them"""

    def __init__(self, config: PolicyConfig, tokenizer: PolicyTokenizer):
        super().__init__()
        config.check_resolved()
        self.config, self.tokenizer = config, tokenizer

    @property
    def name(self) -> str:
        """The registered policy name (the config class's `type`)."""
        return self.config_class.type

    # ----- built from data ---------------------------------------------------------------------------------
    @classmethod
    @abstractmethod
    def from_data(cls: type[P], config: PolicyConfig, data: StoreInfo) -> P:
        """A fresh policy for training data `data`: builds the tokenizer (e.g. a vocabulary of
        `data.instructions`), resolves `config` (`config.resolve(data)` plus the policy's own data-dependent
        fields) and initialises the parameters."""

    @abstractmethod
    def set_normalization(self, state_mean: Any, state_std: Any, action_mean: Any, action_std: Any) -> None:
        """Set the normalisation statistics of state (S,) and action (A,) (array-likes, raw units); they are
        buffers, saved with the weights."""

    # ----- gaze --------------------------------------------------------------------------------------------
    @abstractmethod
    def geometry(self, camera: str) -> PatchGeometry:
        """The image geometry of `camera` as the policy sees it: stored frame -> input image -> patch grid;
        gaze priors are mapped onto this grid."""

    @abstractmethod
    def resolve_layers(self, layers: Sequence[int] | None) -> tuple[int, ...]:
        """Validated, sorted attention layer ids (None: the policy's default; negative ids count from the
        end); raises ValueError naming the bad ids."""

    @abstractmethod
    def gaze_probe_spec(
        self,
        camera: str,
        layers: Sequence[int] | None = None,
        queries: QuerySet = QuerySet.ACTION,
        text_mask: Tensor | None = None,
    ) -> ProbeSpec:
        """Which attention the gaze term reads: the `queries` tokens' attention to `camera`'s N patch tokens
        (row-major over `geometry(camera)`'s grid) on `resolve_layers(layers)`; the policy's attention code
        calls `gazereg.attention.tap` for these layers. The action queries need no batch; a query set with
        the instruction's tokens needs the batch's `text_mask` (B, L) bool and returns (B, n_queries) query
        weights that leave out padding. Callers go through `probe_spec`, which calls this with (camera,
        layers) only for the action queries, so a policy giving just those may keep that signature."""

    def probe_spec(
        self,
        camera: str,
        layers: Sequence[int] | None = None,
        queries: QuerySet = QuerySet.ACTION,
        text_mask: Tensor | None = None,
    ) -> ProbeSpec:
        """`gaze_probe_spec` for query set `queries`; raises UsageError (one line) for a query set the policy
        does not list in `gaze_query_sets`, before any forward."""
        queries = QuerySet(queries)
        if queries is QuerySet.ACTION:
            return self.gaze_probe_spec(camera, layers)
        self.require_query_set(queries)
        return self.gaze_probe_spec(camera, layers, queries, text_mask)

    @classmethod
    def require_query_set(cls, queries: QuerySet) -> None:
        """UsageError (one line) unless this policy type gives query set `queries` (`gaze_query_sets`)."""
        if QuerySet(queries) not in cls.gaze_query_sets:
            can = ", ".join(q.value for q in QuerySet if q in cls.gaze_query_sets)
            raise UsageError(
                f"the {cls.config_class.type} policy cannot regularize the attention of "
                f"{QuerySet(queries).value} queries; it gives {can} only"
            )

    def layer_module(self, layer: int) -> nn.Module:
        """The module computing transformer layer `layer` (a `resolve_layers` id) for every token: its output
        is the (B, T, D) token features after that layer (or a tuple that starts with them), positions as in
        `gaze_probe_spec`'s keys. Optional: only the location control (`--gaze.target features`,
        gazereg.training.location) reads it; the default says the policy does not expose its layers."""
        raise NotImplementedError(
            f"the {self.name} policy does not expose its layers' token features (Policy.layer_module), which "
            "--gaze.target features reads"
        )

    # ----- training and inference --------------------------------------------------------------------------
    @abstractmethod
    def forward(
        self, batch: Mapping[str, Tensor], generator: torch.Generator | None = None, shift: int = 0
    ) -> tuple[Tensor, dict[str, Any]]:
        """Training loss on a batch (module docstring): (scalar loss, info with 'loss/action' a float).
        Every random draw comes from `generator`; `shift` is the random-shift augmentation in input pixels."""

    @abstractmethod
    def select_action(
        self,
        observation: Mapping[str, Any],
        instruction: str | Sequence[str],
        generator: torch.Generator | None = None,
    ) -> np.ndarray:
        """The next action (A,) float32 for observation {'state': (S,), '<camera>': uint8 (H, W, 3), ...}
        (or (B, A) for batched observations); no gaze is involved."""

    def reset(self) -> None:
        """Forget per-episode state (queued actions); called at every episode start. Default: nothing."""

    # ----- save and load -----------------------------------------------------------------------------------
    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    @classmethod
    @abstractmethod
    def load_tokenizer(cls, path: Path) -> PolicyTokenizer:
        """The tokenizer saved as `path` (tokenizer.json, the tokenizer's `to_dict()`)."""

    def write_pretrained(self, directory: str | Path, state_dict: Mapping[str, Tensor] | None = None) -> None:
        """Write model.safetensors (`state_dict`, default the policy's own), config.json and tokenizer.json
        into an existing folder (the folder not atomic: `save_pretrained` and training checkpoints wrap it); equal
        weights give byte-identical files, with the mode an ordinary write gives."""
        d = Path(directory)
        sd = {k: v.detach().contiguous().cpu() for k, v in (state_dict or self.state_dict()).items()}
        save_safetensors(sd, d / MODEL_FILE, metadata={"format": "pt", "policy": self.name})
        (d / CONFIG_FILE).write_text(
            json.dumps({"type": self.name, **self.config.to_dict()}, indent=2, sort_keys=True) + "\n"
        )
        (d / TOKENIZER_FILE).write_text(json.dumps(self.tokenizer.to_dict(), indent=1) + "\n")

    def save_pretrained(self, directory: str | Path, state_dict: Mapping[str, Tensor] | None = None) -> Path:
        """Atomically write the policy (weights, normalisation stats, config, tokenizer) to `directory`."""
        with atomic_dir(directory) as tmp:
            self.write_pretrained(tmp, state_dict)
        return Path(directory)

    @classmethod
    def from_pretrained(cls: type[P], directory: str | Path, map_location: str | torch.device = "cpu") -> P:
        """The policy saved in `directory`, on `map_location`, in eval mode; a damaged weights file is a
        `DamagedFile` (one line naming it)."""
        d = Path(directory)
        for f in (MODEL_FILE, CONFIG_FILE, TOKENIZER_FILE):
            if not (d / f).exists():
                raise FileNotFoundError(f"{d} is not a saved {cls.config_class.type} policy: {f} is missing")
        cfg_dict = json.loads((d / CONFIG_FILE).read_text())
        if cfg_dict.get("type") != cls.config_class.type:
            raise ValueError(f"{d} holds a {cfg_dict.get('type')!r} policy, not {cls.config_class.type!r}")
        policy = cls(cls.config_class.from_dict(cfg_dict), cls.load_tokenizer(d / TOKENIZER_FILE))
        policy.load_state_dict(load_safetensors(d / MODEL_FILE, device=str(map_location)))
        return policy.to(map_location).eval()
