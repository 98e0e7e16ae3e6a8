"""``disparity.ellipse``: sphere-aware disparity from the two silhouette ellipses.

The perspective image of a sphere is an ellipse whose centre -- and area centroid -- is not the
image of the sphere's centre. Each view's ellipse (fitted to the sub-pixel outline) is turned
into its tangent cone; the cone's axis passes through the sphere's centre, so projecting the
axis gives the true centre image in each rectified view, and their horizontal offset is the
disparity of the centre. See ``nodes/disparity/_common.py`` for the math. As a by-product each
view yields the distance from the known radius (``z_from_size_cm``), reported for diagnosis.
"""

from __future__ import annotations

import math

import numpy as np

from nodes.contracts.sphere import ellipse_to_conic, sphere_from_silhouette
from stereograph.api import Field, In, NodeError, Out, node

from ._common import DisparityParams, finish, not_found, seg_reason


class EllipseParams(DisparityParams):
    """Parameters of ``disparity.ellipse``."""

    max_anisotropy: float = Field(
        0.5,
        gt=0,
        description="Max mismatch of the cone's two equal eigenvalues (ratio); above -> not a "
        "sphere.",
    )


def camera_matrices(rectification: dict) -> tuple[np.ndarray, np.ndarray]:
    """The rectified left and right camera matrices (3x3) from P1, P2."""
    P1 = np.asarray(rectification["P1"], float)
    P2 = np.asarray(rectification["P2"], float)
    return P1[:, :3], P2[:, :3]


def sphere_center_images(left_region: dict, right_region: dict, K1: np.ndarray, K2: np.ndarray):
    """Images of the sphere centre in both rectified views from the regions' ellipses.

    Returns
    -------
    (left, right) : dicts of :func:`sphere_from_silhouette`.
    """
    out = []
    for reg, K in ((left_region, K1), (right_region, K2)):
        e = reg.get("ellipse")
        if e is None:
            raise ValueError("region has no ellipse")
        E = ellipse_to_conic(e["center_px"], e["axes_px"], e["angle_deg"])
        out.append(sphere_from_silhouette(E, K))
    return out[0], out[1]


@node(
    "disparity.ellipse",
    inputs={
        "segmentation": In("Segmentation", description="Regions with fitted ellipses."),
        "rectification": In("Rectification", description="Rectified camera matrices P1, P2."),
    },
    outputs={"disparity": Out("Disparity", description="Disparity of the sphere's centre (px).")},
    params=EllipseParams,
    version="1",
)
def ellipse(params: EllipseParams, segmentation, rectification, ctx=None):
    """Sphere-aware disparity: centre images from the silhouette ellipses' tangent cones."""
    if rectification is None or "P1" not in rectification:
        raise NodeError(
            "disparity.ellipse needs a Rectification (P1, P2).",
            hint="wire `rectification` to rectifier.opencv's output.",
        )
    why = seg_reason(segmentation)
    if why is not None:
        return {"disparity": not_found(segmentation, why, "ellipse")}
    K1, K2 = camera_matrices(rectification)
    try:
        cl, cr = sphere_center_images(segmentation["left"], segmentation["right"], K1, K2)
    except ValueError as exc:
        return {"disparity": not_found(segmentation, f"ellipse unusable: {exc}", "ellipse")}
    if max(cl["anisotropy"], cr["anisotropy"]) > params.max_anisotropy:
        return {
            "disparity": not_found(
                segmentation,
                f"silhouette is not the image of a sphere (anisotropy "
                f"{max(cl['anisotropy'], cr['anisotropy']):.2f} > {params.max_anisotropy})",
                "ellipse",
            )
        }
    uL, vL = cl["center_px"]
    uR, _ = cr["center_px"]
    # Uncertainty of an ellipse centre: outline rms x sqrt(2/N) per view.
    s = []
    for reg in (segmentation["left"], segmentation["right"]):
        e = reg["ellipse"]
        if e.get("sigma_center_px") is not None:  # a sphere image fitted to a partial outline
            s.append(float(e["sigma_center_px"]))
            continue
        s.append(e.get("rms_px", 0.3) * math.sqrt(2.0 / max(e.get("inliers", 10), 1)))
    R = float(segmentation.get("object_radius_cm") or 0.0)
    extra = {}
    if R > 0:
        # Distance of the centre from the known radius, per view (monocular cross-check).
        extra["z_from_size_cm"] = [
            R / math.sin(c["half_angle_rad"]) * c["axis"][2] for c in (cl, cr)
        ]
    return {
        "disparity": finish(
            segmentation,
            uL,
            vL,
            uL - uR,
            math.hypot(*s),
            "ellipse",
            rectification,
            params,
            ctx,
            **extra,
        )
    }
