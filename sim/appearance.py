"""Surface looks of the simulated scene: colours, MuJoCo's builtin procedural textures or PNG files, and
random looks for domain randomisation."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prompose_grasp.errors import InvalidInputError, UnknownNameError

__all__ = ["BUILTIN_TEXTURES", "Appearance", "random_appearance"]

#: Procedural textures MuJoCo generates itself (no image file needed).
BUILTIN_TEXTURES = ("checker", "gradient", "flat", "noise")


@dataclass(frozen=True)
class Appearance:
    """Surface look. `texture` is None, one of `BUILTIN_TEXTURES`, or a PNG file path.

    Attributes:
        rgba: base colour (4,) in [0, 1]; with a texture, it tints it.
        rgb2: second colour of builtin textures (3,) in [0, 1].
        specular, shininess, reflectance: MuJoCo material terms in [0, 1].
        texrepeat: texture repetitions per metre (builtin) or per surface.
    """

    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    texture: str | None = None
    rgb2: tuple[float, float, float] = (0.3, 0.3, 0.3)
    specular: float = 0.3
    shininess: float = 0.3
    reflectance: float = 0.0
    texrepeat: tuple[float, float] = (4.0, 4.0)

    def __post_init__(self) -> None:
        rgba = np.asarray(self.rgba, dtype=np.float64)
        if rgba.shape != (4,) or not np.all((rgba >= 0) & (rgba <= 1)):
            raise InvalidInputError(f"rgba must be 4 numbers in [0, 1], got {self.rgba!r}")
        for key in ("specular", "shininess", "reflectance"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise InvalidInputError(f"Appearance.{key} must lie in [0, 1], got {getattr(self, key)}")
        if self.texture is not None and self.texture not in BUILTIN_TEXTURES:
            if not Path(self.texture).is_file():
                raise InvalidInputError(
                    f"texture {self.texture!r} is neither a builtin ({', '.join(BUILTIN_TEXTURES)}) "
                    "nor an image file"
                )


def random_appearance(rng: np.random.Generator, kind: str = "object") -> Appearance:
    """A randomised appearance for data generation.

    kind "object": saturated or muted colours, plastic to metal-like shine, sometimes a texture. kind "table":
    wood-, stone- or cloth-like builtin textures in plausible colours.
    """
    if kind not in ("object", "table"):
        raise UnknownNameError("appearance kind", kind, ("object", "table"))
    hsv = rng.uniform([0.0, 0.1, 0.25], [1.0, 0.9, 0.95])
    rgb = _hsv_to_rgb(*hsv)
    if kind == "object":
        texture = rng.choice(["none", "none", "none", "checker", "noise"])
        return Appearance(
            rgba=(*rgb, 1.0),
            texture=None if texture == "none" else str(texture),
            rgb2=tuple(np.clip(np.asarray(rgb) * rng.uniform(0.4, 0.9), 0, 1)),
            specular=float(rng.uniform(0.0, 0.8)),
            shininess=float(rng.uniform(0.0, 0.8)),
            texrepeat=(float(rng.uniform(2, 8)), float(rng.uniform(2, 8))),
        )
    base = np.array(_hsv_to_rgb(rng.uniform(0.02, 0.15), rng.uniform(0.1, 0.6), rng.uniform(0.3, 0.9)))
    if rng.random() < 0.3:  # grey/white/black tables exist too
        base = np.full(3, rng.uniform(0.15, 0.95))
    return Appearance(
        rgba=(*base, 1.0),
        texture=str(rng.choice(["checker", "gradient", "noise", "flat"])),
        rgb2=tuple(np.clip(base * rng.uniform(0.6, 1.0), 0, 1)),
        specular=float(rng.uniform(0.0, 0.4)),
        shininess=float(rng.uniform(0.0, 0.5)),
        reflectance=float(rng.uniform(0.0, 0.1)),
        texrepeat=(float(rng.uniform(1, 12)), float(rng.uniform(1, 12))),
    )


def _hsv_to_rgb(h: float, s: float, v: float) -> tuple[float, float, float]:
    i = int(h * 6.0) % 6
    f = h * 6.0 - math.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]
