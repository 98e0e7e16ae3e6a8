"""Which image plane a gray-level segmenter works on, and exposure normalisation (issue 15, item 4).

The thesis works on the gray image. An orange ball on grey stone has almost the stone's gray
level (gray = 0.30 R + 0.59 G + 0.11 B), so its outline all but vanishes there, and on a dim
scene every gradient falls below the fixed edge thresholds. Two remedies:

* ``best_plane`` -- with the object's colour known, the plane (B, G, R, gray or HSV saturation)
  in which the object differs most from the background, in units of the background's own
  spread in that plane (speckle, texture): contrast |object - median| / (1.4826 MAD).
* ``normalize_exposure`` -- stretch the plane so that its bright end (99th percentile) is 255:
  thresholds in gray levels then mean the same on a dim and a bright exposure.
"""

from __future__ import annotations

import cv2
import numpy as np

PLANES = ("blue", "green", "red", "gray", "saturation")


def plane(img_bgr: np.ndarray, name: str) -> np.ndarray:
    """One plane (uint8 HxW) of a BGR image by name (see :data:`PLANES`)."""
    if img_bgr.ndim == 2:
        return img_bgr
    if name in ("blue", "green", "red"):
        return np.ascontiguousarray(img_bgr[..., PLANES.index(name)])
    if name == "saturation":
        return cv2.cvtColor(img_bgr, cv2.COLOR_BGR2HSV)[..., 1].copy()
    return cv2.cvtColor(img_bgr, cv2.COLOR_BGR2GRAY)


def _plane_value_of(color_bgr, name: str) -> float:
    px = np.uint8([[list(color_bgr)]])
    return float(plane(px, name)[0, 0])


def best_plane(img_bgr: np.ndarray, color_bgr) -> tuple[str, dict[str, float]]:
    """The plane where the object's colour stands out most from this image's background.

    Each plane is first exposure-normalised (:func:`normalize_exposure`), so the given colour
    (of a well-exposed view) compares with a dim view too. The background is the image itself
    (the ball covers a small share of it): its median and MAD per plane. Returns (name,
    contrast per plane).
    """
    if img_bgr.ndim == 2:
        return "gray", {"gray": 0.0}
    small = img_bgr[::4, ::4] if min(img_bgr.shape[:2]) >= 64 else img_bgr
    out = {}
    for name in PLANES:
        p = normalize_exposure(plane(np.ascontiguousarray(small), name)).astype(np.float32)
        med = float(np.median(p))
        mad = float(np.median(np.abs(p - med))) * 1.4826 + 1.0
        out[name] = abs(_plane_value_of(color_bgr, name) - med) / mad
    return max(out, key=out.get), out


def normalize_exposure(img: np.ndarray) -> np.ndarray:
    """Stretch a uint8 plane so that its 99th percentile becomes 255 (no change if already
    there)."""
    hist = cv2.calcHist([img], [0], None, [256], [0, 256]).ravel()
    cum = np.cumsum(hist)
    p99 = int(np.searchsorted(cum, 0.99 * cum[-1]))
    if p99 >= 250 or p99 <= 0:
        return img
    return cv2.convertScaleAbs(img, alpha=255.0 / p99)
