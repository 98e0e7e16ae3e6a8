"""``disparity.dense``: the full disparity map of a rectified pair, a coloured image of it and a
point cloud.

What a ROS ``stereo_image_proc`` user expects from a stereo rig, as a node: OpenCV's
``StereoSGBM`` over the whole rectified pair (sub-pixel, 1/16 px), optionally followed by the
weighted-least-squares filter of opencv-contrib (``cv2.ximgproc``), which smooths the map along
image edges and fills holes from a left-right pair of matchers. Three products per pair:

* ``disparity_map`` -- float32 disparity (px, NaN where there is no trustworthy match), with the
  camera numbers needed to turn it into depth;
* ``disparity_image`` -- the map coloured (turbo colour map over the searched range; black = no
  match);
* ``point_cloud`` -- a PLY file of the matched pixels, metric (cm) in the physical left-camera frame
  (``Q`` of the rectification, then ``R1^T`` as ``locator.triangulate`` does), coloured from the
  left image.

The disparity search range comes from the rectification and the scene's depth range,
``d = f B / z - doffs`` over ``working_range_cm`` (or ``disparity_range_px`` directly). SGBM leaves
the first ``minDisparity + numDisparities`` columns unmatched; both images are padded on the left by
that many replicated columns (a common column shift leaves disparities unchanged), so the left part
of the image is matched too wherever its partner is inside the right image. Pixels whose match is
not unique, fails the left-right check or sits in a small speckle are left out; with WLS, pixels
whose WLS confidence is below ``wls_min_confidence`` are left out (WLS fills everything, including
occlusions, where its value is a guess: a wrong depth is worse than none).
"""

from __future__ import annotations

import math
import time
from typing import Literal

import cv2
import numpy as np
from pydantic import model_validator

from nodes.disparity._common import OddSize
from nodes.disparity._ply import encode_ply
from stereograph.api import Field, In, NodeError, OrderedRange, Out, Params, PositiveRange, node

__all__ = [
    "DenseParams",
    "colorize",
    "dense",
    "dense_disparity",
    "point_cloud",
    "search_range_px",
    "wls_filter",
]

_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}
_MAPS = {
    "turbo": cv2.COLORMAP_TURBO,
    "jet": cv2.COLORMAP_JET,
    "viridis": cv2.COLORMAP_VIRIDIS,
    "inferno": cv2.COLORMAP_INFERNO,
}
#: Widest search OpenCV's SGBM is given here (px): beyond it memory and time grow without use.
MAX_DISPARITIES = 1024


