"""``segmenter.edge_morph``: the thesis's segmentation -- edges, morphology, largest region.

Edges (Canny or a Sobel magnitude threshold on the smoothed gray image) are dilated to
close gaps in the outline, the holes are filled (a closed outline becomes a solid region),
the result is eroded back and opened to cut thin structures (texture, shadow bridges), and
the largest plausible region is kept (see ``_pair`` for the shared plan: selection, refinement and
checks). Structuring-element sizes default to fractions of the smallest expected ball radius, which
comes from the calibration's focal length, the object's radius and the working range.
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
from nodes.contracts.segmenter._channel import best_plane, normalize_exposure, plane
from nodes.contracts.segmenter._pixels import Channel
from stereograph.api import Field


class EdgeMorphParams(SegmenterParams):
    """Parameters of ``segmenter.edge_morph`` (plus the common ones)."""

    edge_detector: Literal["canny", "sobel"] = Field("canny", description="Edge operator (name).")
    channel: Channel | Literal["auto"] = Field(
        "color",
        description="Image plane for edges: color (max over B,G,R), gray (thesis), saturation, "
        "or auto = "
        "the plane (B, G, R, gray, saturation) where object.color_bgr contrasts most with the "
        "background, per image (needs object.color_bgr; else color) (name).",
    )
    normalize_exposure: bool = Field(
        True,
        description="For a single plane (gray, saturation, auto): stretch it so its 99th "
        "percentile is 255, so "
        "the Canny thresholds hold on a dim exposure (bool).",
    )
    blur_sigma_px: float = Field(
        2.0, ge=0, le=10, description="Gaussian smoothing before edges (px)."
    )
    canny_low: float = Field(
        30.0,
        ge=0,
        le=1000,
        description="Canny lower hysteresis threshold (gradient, gray levels per px).",
    )
    canny_high: float = Field(
        90.0,
        ge=0,
        le=2000,
        description="Canny upper hysteresis threshold (gradient, gray levels per px).",
    )
    sobel_threshold: float = Field(
        60.0,
        gt=0,
        description="Sobel gradient magnitude threshold (gray levels per px, 3x3 kernel).",
    )
    dilate_px: int | None = Field(
        None,
        ge=1,
        le=101,
        description="Dilation element diameter (px); None = 0.4 x smallest expected radius.",
    )
    erode_px: int | None = Field(
        None, ge=1, le=101, description="Erosion element diameter (px); None = same as dilation."
    )
    open_px: int | None = Field(
        None,
        ge=1,
        le=101,
        description="Opening element diameter (px); None = 0.4 x smallest expected radius.",
    )


def gradient_gain(scale: int, blur_sigma_px: float, edge_sigma_px: float = 0.5) -> float:
    """How much steeper per pixel an edge is at pyramid scale ``scale`` than at full resolution.

    A step of contrast C blurred by a Gaussian of sigma s (px) peaks at a gradient of
    C / (s sqrt(2 pi)) per px. At full resolution s = hypot(edge, blur), with ``edge`` the
    image's own edge blur (optics, anti-aliasing); at level k of a ``cv2.pyrDown`` pyramid, in
    that level's px, s = sqrt((edge / scale)^2 + p_k^2 + (blur / scale)^2), where p_k is the
    pyramid's own smoothing (p_1 = 0.5, p_k = sqrt(p_(k-1)^2 + 1) / 2) and the detection blur
    counts only when applied (> 0.3 px). Scale 2 gives 1.8, scale 4 gives 2.7 (blur 2 px).
    """
    if scale <= 1:
        return 1.0
    p = 0.0
    for _ in range(int(round(math.log2(scale)))):
        p = math.sqrt(p * p + 1.0) / 2.0
    blur = blur_sigma_px / scale
    blur = blur if blur > 0.3 else 0.0
    full = math.hypot(edge_sigma_px, blur_sigma_px)
    return full / math.sqrt((edge_sigma_px / scale) ** 2 + p * p + blur * blur)


def _odd(x: float) -> int:
    return max(1, int(round(x)) | 1)


def edge_morph_mask(
    img_bgr: np.ndarray, params: EdgeMorphParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball by edge detection, morphology and largest-region selection (the thesis's
    method); give object.color_bgr (or wire `appearance`: learned from training truth), else
    look-alikes are refused as ambiguous.

    The edge + morphology mask of an image (uint8 0/255). Without object.color_bgr two round objects
    of similar size are refused as ambiguous (not found), and a ball touching another object cannot
    be split from it.

    Parameters
    ----------
    img_bgr : uint8 HxWx3 or HxW
    params : EdgeMorphParams
    r_range_px : (float, float)
        Expected ball radius range at this image's scale (px).
    scale : int
        Downscale factor of ``img_bgr``; pixel sizes in params are divided by it.
    roi : bool
        Unused (edges need no background model).
    """
    if params.channel == "color" or img_bgr.ndim == 2 and not params.normalize_exposure:
        gray = to_channel(img_bgr, params.channel)
    else:
        name = params.channel
        if name == "auto":
            name = (
                best_plane(img_bgr, params.object.color_bgr)[0]
                if params.object.color_bgr is not None
                else "color"
            )
        gray = (
            to_channel(img_bgr, name)
            if name in ("color", "gray", "saturation")
            else plane(img_bgr, name)
        )
        if params.normalize_exposure and gray.ndim == 2:
            gray = normalize_exposure(gray)
    sigma = params.blur_sigma_px / scale
    if sigma > 0.3:
        gray = gaussian_blur(gray, sigma)
    # A blurred edge is steeper per pixel at a coarse level: scale the thresholds so that
    # detection there finds the edges found at full size.
    gain = gradient_gain(scale, params.blur_sigma_px)
    if params.edge_detector == "canny":
        # (One image, not its Sobel derivatives: cv2.Canny(dx, dy, ...) is the binding's
        # second overload, and a stop signal landing as the first one is tried segfaults
        # OpenCV's Python binding: nodes.contracts.cv_overloads.)
        edges = cv2.Canny(gray, params.canny_low * gain, params.canny_high * gain, L2gradient=True)
    else:
        gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
        mag = cv2.magnitude(gx, gy)
        if mag.ndim == 3:
            mag = mag.max(axis=2)
        edges = (mag >= params.sobel_threshold * gain).astype(np.uint8) * 255
    r_min = r_range_px[0]
    d = _odd(params.dilate_px / scale) if params.dilate_px else _odd(max(3.0, 0.4 * r_min))
    e = _odd(params.erode_px / scale) if params.erode_px else d
    o = _odd(params.open_px / scale) if params.open_px else _odd(max(3.0, 0.4 * r_min))
    m = cv2.dilate(edges, structuring_element(d))
    m = fill_holes(m, max_hole_area(r_range_px))
    m = cv2.erode(m, structuring_element(e))
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, structuring_element(o))
    return m


# : ``segmenter.edge_morph``: the node (the shared shell of nodes.contracts.segmenter around
# edge_morph_mask)
edge_morph = segmenter("segmenter.edge_morph", params=EdgeMorphParams)(edge_morph_mask)
