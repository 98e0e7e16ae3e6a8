"""Surface appearance of the synthetic scenes: named colours and the table's repeating texture."""

from __future__ import annotations

import functools
from typing import Any

import cv2
import numpy as np

#: Named colours (BGR, 0..255) for balls and objects.
COLORS: dict[str, tuple[int, int, int]] = {
    "orange": (20, 120, 245),
    "red": (40, 40, 210),
    "green": (60, 170, 50),
    "blue": (200, 90, 30),
    "yellow": (30, 210, 230),
    "white": (235, 235, 235),
    "purple": (150, 50, 120),
    "grey": (128, 128, 128),
    "black": (30, 30, 30),
    "pink": (180, 120, 250),
    "cyan": (210, 200, 40),
}


def color_bgr(color: Any) -> np.ndarray:
    """Albedo (0..1, BGR float) of a colour name or a ``[b, g, r]`` triple (0..255)."""
    if isinstance(color, str):
        if color not in COLORS:
            raise ValueError(f"unknown colour {color!r}; use one of {sorted(COLORS)} or [b, g, r]")
        color = COLORS[color]
    c = np.asarray(color, dtype=float).reshape(3)
    if np.any(c < 0) or np.any(c > 255):
        raise ValueError(f"colour {list(c)} is out of 0..255")
    return c / 255.0


_TEX_CM = 100.0  # the texture tile covers 100 x 100 cm and repeats
_TEX_PX = 2048


@functools.lru_cache(maxsize=4)
def _table_texture(seed: int) -> np.ndarray:
    """A wood-like BGR float32 texture tile (0..1): grain + mottling + fine speckle."""
    rng = np.random.default_rng(seed)
    n = _TEX_PX

    def noise(cells):
        small = rng.standard_normal((cells, cells)).astype(np.float32)
        return cv2.resize(small, (n, n), interpolation=cv2.INTER_CUBIC)

    yy = np.arange(n, dtype=np.float32)[:, None] * (_TEX_CM / n)
    # tone = 1 + 0.10 noise(8) + 0.10 grain + 0.06 noise(200) + 0.05 noise(700), in that order
    # (the draws and the float32 sums are those of the one-line expression), computed in place:
    # every temporary of that expression is a fresh 16 MB array, and this runs before any pair.
    grain = noise(12)  # planks' grain along x: sin(2 pi (y / 0.9 + 0.8 noise(12)))
    grain *= np.float32(0.8)
    grain += yy / np.float32(0.9)
    grain *= np.float32(2 * np.pi)
    np.sin(grain, out=grain)
    tone = np.float32(0.10) * noise(8)
    tone += np.float32(1.0)
    grain *= np.float32(0.10)
    tone += grain
    for cells, weight in ((200, 0.06), (700, 0.05)):
        fine = noise(cells)
        fine *= np.float32(weight)
        tone += fine
    base = np.array([0.42, 0.58, 0.70], dtype=np.float32)  # light wood, BGR
    # tone[..., None] * base, one channel at a time: the broadcast product's inner loop is 3 long
    # (~0.1 s for the 48 MB tile, before any pair renders); these are the same float32 products.
    tex = np.empty((n, n, 3), dtype=np.float32)
    for c in range(3):
        np.multiply(tone, base[c], out=tex[..., c])
    np.clip(tex, 0.0, 1.0, out=tex)
    tex.setflags(write=False)
    return tex


def _sample_texture(tex: np.ndarray, x_cm: np.ndarray, y_cm: np.ndarray) -> np.ndarray:
    scale = _TEX_PX / _TEX_CM
    n = x_cm.size
    cols = 1024  # remap wants maps smaller than 32767 on each side
    pad = (-n) % cols
    # The tile is centred on the table origin so that its seams (at +-50 cm) stay out of view.
    mx = np.pad(((x_cm + _TEX_CM / 2) * scale).astype(np.float32), (0, pad)).reshape(-1, cols)
    my = np.pad(((y_cm + _TEX_CM / 2) * scale).astype(np.float32), (0, pad)).reshape(-1, cols)
    out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return out.reshape(-1, 3)[:n].astype(float)
