"""Simulated eye-hand coordination (`visuomotor`): a stand-in for an eye tracker in simulated demonstrations.

People manipulating objects look at where the hand is going next, not at the hand: the eyes fixate the object
before the hand reaches it, stay until the grasp is secured, then jump (a saccade) to where the object has to
go and wait there for the hand (Land & Hayhoe 2001; Johansson et al. 2001, "Eye-hand coordination in object
manipulation"). This source replays that policy on an episode collected in simulation, from the per-frame
facts `gazereg collect` stores (projected object/goal positions, contact and success events).

Targets. Per task, a sequence of points the hand visits: `("obj", "goal")` (the object, then the place or
goal region) for most tasks, including those without a grasp (button, drawer, door, window: the part the hand
pushes or pulls, then where it has to go); `("goal",)` for reach tasks, which have no object to act on.
`targets=` overrides the sequence (any point with `<name>_uv.<camera>` and `<name>_pos` extras). An episode
whose meta names its own sequence (`meta["gaze_targets"]`, as Gym-Aloha's collector stores: the cube, then the
hand-over point; the peg, the socket, then the meeting point) is fixated in that order when `targets=` is not
given.

Timing. The hand arrives at the object at the first frame with gripper contact (or, in an episode without
contact, with the gripper within `arrive_radius` of it; where the episode records which hand acts on which
object, a `contact.<name>` extra, bool (T,), the first frame of that contact instead: two hands, two objects),
and at the goal at the first success (or the object/hand within `arrive_radius` of
the goal). The eyes switch from target k-1 to target k at
    s_k = max(arrive_{k-1} + dwell, arrive_k - lead)
so they stay on the object until the hand has it (plus `dwell_s`), and are on the next target at least
`lead_time_s` before the hand gets there whenever the transport is longer than that. A target the hand never
reaches is fixated to the end. Saccades move linearly over `saccade_s`.

Noise. Fixations jitter (an AR(1) process, std `jitter` in normalised image units, correlation `jitter_rho`
per frame); blinks occur at `blink_rate_hz` and last `blink_s` (frames invalid); single samples drop out with
probability `missing_rate`; frames whose gaze point is outside the image are invalid too. Everything is
deterministic per (seed, episode seed, task), and the same for every camera of an episode.

Heatmaps: a Gaussian of std `sigma` (a fraction of the map width; GLC's ground truth is 3.2 cells of 64, 0.05)
around the gaze point, via `gazereg.heatmaps.heatmaps_from_points`.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from gazereg.data.store import Episode
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.heatmaps import heatmaps_from_points
from gazereg.runtime.errors import UsageError

# Tasks where the hand has no object to act on: the eyes go straight to the goal.
GOAL_ONLY_TASKS = frozenset({"reach-v3", "reach-wall-v3"})
DEFAULT_FPS = 80.0  # Meta-World: 5 physics steps of 2.5 ms per control step


@dataclass(frozen=True)
class GazeTrace:
    """Per-frame gaze of one episode in one camera.

    uv: float32 (T, 2) normalised (u right, v down), NaN where invalid.
    valid: bool (T,).
    target: int (T,) index into `targets` of the fixated target (the destination during a saccade).
    targets: the target names. arrivals / switches: frame of the hand's arrival at / the saccade to each target.
    """

    uv: np.ndarray
    valid: np.ndarray
    target: np.ndarray
    targets: tuple[str, ...]
    arrivals: tuple[int, ...]
    switches: tuple[int, ...]


@dataclass(frozen=True)
class VisuomotorParams(GazeSourceParams):
    """Parameters of simulated eye-hand coordination (see the module docstring for the model).

    lead_time_s: the eyes reach each target at least this long before the hand (when the hand's approach takes
        longer than this); seconds.
    dwell_s: how long the eyes stay on a target after the hand arrives there; seconds.
    saccade_s: duration of a saccade; seconds.
    jitter: std of fixational jitter, normalised image units (0.01 is about 1 px at 96 px).
    jitter_rho: frame-to-frame correlation of the jitter (0: white noise).
    blink_rate_hz: blinks per second (frames during a blink are invalid); 0 disables.
    blink_s: duration of a blink; seconds.
    missing_rate: probability that a single frame's sample is missing.
    sigma: heatmap Gaussian std as a fraction of the heatmap width.
    arrive_radius: the hand "arrives" within this distance of a target (metres).
    targets: target sequence, or None for the task's default (see GOAL_ONLY_TASKS).
    fps: frames per second of the episodes; None reads episode.meta["fps"] (Meta-World: 80).
    seed: random seed (combined with the episode's seed and task).
    """

    name: ClassVar[str] = "visuomotor"
    lead_time_s: float = 1.0
    dwell_s: float = 0.05
    saccade_s: float = 0.04
    jitter: float = 0.008
    jitter_rho: float = 0.7
    blink_rate_hz: float = 0.0
    blink_s: float = 0.12
    missing_rate: float = 0.0
    sigma: float = 0.05
    arrive_radius: float = 0.03
    targets: tuple[str, ...] | None = None
    fps: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for k in (
            "lead_time_s",
            "dwell_s",
            "saccade_s",
            "jitter",
            "blink_rate_hz",
            "blink_s",
            "arrive_radius",
        ):
            if not getattr(self, k) >= 0:
                raise UsageError(f"{k} must be >= 0, got {getattr(self, k)}")
        if not 0 <= self.missing_rate <= 1 or not 0 <= self.jitter_rho < 1:
            raise UsageError(
                f"need 0 <= missing_rate <= 1 and 0 <= jitter_rho < 1, got {self.missing_rate}, {self.jitter_rho}"
            )
        if not self.sigma > 0:
            raise UsageError(f"sigma must be > 0 (a fraction of the heatmap width), got {self.sigma}")
        if self.fps is not None and not self.fps > 0:
            raise UsageError(f"fps must be > 0, got {self.fps}")


@register_gaze_source(VisuomotorParams)
class VisuomotorGaze:
    """Gaze from simulated eye-hand coordination (see the module docstring for the model and
    `VisuomotorParams` for its parameters)."""

    name = "visuomotor"

    def __init__(self, params: VisuomotorParams = VisuomotorParams()):
        p = params
        self.params = params
        self.lead_time_s, self.dwell_s, self.saccade_s = (
            float(p.lead_time_s),
            float(p.dwell_s),
            float(p.saccade_s),
        )
        self.jitter, self.jitter_rho = float(p.jitter), float(p.jitter_rho)
        self.blink_rate_hz, self.blink_s = float(p.blink_rate_hz), float(p.blink_s)
        self.missing_rate = float(p.missing_rate)
        self.sigma, self.arrive_radius = float(p.sigma), float(p.arrive_radius)
        self.targets = tuple(p.targets) if p.targets is not None else None
        self.fps = None if p.fps is None else float(p.fps)
        self.seed = int(p.seed)

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "lead_time_s": self.lead_time_s,
            "dwell_s": self.dwell_s,
            "saccade_s": self.saccade_s,
            "jitter": self.jitter,
            "jitter_rho": self.jitter_rho,
            "blink_rate_hz": self.blink_rate_hz,
            "blink_s": self.blink_s,
            "missing_rate": self.missing_rate,
            "sigma": self.sigma,
            "arrive_radius": self.arrive_radius,
            "targets": list(self.targets) if self.targets is not None else None,
            "fps": self.fps,
            "seed": self.seed,
        }

    # ----- the model --------------------------------------------------------------------------------------
    def targets_for(self, episode: Episode) -> tuple[str, ...]:
        if self.targets is not None:
            return self.targets
        if "gaze_targets" in episode.meta:
            return tuple(str(t) for t in episode.meta["gaze_targets"])
        return ("goal",) if episode.task in GOAL_ONLY_TASKS else ("obj", "goal")

    def _extra(self, episode: Episode, key: str) -> np.ndarray:
        if key not in episode.extras:
            raise UsageError(
                f"episode {episode.index} ({episode.task}) has no extra {key!r}, which the visuomotor gaze source "
                f"needs; it reads the simulator facts that `gazereg collect` stores (has: {sorted(episode.extras)})"
            )
        return np.asarray(episode.extras[key])

    def _arrival(self, episode: Episode, name: str, previous: tuple[str, ...]) -> int:
        """First frame at which the hand arrives at target `name` (T if never)."""
        T = episode.length
        hand = self._extra(episode, "hand_pos").astype(np.float64)
        pos = self._extra(episode, f"{name}_pos").astype(np.float64)
        if name == "goal":
            # Success after action t shows from frame t + 1 on; the carried object (or the hand) reaches it.
            success = (
                self._extra(episode, "success").astype(bool)
                if "success" in episode.extras
                else np.zeros(T, bool)
            )
            hit = np.zeros(T, bool)
            hit[1:] = success[:-1]
            carried = self._extra(episode, f"{previous[-1]}_pos").astype(np.float64) if previous else hand
            hit |= np.linalg.norm(carried - pos, axis=-1) < self.arrive_radius
        else:
            # The gripper touching the object; the gripper coming within arrive_radius only when it never does
            # (hovering over an object is not having it).
            own = f"contact.{name}"  # the hand that acts on this object touching it (Gym-Aloha: two hands)
            if own in episode.extras:
                hit = np.asarray(episode.extras[own]).astype(bool)
                return int(np.argmax(hit)) if hit.any() else T
            hit = np.zeros(T, bool)
            for event in ("contact", "grasp"):
                if event in episode.extras:
                    hit |= np.asarray(episode.extras[event]).astype(bool)
            if not hit.any():
                hit = np.linalg.norm(hand - pos, axis=-1) < self.arrive_radius
        return int(np.argmax(hit)) if hit.any() else T

    def trace(self, episode: Episode, camera: str) -> GazeTrace:
        """The per-frame gaze point of `episode` in `camera` (see GazeTrace)."""
        T = episode.length
        fps = self.fps or float(episode.meta.get("fps", DEFAULT_FPS))
        names = self.targets_for(episode)
        uv_t = np.stack(
            [self._extra(episode, f"{n}_uv.{camera}").astype(np.float64) for n in names]
        )  # (K, T, 2)
        arrivals = [self._arrival(episode, n, names[:k]) for k, n in enumerate(names)]
        lead, dwell = round(self.lead_time_s * fps), round(self.dwell_s * fps)
        switches = [0]
        for k in range(1, len(names)):
            s = max(arrivals[k - 1] + dwell, arrivals[k] - lead, switches[-1] + 1)
            switches.append(min(s, T))
        target = np.zeros(T, dtype=np.int64)
        for k, s in enumerate(switches):
            target[s:] = k
        uv = uv_t[target, np.arange(T)]  # (T, 2): the fixated target's position in each frame
        n_sac = max(1, round(self.saccade_s * fps))
        for k in range(1, len(names)):
            s = switches[k]
            if s >= T:
                continue
            start = uv_t[k - 1, max(s - 1, 0)]
            for j in range(min(n_sac, T - s)):
                a = (j + 1) / (n_sac + 1)
                uv[s + j] = (1 - a) * start + a * uv_t[k, s + j]

        rng = np.random.default_rng(
            [
                self.seed,
                int(episode.meta.get("seed", episode.index)) & 0xFFFFFFFF,
                zlib.crc32(episode.task.encode()),
            ]
        )
        noise = rng.normal(0.0, 1.0, size=(T, 2))
        jit = np.empty((T, 2))
        jit[0] = noise[0]
        c = np.sqrt(1 - self.jitter_rho**2)
        for t in range(1, T):
            jit[t] = self.jitter_rho * jit[t - 1] + c * noise[t]
        uv = uv + self.jitter * jit
        valid = np.isfinite(uv).all(-1) & (uv >= 0).all(-1) & (uv <= 1).all(-1)
        drop = rng.random(T) < self.missing_rate
        if self.blink_rate_hz > 0:
            starts = rng.random(T) < self.blink_rate_hz / fps
            length = max(1, round(self.blink_s * fps))
            for t in np.flatnonzero(starts):
                drop[t : t + length] = True
        valid &= ~drop
        uv[~valid] = np.nan
        return GazeTrace(
            uv=uv.astype(np.float32),
            valid=valid,
            target=target,
            targets=names,
            arrivals=tuple(arrivals),
            switches=tuple(switches),
        )

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        tr = self.trace(episode, camera)
        h, w = size
        heat, valid = heatmaps_from_points(tr.uv, (h, w), sigma=self.sigma * w, valid=tr.valid)
        return heat.numpy().astype(np.float32), valid.numpy().astype(bool)
