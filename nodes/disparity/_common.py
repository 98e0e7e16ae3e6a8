"""Shared pieces of the disparity estimators: parameters, range checks, the output record,
and the sphere geometry used by ``disparity.ellipse``.

Sphere-aware centre (the math)
------------------------------
A sphere of radius R with centre C seen from a camera centre O is bounded by a right
circular *tangent cone* with apex O, axis along C - O and half-angle alpha, sin(alpha) = R/|C|.
In normalised camera coordinates x = K^-1 [u, v, 1]^T the cone is

    x^T (a a^T - cos^2(alpha) I) x = 0,          a = C / |C|  (unit axis),

so its image -- the silhouette -- is the conic  E = K^-T (a a^T - cos^2 alpha I) K^-1  (up to
scale): an ellipse whose centre is *not* K a, the image of the sphere's centre (it is pushed
away from the principal point by about |Ka - c| tan^2(alpha)). Going back: from the fitted
ellipse's conic E (3x3 symmetric, pixel coordinates) form the cone matrix M = K^T E K. Its
eigenvalues are (up to a common factor) sin^2 alpha once and -cos^2 alpha twice; the
eigenvector of the lone-signed eigenvalue is the axis a, hence the image of the centre
K a, and tan^2 alpha = -lambda_1 / lambda_2 gives the distance |C| = R / sin(alpha) without
any second view. ``disparity.ellipse`` applies this to both rectified views
(K = P1[:, :3], P2[:, :3]) and returns the disparity of the two centre images, which is exactly
f B / Z_c for the sphere's centre -- no perspective bias, unlike the silhouette centroids.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import AfterValidator

from nodes.contracts.working_range import working_range
from stereograph.api import Field, Params, PositiveRange


def _odd(value: int) -> int:
    if value % 2 == 0:
        raise ValueError(
            f"a block size must be odd (got {value}; OpenCV centres the block on the pixel)"
        )
    return value


OddSize = Annotated[int, AfterValidator(_odd)]
"""An odd block size (px): the matched block is centred on its pixel."""


class DisparityParams(Params):
    """Parameters shared by every disparity estimator."""

    working_range_cm: PositiveRange = Field(
        (20.0, 80.0),
        description="Nearest and farthest plausible object distance (cm); outside -> not found. "
        "Not set in the pipeline: the segmenter's, carried in its records.",
    )
    range_slack: float = Field(
        0.25,
        ge=0,
        le=2,
        description="Relative slack on the working range before rejecting a disparity (ratio).",
    )
    min_sigma_disparity_px: float = Field(
        0.02, gt=0, description="Floor of the reported disparity uncertainty (px)."
    )


def disparity_range_px(
    rectification: dict | None, params: DisparityParams, seg: dict | None = None
) -> tuple[float, float] | None:
    """Plausible disparity range (px) from f*B and the working range (``working_range``: this node's
    if the pipeline set it, else the Segmentation's), or None without calibration."""
    if rectification is None:
        return None
    fb = float(rectification["f_px"]) * float(rectification["baseline_cm"])
    z0, z1 = working_range(params, seg)
    return fb / (z1 * (1 + params.range_slack)), fb / (z0 * (1 - min(params.range_slack, 0.9)))


REJECTED_KEYS = ("rejected_left_px", "rejected_left_why", "rejected_right_px", "rejected_right_why")
PASSED_ON = (
    *REJECTED_KEYS,
    "color_from",
    "working_range_cm",
    "object_radius_cm",
    "object",
    "merged",
)


def _passed_on(seg) -> dict:
    """What a Disparity passes on from its Segmentation: the rejected-candidate outlines (for the
    locator's overlay), where the object's colour came from (``color_from``) and the ball's radius
    (``object_radius_cm``: ik.pick_sequence checks the ball's centre is a radius above the table),
    when present."""
    return {k: seg[k] for k in PASSED_ON if k in seg} if isinstance(seg, dict) else {}


def not_found(seg_or_id, reason: str, method: str) -> dict:
    """A Disparity record with ``found: False``."""
    sid = seg_or_id["id"] if isinstance(seg_or_id, dict) else str(seg_or_id)
    split = seg_or_id.get("split") if isinstance(seg_or_id, dict) else None
    return {
        "id": sid,
        "found": False,
        "reason": reason,
        "u_left_px": None,
        "v_left_px": None,
        "disparity_px": None,
        "sigma_disparity_px": None,
        "method": method,
        "split": split,
        "depth_offset_cm": 0.0,
        **_passed_on(seg_or_id),
    }


def finish(
    seg: dict,
    u: float,
    v: float,
    d: float,
    sigma_d: float,
    method: str,
    rectification: dict | None,
    params: DisparityParams,
    ctx=None,
    **extra,
) -> dict:
    """A Disparity record, or a not-found one when d lies outside the plausible range."""
    rng = disparity_range_px(rectification, params, seg)
    used = list(working_range(params, seg))
    if not np.isfinite(d) or d <= 0:
        rec = not_found(seg, f"disparity out of range ({d:.2f} px <= 0)", method)
    elif rng is not None and not (rng[0] <= d <= rng[1]):
        rec = not_found(
            seg,
            f"disparity out of range ({d:.2f} px not in {rng[0]:.1f}-{rng[1]:.1f} px "
            f"= working range {used} cm)",
            method,
        )
    else:
        rec = {
            "id": seg["id"],
            "found": True,
            "reason": None,
            "u_left_px": float(u),
            "v_left_px": float(v),
            "disparity_px": float(d),
            "sigma_disparity_px": float(max(sigma_d, params.min_sigma_disparity_px)),
            "method": method,
            "split": seg.get("split"),
            "depth_offset_cm": 0.0,
            **_passed_on(seg),
        }
        rec.update(extra)
    rec["working_range_cm"] = used  # (the locator's default)
    if not rec["found"] and ctx is not None:
        ctx.warn(f"{rec['id']}: {rec['reason']}")
    return rec


def seg_reason(seg: dict) -> str | None:
    """Why a Segmentation cannot give a disparity (it was not found), or None."""
    if not isinstance(seg, dict) or "found" not in seg:
        from stereograph.api import NodeError

        raise NodeError(
            "disparity input is not a Segmentation record.",
            hint="wire `segmentation` to a segmenter's `segmentation` output.",
        )
    if not seg["found"]:
        return seg.get("reason") or "segmentation found no object"
    return None