class DenseParams(Params):
    """Parameters of ``disparity.dense``; SGBM's names in OpenCV are given in brackets."""

    working_range_cm: PositiveRange = Field(
        (20.0, 200.0),
        description="Nearest and farthest scene depth to match (cm); sets the disparity search "
        "range.",
    )
    disparity_range_px: OrderedRange | None = Field(
        None,
        description="Search range of disparities (px, lowest first), overriding "
        "working_range_cm; null = from "
        "the range. Image disparities x_left - x_right, without the principal points' offset "
        "(doffs); the span is rounded up to a multiple of 16 as OpenCV's SGBM requires.",
    )
    block_size_px: OddSize = Field(
        3, ge=1, le=21, description="Matched block size [blockSize] (px, odd; 3-11 usual)."
    )
    mode: Literal["sgbm", "hh", "sgbm_3way", "hh4"] = Field(
        "sgbm",
        description="SGBM variant [mode]: sgbm (5 paths), hh (full 8 paths, slow, memory-hungry), "
        "sgbm_3way, hh4 (name).",
    )
    p1_factor: float = Field(
        8.0,
        gt=0,
        description="Small-step smoothness penalty P1 per channel per block pixel "
        "(unitless; OpenCV's recommended 8).",
    )
    p2_factor: float = Field(
        32.0,
        gt=0,
        description="Large-step penalty P2 per channel per block pixel "
        "(unitless; OpenCV's recommended 32; must exceed p1_factor).",
    )
    uniqueness_pct: int = Field(
        10,
        ge=0,
        le=100,
        description="Best match must beat the second by this margin "
        "[uniquenessRatio] (percent; 5-15 usual).",
    )
    lr_max_diff_px: int = Field(
        1,
        ge=-1,
        description="Left-right consistency tolerance [disp12MaxDiff] "
        "(px; -1 switches the check off).",
    )
    speckle_window_px: int = Field(
        100,
        ge=0,
        description="Connected regions of at most this area are speckles "
        "and removed [speckleWindowSize] (px area; 0 = off).",
    )
    speckle_range_px: int = Field(
        2, ge=0, description="Disparity variation allowed within one region [speckleRange] (px)."
    )
    color: bool = Field(
        True, description="Match on the colour images (true) or on grey levels (switch)."
    )
    pad_left: bool = Field(
        True,
        description="Pad both images on the left so the left border columns are matched "
        "too (switch).",
    )
    # (defaults chosen on two real pairs, Middlebury's Aloe and Motorcycle:
    # benchmarks/dense_pairs.py)
    wls: bool = Field(True, description="Filter the map with opencv-contrib's WLS filter (switch).")
    wls_lambda: float = Field(
        8000.0, gt=0, description="WLS smoothness weight (unitless; OpenCV's tutorial 8000)."
    )
    wls_sigma_color: float = Field(
        1.0,
        gt=0,
        description="WLS sensitivity to image edges (unitless; OpenCV's "
        "tutorial 1.5; lower follows edges more closely).",
    )
    wls_min_confidence: float = Field(
        128.0,
        ge=0,
        le=255,
        description="WLS pixels below this confidence (0-255 scale) count as unmatched.",
    )
    colormap: Literal["turbo", "jet", "viridis", "inferno"] = Field(
        "turbo", description="Colour map of the disparity image (name)."
    )
    cloud_stride_px: int = Field(
        1, ge=1, le=64, description="Keep every n-th pixel in x and y in the point cloud (px)."
    )

    @model_validator(mode="after")
    def _p2_above_p1(self) -> DenseParams:
        if self.p2_factor <= self.p1_factor:
            raise ValueError(
                f"p2_factor ({self.p2_factor:g}) must exceed p1_factor "
                f"({self.p1_factor:g}): OpenCV's "
                "SGBM needs P2 > P1 (recommended 32 and 8)"
            )
        return self


def search_range_px(rectification: dict, params: DenseParams) -> tuple[int, int]:
    """(minDisparity, numDisparities) of the search, px: d = f B / z - doffs over the working
    range."""
    if params.disparity_range_px is not None:
        lo, hi = (float(v) for v in params.disparity_range_px)
        source = f"disparity_range_px {list(params.disparity_range_px)}"
    else:
        fb = float(rectification["f_px"]) * float(rectification["baseline_cm"])
        doffs = float(rectification.get("cx_right_px", rectification["cx_px"])) - float(
            rectification["cx_px"]
        )
        z0, z1 = (float(v) for v in params.working_range_cm)  # (0 < z0 < z1: checked by the params)
        lo, hi = fb / z1 - doffs, fb / z0 - doffs
        source = (
            f"working_range_cm {list(params.working_range_cm)} with f B = {fb:.4g} px cm, "
            f"doffs {doffs:.4g} px"
        )
    d_min = int(math.floor(lo))
    num = max(16, int(math.ceil((hi - d_min + 1) / 16.0)) * 16)
    if num > MAX_DISPARITIES:
        raise NodeError(
            f"disparity.dense: the search would span {num} disparities ({source}); at most "
            f"{MAX_DISPARITIES} are matched.",
            hint="narrow working_range_cm to the scene's real depths (a near limit close to "
            "the camera "
            "costs most), or give disparity_range_px",
        )
    return d_min, num


def _matcher(params: DenseParams, d_min: int, num: int, channels: int):
    bs = params.block_size_px
    return cv2.StereoSGBM_create(
        minDisparity=d_min,
        numDisparities=num,
        blockSize=bs,
        P1=int(round(params.p1_factor * channels * bs * bs)),
        P2=int(round(params.p2_factor * channels * bs * bs)),
        disp12MaxDiff=params.lr_max_diff_px,
        uniquenessRatio=params.uniqueness_pct,
        speckleWindowSize=params.speckle_window_px,
        speckleRange=params.speckle_range_px,
        mode=_MODES[params.mode],
    )


