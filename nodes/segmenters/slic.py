"""``segmenter.slic``: region-based segmentation: SLIC superpixels (scikit-image) of the object's
colour."""

from __future__ import annotations

import math

import numpy as np
from skimage.segmentation import slic as sk_slic

from nodes.contracts.segmenter import (
    SegmenterParams,
    color_distance_map,
    fill_holes,
    max_hole_area,
    segmenter,
)
from stereograph.api import Field, NodeError


class SlicParams(SegmenterParams):
    """Parameters of ``segmenter.slic`` (plus the common ones); needs the object's colour."""

    compactness: float = Field(
        10.0,
        gt=0,
        le=100,
        description="SLIC compactness: colour against space (unitless; "
        "higher = squarer superpixels).",
    )
    pieces_per_ball: float = Field(
        6.0,
        ge=1,
        le=50,
        description="Superpixels the smallest expected ball is cut "
        "into (count): the superpixel size.",
    )


def slic_mask(
    img_bgr: np.ndarray, params: SlicParams, r_range_px, scale: int = 1, roi: bool = False
) -> np.ndarray:
    """Segment the ball as the superpixels (SLIC, in Lab) whose mean colour is the object's:
    regions, not pixels, are judged, so image noise and texture inside one region do not break the
    outline. Needs the object's colour (given, declared or learned). The mask is uint8 0/255."""
    if img_bgr.ndim == 2 or params.object.color_bgr is None:
        raise NodeError(
            "segmenter.slic needs colour images and the object's color_bgr.",
            hint="declare the colour (objects.declare, or object.color_bgr), or wire `appearance`; "
            "for gray images use segmenter.edge_morph or segmenter.otsu",
        )
    h, w = img_bgr.shape[:2]
    size_px = max(4.0, math.pi * r_range_px[0] ** 2 / params.pieces_per_ball)
    labels = sk_slic(
        np.ascontiguousarray(img_bgr[..., ::-1]),
        n_segments=int(min(6000, max(8, h * w / size_px))),
        compactness=params.compactness,
        start_label=0,
        channel_axis=-1,
    )
    count = np.maximum(np.bincount(labels.ravel()), 1)
    dist = color_distance_map(img_bgr, params.object.color_bgr)
    keep = np.bincount(labels.ravel(), dist.ravel()) / count <= params.object.color_tolerance
    return fill_holes(keep[labels].astype(np.uint8) * 255, max_hole_area(r_range_px))


def _needs_a_colour(params: SlicParams, wired: frozenset[str]) -> None:
    if params.object.color_bgr is None and not {"appearance", "objects"} & wired:
        raise NodeError(
            "needs the object's colour: object.color_bgr is unset and neither `objects` nor "
            "`appearance` is wired",
            hint="declare it once (objects.declare wired to `objects`), give "
            "object.color_bgr, or wire `appearance`",
        )


# : ``segmenter.slic``: the node (the shared shell of nodes.contracts.segmenter around slic_mask);
# named as
#: its method, so that a worker process finds it by name
slic = segmenter("segmenter.slic", params=SlicParams, check=_needs_a_colour)(slic_mask)
