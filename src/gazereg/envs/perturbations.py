"""Visual perturbations for robustness evaluation: lighting changes and sensor noise.

A `Perturbation` is a `Lighting` change (applied to the render-only model at reset: the physics, the state,
the actions and the success test never see it) plus `SensorNoise` (applied to each rendered image, after
rendering, with a generator seeded per episode). Both are frozen dataclasses, so a perturbation is a value:
it can be stored in a config, compared and composed (`a + b`).

Named perturbations with a severity in [0, 1] (0 is the identity; 1 is strong but the task stays visible):

    name              what changes (at severity s)
    dim               every light (and the headlight) at (1 - 0.75 s) of its intensity
    bright            every light at (1 + s) of its intensity
    tint              light colour multiplied by (1, 1 - 0.35 s, 1 - 0.7 s): warm, orange light
    light_direction   directional lights turned 180 s degrees about the vertical and 40 s degrees lower
    ambient           0.4 s added to every light's ambient term: flat, washed-out shading
    headlight         the camera headlight at (1 - s) of its intensity
    gaussian_noise    additive Gaussian pixel noise with std 0.12 s of the full range (30 grey levels at s=1)
    salt_pepper       a fraction 0.08 s of the pixels set to black or white

`make_perturbation("dim", 0.5)`, `parse_perturbation("dim:0.5+gaussian_noise:0.3")`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Lighting:
    """A change of the scene's lights relative to the task's own lighting (identity by default).

    intensity: scales the diffuse, specular and ambient terms of every light and of the headlight.
    color: multiplies the diffuse colour (r, g, b) of every light and of the headlight.
    azimuth_deg: turns every light's direction about the world's vertical axis.
    elevation_deg: changes every light's elevation (positive: from higher up), kept within [5, 90] degrees.
    ambient: added to every light's ambient term (all channels).
    headlight: scales the headlight's diffuse, specular and ambient terms (on top of `intensity`).
    """

    intensity: float = 1.0
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    azimuth_deg: float = 0.0
    elevation_deg: float = 0.0
    ambient: float = 0.0
    headlight: float = 1.0

    def __post_init__(self) -> None:
        if self.intensity < 0 or self.headlight < 0 or self.ambient < 0 or min(self.color) < 0:
            raise ValueError(f"lighting factors must be non-negative: {self}")
        if len(self.color) != 3:
            raise ValueError(f"color must be (r, g, b), got {self.color}")

    @property
    def is_identity(self) -> bool:
        return self == Lighting()

    def __add__(self, other: Lighting) -> Lighting:
        return Lighting(
            intensity=self.intensity * other.intensity,
            color=tuple(a * b for a, b in zip(self.color, other.color)),  # type: ignore[arg-type]
            azimuth_deg=self.azimuth_deg + other.azimuth_deg,
            elevation_deg=self.elevation_deg + other.elevation_deg,
            ambient=self.ambient + other.ambient,
            headlight=self.headlight * other.headlight,
        )

    def apply(self, model: Any, base: LightState) -> None:
        """Set the model's lights to `base` changed by this lighting (absolute: applying twice is the same)."""
        color = np.asarray(self.color, dtype=np.float64)
        k = self.intensity
        model.light_diffuse[:] = base.diffuse * k * color
        model.light_specular[:] = base.specular * k
        model.light_ambient[:] = base.ambient * k + self.ambient
        model.light_dir[:] = _turn(base.dir, self.azimuth_deg, self.elevation_deg)
        model.light_pos[:] = base.pos
        hk = k * self.headlight
        model.vis.headlight.diffuse[:] = base.head_diffuse * hk * color
        model.vis.headlight.specular[:] = base.head_specular * hk
        model.vis.headlight.ambient[:] = base.head_ambient * hk