def wls_filter(
    matcher, raw: np.ndarray, left: np.ndarray, right: np.ndarray, lam: float, sigma: float
):
    """opencv-contrib's WLS filter of a left SGBM map (int16, x16) with its right-view twin.

    Returns
    -------
    (filtered int16 map x16, confidence float32 map on a 0-255 scale)
    """
    raw_r = cv2.ximgproc.createRightMatcher(matcher).compute(right, left)
    wls = cv2.ximgproc.createDisparityWLSFilter(matcher)
    wls.setLambda(lam)
    wls.setSigmaColor(sigma)
    return wls.filter(raw, left, disparity_map_right=raw_r), wls.getConfidenceMap()


def dense_disparity(
    left: np.ndarray, right: np.ndarray, d_min: int, num: int, params: DenseParams
) -> np.ndarray:
    """Disparity map (float32 HxW, px; NaN = no trustworthy match) of a rectified pair."""

    def prep(im):
        im = np.asarray(im)
        if im.ndim == 3 and not params.color:
            return cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)
        return im

    a, b = prep(left), prep(right)
    pad = max(0, d_min + num) if params.pad_left else 0
    if pad:
        a = cv2.copyMakeBorder(a, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        b = cv2.copyMakeBorder(b, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    matcher = _matcher(params, d_min, num, 1 if a.ndim == 2 else a.shape[2])
    raw = matcher.compute(a, b)  # int16, disparity x 16; < minDisparity x 16 where unmatched
    valid = raw >= d_min * 16
    if params.wls:
        raw, confidence = wls_filter(matcher, raw, a, b, params.wls_lambda, params.wls_sigma_color)
        valid = (raw >= d_min * 16) & (confidence >= params.wls_min_confidence)
    disp = raw.astype(np.float32) / 16.0
    disp[~valid] = np.nan
    return np.ascontiguousarray(disp[:, pad:])


def colorize(disp: np.ndarray, d_range: tuple[float, float], colormap: str = "turbo") -> np.ndarray:
    """BGR uint8 image of a disparity map: colour over ``d_range`` (px), black where NaN."""
    lo, hi = d_range
    scaled = np.clip(
        (np.nan_to_num(disp, nan=lo) - lo) / max(hi - lo, 1e-6) * 255.0, 0, 255
    ).astype(np.uint8)
    img = cv2.applyColorMap(scaled, _MAPS[colormap])
    img[~np.isfinite(disp)] = 0
    return img


def point_cloud(disp: np.ndarray, left: np.ndarray, rectification: dict, stride: int = 1):
    """Points (N, 3) cm in the physical left-camera frame and their colours (N, 3) RGB uint8.

    ``Q`` maps (u, v, d) to the rectified left camera; ``R1^T`` turns that into the physical left
    camera (docs/conventions.md). Pixels without a match, or whose depth is not positive and finite,
    are skipped.
    """
    h, w = disp.shape
    vs, us = np.mgrid[0:h:stride, 0:w:stride]
    d = disp[0:h:stride, 0:w:stride]
    ok = np.isfinite(d)
    u, v, d = us[ok].astype(np.float64), vs[ok].astype(np.float64), d[ok].astype(np.float64)
    Q = np.asarray(rectification["Q"], dtype=float)
    hom = Q @ np.vstack([u, v, d, np.ones_like(u)])
    with np.errstate(divide="ignore", invalid="ignore"):
        pts = (hom[:3] / hom[3]).T
    if np.nanmedian(pts[:, 2]) < 0:  # Q of a rig with the right camera on the other side
        pts = -pts
    keep = np.all(np.isfinite(pts), axis=1) & (pts[:, 2] > 0)
    pts = pts[keep]
    R1 = rectification.get("R1")
    if R1 is not None:
        pts = pts @ np.asarray(R1, dtype=float)  # row-wise R1^T p
    img = np.asarray(left)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img[..., :3]
    bgr = img[0:h:stride, 0:w:stride][ok][keep]
    return pts.astype(np.float32), np.ascontiguousarray(bgr[:, ::-1])


@node(
    "disparity.dense",
    inputs={
        "pair": In("RectifiedPair", description="Rectified stereo pair (rectifier.remap)."),
        "rectification": In(
            "Rectification", description="f, baseline, Q, R1 (rectifier.opencv or rectifier.given)."
        ),
    },
    outputs={
        "disparity_map": Out(
            "DisparityMap", save=True, description="float32 disparity (px, NaN = no match)."
        ),
        "disparity_image": Out(
            "Image", save=True, description="Coloured disparity map (black = no match)."
        ),
        "point_cloud": Out(
            "File", save=True, description="PLY point cloud, cm, physical left-camera frame."
        ),
    },
    params=DenseParams,
    version="1",
)
def dense(params: DenseParams, pair, rectification, ctx=None):
    """Full disparity map of a rectified pair (StereoSGBM, optional WLS), a coloured image and a PLY
    point cloud."""
    left, right = _checked_pair(pair, rectification)
    d_min, num = search_range_px(rectification, params)
    t0 = time.perf_counter()
    disp = dense_disparity(left, right, d_min, num, params)
    seconds = time.perf_counter() - t0
    valid = np.isfinite(disp)
    fraction = float(valid.mean())
    pts, rgb = point_cloud(disp, left, rectification, params.cloud_stride_px)
    frame = "left camera (physical), OpenCV axes: x right, y down, z forward"
    ply = encode_ply(
        pts,
        rgb,
        [f"stereograph disparity.dense pair {pair.get('id')}", "units cm", f"frame {frame}"],
    )
    if ctx is not None and fraction < 0.2:
        ctx.warn(
            f"pair '{pair.get('id')}': only {fraction:.0%} of the pixels matched; check "
            "the search range "
            f"({d_min}..{d_min + num - 1} px) against the scene, and the rectification"
        )
    dmap = {
        "id": pair.get("id"),
        "split": pair.get("split"),
        "disparity_px": disp,
        "valid_fraction": fraction,
        "search_range_px": [d_min, d_min + num - 1],
        "method": "sgbm+wls" if params.wls else "sgbm",
        "compute_seconds": float(seconds),
        "f_px": float(rectification["f_px"]),
        "cx_px": float(rectification["cx_px"]),
        "cy_px": float(rectification["cy_px"]),
        "baseline_cm": float(rectification["baseline_cm"]),
        "doffs_px": float(rectification.get("cx_right_px", rectification["cx_px"]))
        - float(rectification["cx_px"]),
        # the dataset's own truth, if the source found it
        "truth_disparity_path": pair.get("truth_disparity_path"),
    }
    cloud = {
        "file_suffix": ".ply",
        "file_bytes": np.frombuffer(ply, dtype=np.uint8).copy(),
        "n_points": int(len(pts)),
        "units": "cm",
        "frame": "left_camera",
    }
    return {
        "disparity_map": dmap,
        "disparity_image": colorize(disp, (d_min, d_min + num - 1), params.colormap),
        "point_cloud": cloud,
    }


def _checked_pair(pair: dict, rectification: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """The pair's images, when ``rectification`` can match them (f_px, baseline_cm, Q; their
    size); NodeError otherwise."""
    if rectification is None or "f_px" not in rectification or rectification.get("Q") is None:
        raise NodeError(
            "disparity.dense needs a Rectification with f_px, baseline_cm and Q.",
            hint="wire `rectification` to rectifier.opencv or rectifier.given",
        )
    left, right = np.asarray(pair["left"]), np.asarray(pair["right"])
    size = list(rectification.get("image_size") or [left.shape[1], left.shape[0]])
    if left.shape != right.shape or [left.shape[1], left.shape[0]] != [int(v) for v in size]:
        raise NodeError(
            f"disparity.dense: pair '{pair.get('id')}' is {left.shape[1]}x{left.shape[0]} / "
            f"{right.shape[1]}x{right.shape[0]} px but the rectification is for "
            f"{size[0]}x{size[1]}.",
            hint="rectify the pair with the same rectification (rectifier.remap), or fix "
            "image_size "
            "of rectifier.given",
        )
    return left, right
