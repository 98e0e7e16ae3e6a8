"""``toy.saturation``: a segmenter written as a plugin on the public contract only.

A coloured ball on a grey or beige table is its most saturated region: threshold the HSV saturation
at Otsu's level. Everything else -- candidate search, checks, partial views, overlay -- is the
contract's (nodes.contracts.segmenter).
"""

from __future__ import annotations

import cv2
import numpy as np

from nodes.contracts.segmenter import (
    SegmenterParams,
    fill_holes,
    max_hole_area,
    segmenter,
    to_channel,
)
from stereograph.api import Field


class SaturationParams(SegmenterParams):
    blur_px: float = Field(
        1.5, ge=0, le=10, description="Gaussian smoothing before the threshold (px)."
    )


@segmenter("toy.saturation", params=SaturationParams)
def saturation_mask(
    image_bgr: np.ndarray, params: SaturationParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball as the image's most saturated region (Otsu's threshold of HSV
    saturation)."""
    s = to_channel(image_bgr, "saturation")
    if params.blur_px / scale > 0.3:
        s = cv2.GaussianBlur(s, (0, 0), params.blur_px / scale)
    seen = to_channel(image_bgr, "gray") > 0  # not the rectified image's black rim
    level, _ = cv2.threshold(s[seen].reshape(-1, 1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return fill_holes(((s > level) & seen).astype(np.uint8) * 255, max_hole_area(r_range_px))
