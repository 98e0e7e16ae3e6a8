"""``disparity.sgbm``: dense semi-global matching, object disparity = robust statistic in the mask.

OpenCV's StereoSGBM runs on a crop of the rectified pair around the left region (the same
column offset in both images keeps disparities unchanged; the crop reaches ``numDisparities``
further left so that every candidate match is inside). ``minDisparity`` / ``numDisparities``
come from the calibration: f B / z_max .. f B / z_min over the working range. Optional WLS
filtering (opencv-contrib ``ximgproc``) smooths the map along image edges. The object's
disparity is the inter-quartile mean of the valid disparities inside the left mask eroded by
``erode_fraction`` of the radius (the border pixels mix ball and table).

Those disparities belong to the sphere's *visible surface*, not its centre: over the
central disc of relative radius rho_m, the mean depth of the front surface is
Z_c - R * (2/3) (1 - (1 - rho_m^2)^1.5) / rho_m^2 (orthographic approximation), so the record
carries ``depth_offset_cm`` = that correction, which the locator adds along the viewing ray.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from nodes.disparity.dense import wls_filter
from stereograph.api import Field, In, NodeError, Out, node

from ._common import DisparityParams, OddSize, disparity_range_px, finish, not_found, seg_reason


class SgbmParams(DisparityParams):
    """Parameters of ``disparity.sgbm``."""

    block_size: OddSize = Field(5, ge=1, le=21, description="SGBM matched block size (px, odd).")
    uniqueness_ratio: int = Field(5, ge=0, le=100, description="SGBM uniqueness margin (percent).")
    speckle_window: int = Field(
        0, ge=0, description="SGBM speckle filter window (px area; 0 = off)."
    )
    wls: bool = Field(
        False, description="Apply the ximgproc WLS filter to the disparity map (bool)."
    )
    wls_lambda: float = Field(8000.0, gt=0, description="WLS smoothness weight (unitless).")
    wls_sigma: float = Field(1.5, gt=0, description="WLS colour sensitivity (gray levels, scaled).")
    erode_fraction: float = Field(
        0.3,
        ge=0,
        lt=1,
        description="Erode the mask by this fraction of the region radius before the statistic.",
    )
    margin_px: int = Field(16, ge=0, description="Extra crop margin around the region (px).")


def sgbm_object_disparity(
    left: np.ndarray, right: np.ndarray, mask: np.ndarray, bbox, d_range, params: SgbmParams
) -> tuple[float, float, int, float]:
    """Robust disparity of the masked object from a dense SGBM map.

    Parameters
    ----------
    left, right : uint8 rectified images (gray or BGR)
    mask : bool HxW, the object in the left image
    bbox : [u0, v0, u1, v1] of the region (px)
    d_range : (d_min, d_max) plausible disparities (px)

    Returns
    -------
    (disparity_px, sigma_px, n_valid, rho_m) -- rho_m is the relative radius of the eroded disc.
    """
    h, w = mask.shape
    d_min = max(0, int(math.floor(d_range[0])))
    num = int(math.ceil((d_range[1] - d_min + 1) / 16.0)) * 16
    u0, v0, u1, v1 = bbox
    bs = params.block_size
    m = params.margin_px + bs
    # SGBM leaves the first minDisparity + numDisparities columns invalid: crop so that the
    # candidate matches are inside, and pad both images on the left by the same amount
    # (a common column shift leaves disparities unchanged).
    c0 = max(0, u0 - d_min - num - m)
    c1 = min(w, u1 + m + 1)
    r0, r1 = max(0, v0 - m), min(h, v1 + m + 1)
    gl = left[r0:r1, c0:c1]
    gr = right[r0:r1, c0:c1]
    if gl.ndim == 3:
        gl = cv2.cvtColor(gl, cv2.COLOR_BGR2GRAY)
        gr = cv2.cvtColor(gr, cv2.COLOR_BGR2GRAY)
    pad = d_min + num + bs
    gl = cv2.copyMakeBorder(gl, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    gr = cv2.copyMakeBorder(gr, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    matcher = cv2.StereoSGBM_create(
        minDisparity=d_min,
        numDisparities=num,
        blockSize=bs,
        P1=8 * bs * bs,
        P2=32 * bs * bs,
        uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )
    disp = matcher.compute(gl, gr)
    if params.wls:
        disp, _ = wls_filter(matcher, disp, gl, gr, params.wls_lambda, params.wls_sigma)
    disp = disp[:, pad:].astype(np.float32) / 16.0
    sub = mask[r0:r1, c0:c1].astype(np.uint8)
    r_px = math.sqrt(max(sub.sum(), 1) / math.pi)
    k = int(round(2 * params.erode_fraction * r_px)) | 1
    if k > 1:
        sub = cv2.erode(sub, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    rho_m = max(1.0 - params.erode_fraction, 0.05)
    vals = disp[(sub > 0) & (disp >= d_min)]
    if len(vals) < 5:
        return float("nan"), float("nan"), len(vals), rho_m
    q1, q3 = np.percentile(vals, [25, 75])
    core = vals[(vals >= q1) & (vals <= q3)]
    d = float(core.mean())
    # Robust spread (MAD) over an effective count (neighbouring SGBM pixels are correlated).
    mad = float(np.median(np.abs(vals - np.median(vals)))) * 1.4826
    sigma = max(mad, 1.0 / 16.0) / math.sqrt(max(len(vals) / (bs * bs), 1.0))
    return d, sigma, len(vals), rho_m


def surface_depth_offset(radius_cm: float, rho_m: float) -> float:
    """Mean front-surface depth deficit (cm) of a sphere over its central disc of relative radius
    rho_m."""
    t = rho_m**2
    return radius_cm * (2.0 / 3.0) * (1.0 - (1.0 - t) ** 1.5) / t


@node(
    "disparity.sgbm",
    inputs={
        "segmentation": In("Segmentation", description="Left mask of the object."),
        "pair": In("RectifiedPair", description="Rectified stereo pair."),
        "rectification": In("Rectification", description="For the disparity search range."),
    },
    outputs={"disparity": Out("Disparity", description="Object disparity (px), surface-referred.")},
    params=SgbmParams,
    version="1",
)
def sgbm(params: SgbmParams, segmentation, pair, rectification, ctx=None):
    """Dense StereoSGBM disparity; the object's value is a robust mean inside the eroded mask."""
    if rectification is None or "f_px" not in rectification:
        raise NodeError(
            "disparity.sgbm needs a Rectification (f_px, baseline_cm) for its search range.",
            hint="wire `rectification` to rectifier.opencv's output.",
        )
    why = seg_reason(segmentation)
    if why is not None:
        return {"disparity": not_found(segmentation, why, "sgbm")}
    rng = disparity_range_px(rectification, params, segmentation)
    L, R = np.asarray(pair["left"]), np.asarray(pair["right"])
    d, s, n, rho_m = sgbm_object_disparity(
        L, R, np.asarray(segmentation["left_mask"], bool), segmentation["left"]["bbox"], rng, params
    )
    if not np.isfinite(d):
        return {
            "disparity": not_found(
                segmentation, f"too few valid SGBM disparities in the mask ({n})", "sgbm"
            )
        }
    u, v = segmentation["left"]["centroid_px"]
    rec = finish(segmentation, u, v, d, s, "sgbm", rectification, params, ctx, n_valid_px=n)
    if rec["found"]:
        rec["depth_offset_cm"] = surface_depth_offset(
            float(segmentation.get("object_radius_cm") or 0.0), rho_m
        )
    return {"disparity": rec}
