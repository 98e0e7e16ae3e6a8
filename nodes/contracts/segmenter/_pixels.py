"""Pixel-level helpers of the segmenters: the image plane a method works on, structuring
elements, hole filling, masked pixels and a fast median.
"""

from __future__ import annotations

import functools
import math
from typing import Literal

import cv2
import numpy as np

from nodes.contracts.cv_overloads import scalar_op

Channel = Literal["gray", "saturation", "color"]


def to_channel(img_bgr: np.ndarray, channel: str) -> np.ndarray:
    """The image plane a gray-level method works on.

    ``gray`` (the thesis), ``saturation`` (HSV S: a coloured ball on a neutral, textured table
    stands out while the texture and the shadow mostly vanish) or ``color`` (the BGR image
    itself; OpenCV's Canny then takes the strongest channel gradient).
    """
    if img_bgr.ndim == 2 or channel == "color":
        return img_bgr
    if channel == "saturation":
        return cv2.cvtColor(img_bgr, cv2.COLOR_BGR2HSV)[..., 1].copy()
    return cv2.cvtColor(img_bgr, cv2.COLOR_BGR2GRAY)


def structuring_element(size_px: int) -> np.ndarray:
    """Elliptical structuring element of the given diameter (px, >= 1); do not modify it
    (shared)."""
    return _ellipse_element(max(1, int(size_px)))


@functools.lru_cache(maxsize=64)
def _ellipse_element(size_px: int) -> np.ndarray:
    el = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px))
    el.flags.writeable = False
    return el


def fill_holes(mask: np.ndarray, max_area_px: float | None = None) -> np.ndarray:
    """Fill the holes of a uint8 0/255 mask (flood fill of the background from the border).

    Parameters
    ----------
    mask : uint8 HxW, 0/255
    max_area_px : float, optional
        Fill only holes up to this area (px). A closed outline much larger than any ball --
        the edge of a rectified image's valid area, a table edge -- then does not swallow the
        whole scene.
    """
    h, w = mask.shape
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    cv2.floodFill(padded, None, (0, 0), 128)  # 4-connected background reachable from the border
    holes = scalar_op(cv2.compare, padded[1:-1, 1:-1], 0, cv2.CMP_EQ)
    if max_area_px is not None and cv2.countNonZero(holes) > max_area_px:
        # Drop the holes larger than max_area_px (4-connected components). Cheaper than
        # labelling the whole image: only outlines whose area bound exceeds the limit are
        # measured exactly, by a flood fill (marked 1 = kept, 0 = dropped); a big hole may
        # surround small ones, which stay (they are separate components).
        while True:
            cnts, _ = cv2.findContours(
                scalar_op(cv2.compare, holes, 255, cv2.CMP_EQ),
                cv2.RETR_EXTERNAL,
                cv2.CHAIN_APPROX_NONE,
            )
            # Pixel count <= polygon area + boundary points + 1 (Pick's theorem).
            big = [c for c in cnts if cv2.contourArea(c) + len(c) + 1 > max_area_px]
            if not big:
                break
            for c in big:
                x, y = (int(v) for v in c[0, 0])
                if holes[y, x] != 255:
                    continue
                if cv2.floodFill(holes, None, (x, y), 1, flags=4)[0] > max_area_px:
                    cv2.floodFill(holes, None, (x, y), 0, flags=4)
        holes = scalar_op(cv2.compare, holes, 0, cv2.CMP_GT)
    return cv2.bitwise_or(mask, holes)


def max_hole_area(r_range_px: tuple[float, float]) -> float:
    """Largest hole worth filling: a ball of the largest expected radius plus its shadow (px)."""
    return 4.0 * math.pi * r_range_px[1] ** 2


def fast_median(a: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """``np.median`` of a 1-D array (``axis=None``, flattened) or of a 2-D array along axis 0.

    Same values as ``np.median`` (the mean of the two middle values for an even count; float64
    for integers) with a single ``np.partition`` -- ``np.median``'s own overhead dominates on
    the few hundred values per call here.
    """
    a = np.asarray(a)
    if axis is None:
        a = a.ravel()
    n = a.shape[0]
    if n == 0:
        return np.median(a, axis=0)
    k = n // 2
    if a.dtype.kind in "iub":
        a = a.astype(np.float64)
    if n % 2:
        return np.partition(a, k, axis=0)[k]
    p = np.partition(a, (k - 1, k), axis=0)
    return (p[k - 1] + p[k]) / 2


def _channels(img: np.ndarray) -> int:
    return 1 if img.ndim == 2 else img.shape[2]


def masked_pixels(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``img[mask]`` -- the pixels where ``mask`` is true, (N, C) for a colour image -- but fast.

    NumPy's boolean gather is ~25x slower per pixel when a pixel is C elements than when it
    is one, so a colour image is viewed as HxW elements of C bytes for the gather.
    """
    if img.ndim != 3 or img.shape[:2] != mask.shape:
        return img[mask]
    try:
        whole = img.view(np.dtype((np.void, img.shape[2] * img.itemsize)))[..., 0]
    except ValueError:  # pixels not contiguous in memory
        return img[mask]
    return whole[mask].view(img.dtype).reshape(-1, img.shape[2])
