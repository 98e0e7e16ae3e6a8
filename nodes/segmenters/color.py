"""``segmenter.color``: colour thresholding for a coloured ball.

Pixels close to the object's colour -- the distance of the normalised chromaticity
(b, g, r) / (b + g + r) to that of ``object.color_bgr`` (brightness-invariant, so the shaded side
of the ball matches too) or an HSV hue range
``object.hue_range_deg`` -- form the mask; holes (specular highlight) are filled and a small
opening removes speckle. Selection, sub-pixel refinement and checks are the shared ones (``_pair``).
"""

from __future__ import annotations

import cv2
import numpy as np

from nodes.contracts.segmenter import (
    SegmenterParams,
    fill_holes,
    max_hole_area,
    segmenter,
    structuring_element,
)
from nodes.contracts.segmenter._color import color_distance_map, hue_mask
from stereograph.api import Field, NodeError


class ColorParams(SegmenterParams):
    """Parameters of ``segmenter.color`` (plus the common ones); needs object.color_bgr or
    hue_range_deg."""

    open_px: int | None = Field(
        None,
        ge=1,
        le=101,
        description="Opening element diameter (px); None = 0.2 x smallest expected radius.",
    )


def color_mask(
    img_bgr: np.ndarray, params: ColorParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball by thresholding its colour (chromaticity distance or HSV hue range); needs
    the colour: object.color_bgr, object.hue_range_deg or a wired `appearance` input.

    The mask (uint8 0/255) holds the pixels matching the object's colour.
    """
    if img_bgr.ndim == 2:
        raise NodeError(
            "segmenter.color needs colour images, got a gray image.",
            hint="use segmenter.edge_morph or segmenter.otsu for gray images.",
        )
    obj = params.object
    if obj.color_bgr is not None:
        m = (color_distance_map(img_bgr, obj.color_bgr) <= obj.color_tolerance).astype(
            np.uint8
        ) * 255
    else:
        m = hue_mask(img_bgr, obj.hue_range_deg, obj.min_saturation)
    m = fill_holes(m, max_hole_area(r_range_px))
    o = params.open_px / scale if params.open_px else max(3.0, 0.2 * r_range_px[0])
    return cv2.morphologyEx(m, cv2.MORPH_OPEN, structuring_element(int(round(o)) | 1))


_NO_COLOUR_HINT = (
    "declare the colour once for the pipeline: an objects.declare node with `objects: [{radius_cm: "
    "2.0, color_bgr: [B, G, R]}]` wired to the segmenter's `objects` input (or `object: "
    "{color_bgr: "
    "[B, G, R]}` in its params; the colour of YOUR ball), or wire `appearance` to a "
    "segmenter.appearance node (the colour learned from training truth); or use "
    "segmenter.edge_morph, "
    "which works without a colour"
)


def _needs_a_colour(params: ColorParams, wired: frozenset[str]) -> None:
    obj = params.object
    if (
        obj.color_bgr is None
        and obj.hue_range_deg is None
        and not {"appearance", "objects"} & wired
    ):
        raise NodeError(
            "needs the object's colour: object.color_bgr and object.hue_range_deg are "
            "both unset and "
            "neither `objects` nor `appearance` is wired",
            hint=_NO_COLOUR_HINT,
        )


def _has_a_colour(params: ColorParams) -> None:
    # (called directly, not validated)
    if params.object.color_bgr is None and params.object.hue_range_deg is None:
        raise NodeError(
            "segmenter.color has no object colour: the object (its params, or the wired `objects`) "
            "has neither color_bgr nor hue_range_deg.",
            hint=_NO_COLOUR_HINT,
        )


#: ``segmenter.color``: the node (the shared shell of nodes.contracts.segmenter around color_mask)
color = segmenter(
    "segmenter.color", params=ColorParams, check=_needs_a_colour, before=_has_a_colour
)(color_mask)
