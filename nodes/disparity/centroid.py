"""``disparity.centroid``: the thesis's estimator -- u_left - u_right of the region centroids.

In rectified images a scene point has the same row in both views, so the horizontal offset of
the two region centroids is the object's disparity (sub-pixel: the segmenters' centroids come
from the moments of a sub-pixel outline). The point used for x, y is the left centroid. The
silhouette centroid of a sphere is not the image of its centre; ``disparity.ellipse`` removes
that bias.
"""

from __future__ import annotations

import math

from stereograph.api import In, Out, node

from ._common import DisparityParams, finish, not_found, seg_reason


class CentroidParams(DisparityParams):
    """Parameters of ``disparity.centroid``."""


def centroid_disparity(left_region: dict, right_region: dict) -> tuple[float, float, float, float]:
    """(u_left, v_left, disparity, sigma_disparity) in px from two Region dicts."""
    uL, vL = left_region["centroid_px"]
    uR, _ = right_region["centroid_px"]
    sL = left_region.get("sigma_centroid_px") or 0.0
    sR = right_region.get("sigma_centroid_px") or 0.0
    return float(uL), float(vL), float(uL - uR), math.hypot(sL, sR)


@node(
    "disparity.centroid",
    inputs={
        "segmentation": In("Segmentation", description="Regions in the rectified pair."),
        "rectification": In("Rectification", optional=True, description="For the plausible disparity range."),
    },
    outputs={"disparity": Out("Disparity", description="Object disparity (px).")},
    params=CentroidParams,
    version="1",
)
def centroid(params: CentroidParams, segmentation, rectification=None, ctx=None):
    """Disparity as the difference of the left and right region centroids (the thesis's method)."""
    why = seg_reason(segmentation)
    if why is not None:
        return {"disparity": not_found(segmentation, why, "centroid")}
    u, v, d, s = centroid_disparity(segmentation["left"], segmentation["right"])
    return {"disparity": finish(segmentation, u, v, d, s, "centroid", rectification, params, ctx)}
