"""Colour helpers: chromaticity, distance to the object colour, hue masks and a region's
colour score.
"""

from __future__ import annotations

import cv2
import numpy as np

from nodes.contracts.cv_overloads import scalar_op

from ._params import ObjectSpec
from ._pixels import fast_median, masked_pixels


def chromaticity(img_bgr: np.ndarray) -> np.ndarray:
    """Normalised chromaticity (b, g, r) / (b + g + r) per pixel (float32, sums to 1).

    Invariant to the brightness of the illumination, so the lit and the shaded side of a
    matte ball have the same value.
    """
    f = np.asarray(img_bgr, np.float32)
    return f / np.maximum(f.sum(axis=-1, keepdims=True), 1.0)


#: Gray levels below which a pixel's chromaticity is sensor noise (its largest channel, 0-255).
DARK_LEVEL = 25


def dark_pixel_distance(color_bgr) -> float:
    """The colour distance given to a pixel darker than :data:`DARK_LEVEL`, whose chromaticity is
    noise.

    2 (no match) for an object of any colour that has one; 0 (a match) for a dark object -- one
    whose own colour is within twice that level of black (``black``, [30, 30, 30]): most of its
    pixels are that dark, and taking them for "not the object's colour" left only its highlight
    (never found).
    """
    return 0.0 if max(float(x) for x in color_bgr) < 2 * DARK_LEVEL else 2.0


def color_distance_map(img_bgr: np.ndarray, color_bgr) -> np.ndarray:
    """Per-pixel L1 distance of the normalised chromaticity to that of ``color_bgr`` (0-2,
    unitless).

    sum_c |x_c / S - r_c| = sum_c |x_c - r_c S| / S with S = x_b + x_g + x_r, computed with
    cv2 channel transforms (fast). Pixels darker than :data:`DARK_LEVEL` (chromaticity undefined
    in the noise) get :func:`dark_pixel_distance`: 2, or 0 for a dark object.
    """
    img = np.asarray(img_bgr)
    f = img.astype(np.float32)
    d = _chroma_distance(f, _channel_total(f), color_bgr).reshape(img.shape[:2])
    gray_max = cv2.max(cv2.max(img[..., 0], img[..., 1]), img[..., 2]).reshape(img.shape[:2])
    d[gray_max < DARK_LEVEL] = dark_pixel_distance(color_bgr)
    return d


_ONES_1x3 = np.ones((1, 3), np.float32)


def _channel_total(f: np.ndarray) -> np.ndarray:
    """max(S, 1), S = x_b + x_g + x_r, of a float32 BGR image (any size, 1x1 too)."""
    return scalar_op(cv2.max, cv2.transform(f, _ONES_1x3), 1.0)


def _chroma_distance(f: np.ndarray, total: np.ndarray, color_bgr) -> np.ndarray:
    """sum_c |x_c - r_c S| / S for a float32 BGR image ``f`` and its channel sum ``total`` = max(S,
    1)."""
    b, g, r = (float(x) for x in color_bgr)
    k = max(b + g + r, 1.0)
    ref = np.array([[b / k] * 3, [g / k] * 3, [r / k] * 3], np.float32)  # row c: r_c * (1, 1, 1)
    scaled = cv2.transform(f, ref)  # channel c = r_c * S
    return cv2.divide(cv2.transform(cv2.absdiff(f, scaled), _ONES_1x3), total)


def hue_mask(img_bgr: np.ndarray, hue_range_deg, min_saturation: int) -> np.ndarray:
    """uint8 0/255 mask of pixels whose hue is in the range (degrees, wrapping) and saturated."""
    hsv = cv2.cvtColor(img_bgr, cv2.COLOR_BGR2HSV)
    lo, hi = (float(x) % 360.0 / 2.0 for x in hue_range_deg)  # OpenCV hue is 0..180
    hch = hsv[..., 0]
    if lo <= hi:
        m = (hch >= lo) & (hch <= hi)
    else:
        m = (hch >= lo) | (hch <= hi)
    m &= hsv[..., 1] >= min_saturation
    return m.astype(np.uint8) * 255


def object_color_score(img_bgr: np.ndarray, mask: np.ndarray, obj: ObjectSpec) -> float | None:
    """How far the region's median colour is from the object's colour (0 = same; None = no colour
    set).

    For ``color_bgr`` it is the median chromaticity distance divided by the tolerance; for a hue
    range it is 1 - fraction of region pixels inside the range.
    """
    if obj.color_bgr is None and obj.hue_range_deg is None:
        return None
    sel = mask > 0
    if not sel.any():
        return float("inf")
    if obj.color_bgr is not None:
        dist = float(
            fast_median(color_distance_map(masked_pixels(img_bgr, sel)[None], obj.color_bgr))
        )
        return dist / obj.color_tolerance
    hm = hue_mask(img_bgr, obj.hue_range_deg, obj.min_saturation)
    return float(1.0 - (hm[sel] > 0).mean()) * 2.0  # 50 % outside the range -> score 1


def object_pixel_count(img_bgr: np.ndarray, mask: np.ndarray, obj: ObjectSpec) -> int:
    """How many pixels of the region ``mask`` have the object's colour (within ``color_tolerance``
    of ``color_bgr``, or inside the hue range); 0 when no colour is set."""
    sel = mask > 0
    if not sel.any():
        return 0
    if obj.color_bgr is not None:
        dist = color_distance_map(masked_pixels(img_bgr, sel)[None], obj.color_bgr)
        return int(np.count_nonzero(dist <= obj.color_tolerance))
    if obj.hue_range_deg is not None:
        return int(np.count_nonzero(hue_mask(img_bgr, obj.hue_range_deg, obj.min_saturation)[sel]))
    return 0
