"""``segmenter.hough``: circular Hough transform (scikit-image) on the image's edges."""

from __future__ import annotations

import math

import cv2
import numpy as np
from skimage.feature import canny
from skimage.transform import hough_circle, hough_circle_peaks

from nodes.contracts.segmenter import segmenter, to_channel
from stereograph.api import Field

from .otsu import OtsuParams, background_difference


class HoughParams(OtsuParams):
    """Parameters of ``segmenter.hough`` (plus the common ones and Otsu's background)."""

    sigma_px: float = Field(
        2.0, ge=0.5, le=10, description="Canny smoothing at full resolution (px)."
    )
    min_votes: float = Field(
        0.35, gt=0, le=1, description="Least share of a circle's perimeter on edges (0-1)."
    )
    max_circles: int = Field(
        6,
        ge=1,
        le=50,
        description="Strongest circles kept per image (count); the shared "
        "selection then picks the ball among them.",
    )


def hough_mask(
    img_bgr: np.ndarray, params: HoughParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball as a circle of a circular Hough transform: Canny edges vote for centres at
    every radius the ball can have here (from the calibration, its radius and the working range).

    The mask (uint8 0/255) holds the discs of the strongest circles (the best one in a window).
    Circles need no colour, but a round look-alike of the ball's size is refused as ambiguous
    unless object.color_bgr is given.
    """
    # edges of the difference from the background: the ball stands out, a fine table texture does
    # not
    raw = to_channel(img_bgr, "gray")
    gray = background_difference(raw, params, r_range_px, roi)
    edges = canny(gray, sigma=max(params.sigma_px / scale, 0.2 * r_range_px[0], 0.5))
    rim = min(2 * math.ceil(r_range_px[1]) + 1, 61)  # no votes from the rectified image's black rim
    edges &= cv2.erode((raw > 0).astype(np.uint8), np.ones((rim, rim), np.uint8)) > 0
    lo, hi = max(2, math.floor(r_range_px[0])), max(3, math.ceil(r_range_px[1]))
    radii = np.unique(np.linspace(lo, hi, min(hi - lo + 1, 16)).round().astype(int))
    # ranked by the edge pixels on the circle (a small circle in texture is easily complete; a
    # ball's outline has many more), among those whose perimeter is covered at least min_votes
    votes = hough_circle(edges, radii, normalize=False)
    perimeter = (2 * np.pi * radii)[:, None, None]
    votes = np.where(votes >= params.min_votes * perimeter, votes, 0)
    _, xs, ys, rs = hough_circle_peaks(
        votes,
        radii,
        min_xdistance=lo,
        min_ydistance=lo,
        threshold=1,
        total_num_peaks=1 if roi else params.max_circles,
    )
    mask = np.zeros(gray.shape[:2], np.uint8)
    for x, y, r in zip(xs, ys, rs):
        cv2.circle(mask, (int(x), int(y)), int(r), 255, -1)
    return mask


#: ``segmenter.hough``: the node (the shared shell of nodes.contracts.segmenter around hough_mask)
hough = segmenter("segmenter.hough", params=HoughParams)(hough_mask)