def _turn(dirs: np.ndarray, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Rotate light directions (n, 3) about world z and change their elevation below the horizon."""
    if azimuth_deg == 0 and elevation_deg == 0:
        return dirs.copy()
    out = np.empty_like(dirs)
    for i, d in enumerate(dirs):
        n = float(np.linalg.norm(d)) or 1.0
        x, y, z = d / n
        az = math.atan2(y, x) + math.radians(azimuth_deg)
        el = math.degrees(math.asin(max(-1.0, min(1.0, -z))))  # degrees below the horizon (light points down)
        el = min(90.0, max(5.0, el + elevation_deg))
        c = math.cos(math.radians(el))
        out[i] = n * np.array([c * math.cos(az), c * math.sin(az), -math.sin(math.radians(el))])
    return out


@dataclass(frozen=True)
class LightState:
    """A snapshot of a model's lights, the base that `Lighting.apply` changes."""

    diffuse: np.ndarray
    specular: np.ndarray
    ambient: np.ndarray
    dir: np.ndarray
    pos: np.ndarray
    head_diffuse: np.ndarray
    head_specular: np.ndarray
    head_ambient: np.ndarray

    @classmethod
    def capture(cls, model: Any) -> LightState:
        h = model.vis.headlight
        return cls(
            diffuse=np.array(model.light_diffuse, dtype=np.float64),
            specular=np.array(model.light_specular, dtype=np.float64),
            ambient=np.array(model.light_ambient, dtype=np.float64),
            dir=np.array(model.light_dir, dtype=np.float64),
            pos=np.array(model.light_pos, dtype=np.float64),
            head_diffuse=np.array(h.diffuse, dtype=np.float64),
            head_specular=np.array(h.specular, dtype=np.float64),
            head_ambient=np.array(h.ambient, dtype=np.float64),
        )


@dataclass(frozen=True)
class SensorNoise:
    """Pixel noise on rendered images (uint8 in, uint8 out).

    gaussian_std: std of additive Gaussian noise as a fraction of the full range (0.1 = 25.5 grey levels).
    salt_pepper: fraction of pixels replaced by black or white (half each, all channels of the pixel).
    """

    gaussian_std: float = 0.0
    salt_pepper: float = 0.0

    def __post_init__(self) -> None:
        if self.gaussian_std < 0 or not 0 <= self.salt_pepper <= 1:
            raise ValueError(f"bad sensor noise: {self} (std >= 0, salt_pepper in [0, 1])")

    @property
    def is_identity(self) -> bool:
        return self.gaussian_std == 0 and self.salt_pepper == 0

    def __add__(self, other: SensorNoise) -> SensorNoise:
        return SensorNoise(
            gaussian_std=math.hypot(self.gaussian_std, other.gaussian_std),
            salt_pepper=1 - (1 - self.salt_pepper) * (1 - other.salt_pepper),
        )

    def apply(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A noisy copy of `image` (..., H, W, C) uint8; the input is never modified."""
        if image.dtype != np.uint8:
            raise ValueError(f"sensor noise applies to uint8 images, got {image.dtype}")
        if self.is_identity:
            return image
        out = image.astype(np.float32)
        if self.gaussian_std > 0:
            out += rng.normal(0.0, 255.0 * self.gaussian_std, size=out.shape).astype(np.float32)
        if self.salt_pepper > 0:
            u = rng.random(out.shape[:-1])
            out[u < self.salt_pepper / 2] = 0.0
            out[(u >= self.salt_pepper / 2) & (u < self.salt_pepper)] = 255.0
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class Perturbation:
    """Lighting + sensor noise, with a name for reports. `a + b` composes two perturbations."""

    lighting: Lighting = field(default_factory=Lighting)
    noise: SensorNoise = field(default_factory=SensorNoise)
    name: str = "clean"

    @property
    def is_identity(self) -> bool:
        return self.lighting.is_identity and self.noise.is_identity

    def __add__(self, other: Perturbation) -> Perturbation:
        names = [n for n in (self.name, other.name) if n != "clean"]
        return Perturbation(
            self.lighting + other.lighting, self.noise + other.noise, "+".join(names) or "clean"
        )

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "lighting": asdict(self.lighting), "noise": asdict(self.noise)}


def _dim(s: float) -> Perturbation:
    return Perturbation(lighting=Lighting(intensity=1 - 0.75 * s))


def _bright(s: float) -> Perturbation:
    return Perturbation(lighting=Lighting(intensity=1 + s))


def _tint(s: float) -> Perturbation:
    return Perturbation(lighting=Lighting(color=(1.0, 1 - 0.35 * s, 1 - 0.7 * s)))


def _direction(s: float) -> Perturbation:
    return Perturbation(lighting=Lighting(azimuth_deg=180 * s, elevation_deg=-40 * s))


def _ambient(s: float) -> Perturbation:
    return Perturbation(lighting=Lighting(ambient=0.4 * s))


def _headlight(s: float) -> Perturbation:
    return Perturbation(lighting=Lighting(headlight=1 - s))


def _gauss(s: float) -> Perturbation:
    return Perturbation(noise=SensorNoise(gaussian_std=0.12 * s))


def _salt_pepper(s: float) -> Perturbation:
    return Perturbation(noise=SensorNoise(salt_pepper=0.08 * s))


PERTURBATIONS: dict[str, Callable[[float], Perturbation]] = {
    "clean": lambda s: Perturbation(),
    "dim": _dim,
    "bright": _bright,
    "tint": _tint,
    "light_direction": _direction,
    "ambient": _ambient,
    "headlight": _headlight,
    "gaussian_noise": _gauss,
    "salt_pepper": _salt_pepper,
}
LIGHTING_PERTURBATIONS = ("dim", "bright", "tint", "light_direction", "ambient", "headlight")
NOISE_PERTURBATIONS = ("gaussian_noise", "salt_pepper")


def make_perturbation(name: str, severity: float = 1.0) -> Perturbation:
    """A named perturbation at `severity` in [0, 1] (see the module docstring for what each one does)."""
    if name not in PERTURBATIONS:
        raise KeyError(f"unknown perturbation {name!r}; available: {sorted(PERTURBATIONS)}")
    if not 0 <= severity <= 1:
        raise ValueError(f"severity must be in [0, 1], got {severity}")
    p = PERTURBATIONS[name](float(severity))
    label = "clean" if name == "clean" or severity == 0 else f"{name}:{severity:g}"
    return replace(p, name=label)


def parse_perturbation(spec: str) -> Perturbation:
    """'dim:0.5+gaussian_noise:0.3' -> the composed perturbation (severity defaults to 1; '' is clean)."""
    out = Perturbation()
    for part in filter(None, (p.strip() for p in spec.split("+"))):
        name, _, sev = part.partition(":")
        try:
            severity = float(sev) if sev else 1.0
        except ValueError as e:
            raise ValueError(f"bad severity {sev!r} in perturbation {spec!r}") from e
        out = out + make_perturbation(name.strip(), severity)
    return out
