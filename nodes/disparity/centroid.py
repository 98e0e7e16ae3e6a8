"""``disparity.centroid``: the thesis's estimator -- u_left - u_right of the region centroids.

In rectified images a scene point has the same row in both views, so the horizontal offset of
the two region centroids is the object's disparity (sub-pixel: the segmenters' centroids come
from the moments of a sub-pixel outline). The point used for x, y is the left centroid. The
silhouette centroid of a sphere is not the image of its centre; ``disparity.ellipse`` removes
that bias.
"""

from __future__ import annotations

import math

from stereograph.api import Field, In, Out, node

from ._common import DisparityParams, finish, not_found, seg_reason


class CentroidParams(DisparityParams):
    """Parameters of ``disparity.centroid``."""

    max_sphere_bias_cm: float = Field(
        0.5,
        gt=0,
        description="Refuse a pair whose silhouette-centroid depth error, predicted for a sphere "
        "from "
        "its angular size, exceeds this (cm): a large ball near the cameras "
        "(disparity.ellipse has no such error).",
    )


def sphere_bias(
    left_region: dict, right_region: dict, d_px: float, f_px: float, baseline_cm: float
) -> tuple[float, float]:
    """(disparity bias px, depth bias cm) of the centroid estimator for a sphere.

    A sphere's silhouette is the image of its tangent cone (half-angle alpha): its centre lies
    tan^2(alpha) further from the principal point than the image of the sphere's centre
    (``_common``'s module docstring), in both views, so the centroid disparity is about
    (1 + tan^2 alpha) times the centre's and the depth comes out Z tan^2 alpha too near. tan(alpha)
    is read from the image: the silhouette's area-equivalent radius over f (the larger view's).
    """
    r_px = math.sqrt(
        max(float(left_region.get("area_px") or 0.0), float(right_region.get("area_px") or 0.0))
        / math.pi
    )
    t2 = (r_px / f_px) ** 2
    z_cm = f_px * baseline_cm / d_px
    return d_px * t2 / (1.0 + t2), z_cm * t2


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
        "rectification": In(
            "Rectification", optional=True, description="For the plausible disparity range."
        ),
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
    extra = {}
    if rectification is not None and d > 0:
        bias_px, bias_cm = sphere_bias(
            segmentation["left"],
            segmentation["right"],
            d,
            float(rectification["f_px"]),
            float(rectification["baseline_cm"]),
        )
        if bias_cm > params.max_sphere_bias_cm:  # a wrong answer is worse than none
            rec = not_found(
                segmentation,
                f"the ball is so large and near that its silhouette centroids put it "
                f"~{bias_cm:.2f} cm too near (over max_sphere_bias_cm "
                f"{params.max_sphere_bias_cm:g}); use disparity.ellipse, which "
                "measures the sphere's centre",
                "centroid",
            )
            if ctx is not None:
                ctx.warn(f"{rec['id']}: {rec['reason']}")
            return {"disparity": rec}
        extra["sphere_bias_cm"] = bias_cm
    return {
        "disparity": finish(
            segmentation, u, v, d, s, "centroid", rectification, params, ctx, **extra
        )
    }
