"""``segmenter.otsu``: global gray-level threshold (Otsu's method).

Otsu's threshold splits a gray image into two classes. On a whole image the two classes are
usually table and wall, not ball and table, so the threshold is applied to the image's
difference from its *background*: a median filter wider than the largest expected ball
(the ball vanishes from it) on whole images, the median of the window's border in the small
window around a detected ball. ``polarity`` says whether the ball is brighter or darker than
its background (``auto``: either -- the absolute difference). Holes are filled and an opening
removes speckle. ``channel: auto`` thresholds the plane (gray or HSV saturation) on which
Otsu's separability eta (between-class / total variance) is higher: a coloured ball on a
neutral or textured table separates in saturation, a white ball on a dark table in gray.
"""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np

from nodes.contracts.segmenter import (
    SegmenterParams,
    fill_holes,
    gaussian_blur,
    max_hole_area,
    segmenter,
    structuring_element,
    to_channel,
)
from stereograph.api import Field


class OtsuParams(SegmenterParams):
    """Parameters of ``segmenter.otsu`` (plus the common ones)."""

    polarity: Literal["auto", "bright", "dark"] = Field(
        "auto", description="Is the ball brighter or darker than its background (auto = either)."
    )
    channel: Literal["auto", "gray", "saturation"] = Field(
        "auto",
        description="Image plane to threshold: gray, HSV saturation, or auto = the more "
        "separable one (name).",
    )
    blur_sigma_px: float = Field(
        2.0, ge=0, le=10, description="Gaussian smoothing before thresholding (px)."
    )
    flatten_background: bool = Field(
        True,
        description="Threshold the difference from a median-filtered background instead of raw "
        "gray (bool).",
    )
    open_px: int | None = Field(
        None,
        ge=1,
        le=101,
        description="Opening element diameter (px); None = 0.3 x smallest expected radius.",
    )


def otsu_separability(img: np.ndarray) -> float:
    """Otsu's effectiveness measure eta = between-class / total variance of a uint8 image (0..1)."""
    hist = np.bincount(img.ravel(), minlength=256).astype(np.float64)
    p = hist / max(hist.sum(), 1.0)
    levels = np.arange(256.0)
    omega = np.cumsum(p)
    mu = np.cumsum(p * levels)
    mu_t = mu[-1]
    var_t = float((p * (levels - mu_t) ** 2).sum())
    if var_t <= 0:
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        sb = (mu_t * omega - mu) ** 2 / (omega * (1.0 - omega))
    return float(np.nanmax(sb[:-1]) / var_t)


# cv2.medianBlur's 8-bit path for large kernels counts a window in 16-bit histograms: a window of
# more than 65535 pixels (255 x 255) fails its assertion on some images.
_MAX_MEDIAN_KSIZE = 255


def _odd_at_most(n: int) -> int:
    """The largest odd number <= ``n``."""
    return n if n % 2 else n - 1


def _median_background(gray: np.ndarray, k: int) -> np.ndarray:
    """Median-filtered background of a uint8 image with a k x k window (k odd); a window larger than
    OpenCV's 8-bit limit is taken on a copy shrunk by the needed factor, then scaled back."""
    if k <= _MAX_MEDIAN_KSIZE:
        return cv2.medianBlur(gray, k)
    f = math.ceil(k / _MAX_MEDIAN_KSIZE)
    h, w = gray.shape[:2]
    small = cv2.resize(gray, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
    ks = min(_MAX_MEDIAN_KSIZE, (k // f) | 1, _odd_at_most(min(small.shape)))
    return cv2.resize(cv2.medianBlur(small, max(ks, 3)), (w, h), interpolation=cv2.INTER_LINEAR)


def background_difference(
    gray: np.ndarray, params: OtsuParams, r_range_px, roi: bool
) -> np.ndarray:
    """The image's difference from its background (polarity applied), uint8."""
    if roi:
        border = np.concatenate([gray[0], gray[-1], gray[:, 0], gray[:, -1]])
        bg = np.full_like(gray, int(np.median(border)))
    else:
        k = int(2.2 * r_range_px[1]) | 1
        k = min(k, _odd_at_most(min(gray.shape)))
        bg = _median_background(gray, max(k, 3))
    if params.polarity == "bright":
        return cv2.subtract(gray, bg)
    if params.polarity == "dark":
        return cv2.subtract(bg, gray)
    return cv2.absdiff(gray, bg)


def otsu_mask(
    img_bgr: np.ndarray, params: OtsuParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball with an Otsu threshold of the gray image's difference from its background;
    give object.color_bgr (or wire `appearance`: learned from training truth), else look-alikes are
    refused as ambiguous.

    The mask (uint8 0/255) has the object class set to 255. Without object.color_bgr two round
    objects of similar size are refused as ambiguous (not found), and a ball touching another
    object cannot be split from it.
    """
    sigma = params.blur_sigma_px / scale
    planes = (
        ["gray", "saturation"]
        if params.channel == "auto" and img_bgr.ndim == 3
        else [params.channel]
    )
    best = None
    for ch in planes:
        g = to_channel(img_bgr, "gray" if ch == "auto" else ch)
        if sigma > 0.3:
            g = gaussian_blur(g, sigma)
        if params.flatten_background:
            g = background_difference(g, params, r_range_px, roi)
        eta = otsu_separability(g) if len(planes) > 1 else 1.0
        if best is None or eta > best[0]:
            best = (eta, g)
    gray = best[1]
    if params.flatten_background:
        _, m = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    else:
        _, m = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        polarity = params.polarity
        if polarity == "auto":  # the background is the class that dominates the border
            border = np.concatenate([m[0], m[-1], m[:, 0], m[:, -1]])
            polarity = "dark" if (border > 0).mean() > 0.5 else "bright"
        if polarity == "dark":
            m = cv2.bitwise_not(m)
    m = fill_holes(m, max_hole_area(r_range_px))
    o = params.open_px / scale if params.open_px else max(3.0, 0.3 * r_range_px[0])
    return cv2.morphologyEx(m, cv2.MORPH_OPEN, structuring_element(int(round(o)) | 1))


#: ``segmenter.otsu``: the node (the shared shell of nodes.contracts.segmenter around otsu_mask)
otsu = segmenter("segmenter.otsu", params=OtsuParams)(otsu_mask)
