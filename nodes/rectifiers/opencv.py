"""``rectifier.opencv``: stereo rectification (``stereoRectify`` + ``initUndistortRectifyMap``),
maps computed once."""

from __future__ import annotations

import cv2
import numpy as np

from nodes.contracts.calibration_export import EXPORT_OUTPUTS, export_texts
from nodes.contracts.drawing import caption
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["RectifyParams", "opencv", "rectified_dy", "rectified_points", "rectify_calibration"]

_CRIT = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-10)


def rectify_calibration(
    cal: dict, alpha: float = 1.0, zero_disparity: bool = True, output_scale: float = 1.0
) -> dict:
    """Rectification of a calibrated stereo pair.

    Parameters
    ----------
    cal : dict
        A ``StereoCalibration``.
    alpha : float
        ``stereoRectify``'s free scaling, 0..1 (or -1 for OpenCV's default):
        1 keeps every source pixel (black corners appear), 0 crops to valid
        pixels only and loses the image borders.
    zero_disparity : bool
        Same principal point in both rectified images, so disparity is uL - uR.
    output_scale : float
        Rectified image size relative to the source (unitless).

    Returns
    -------
    dict
        A ``Rectification`` (see ``docs/artifacts.md``), plus fixed-point maps
        for fast remapping (``map_left_fixed`` int16 HxWx2,
        ``map_left_interp`` uint16 HxW, same for right), ``K2``, ``D2``, ``R``,
        ``T_cm``, ``alpha`` and ``roi_left`` / ``roi_right`` (valid rectangles).
    """
    w, h = (int(v) for v in cal["image_size"])
    new = (int(round(w * output_scale)), int(round(h * output_scale)))
    K1, D1, K2, D2 = (np.asarray(cal[k], dtype=float) for k in ("K1", "D1", "K2", "D2"))
    R = np.asarray(cal["R"], dtype=float)
    T = np.asarray(cal["T_cm"], dtype=float).reshape(3, 1)
    flags = cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0
    R1, R2, P1, P2, Q, roi1, roi2 = cv2.stereoRectify(
        K1, D1, K2, D2, (w, h), R, T, flags=flags, alpha=alpha, newImageSize=new
    )
    if abs(P2[1, 3]) > abs(P2[0, 3]):
        raise NodeError(
            "rectifier.opencv: the cameras are stacked vertically; only side-by-side "
            "rigs are supported.",
            hint="rotate both images by 90 degrees before calibrating",
        )
    out = {
        "R1": R1,
        "R2": R2,
        "P1": P1,
        "P2": P2,
        "Q": Q,
        "image_size": list(new),
        "source_size": [w, h],
        "K1": K1,
        "D1": D1,
        "K2": K2,
        "D2": D2,
        "R": R,
        "T_cm": T.ravel(),
        "alpha": float(alpha),
        "roi_left": [int(v) for v in roi1],
        "roi_right": [int(v) for v in roi2],
    }
    for side, K, D, Rr, P in (("left", K1, D1, R1, P1), ("right", K2, D2, R2, P2)):
        mx, my = cv2.initUndistortRectifyMap(K, D, Rr, P, new, cv2.CV_32FC1)
        out[f"map_{side}_x"], out[f"map_{side}_y"] = mx, my
        # Fixed-point maps make cv2.remap about twice as fast; converted once here, not per image.
        fixed, interp = cv2.convertMaps(mx, my, cv2.CV_16SC2)
        out[f"map_{side}_fixed"], out[f"map_{side}_interp"] = fixed, interp
    out["f_px"] = float(P1[0, 0])
    out["cx_px"] = float(P1[0, 2])
    out["cy_px"] = float(P1[1, 2])
    out["cx_right_px"] = float(P2[0, 2])
    out["baseline_cm"] = float(-P2[0, 3] / P2[0, 0])
    if cal.get("T_table_from_left") is not None:
        out["T_table_from_left"] = np.asarray(cal["T_table_from_left"], dtype=float)
    out["dy_mean_px"] = None
    out["dy_max_px"] = None
    return out


def rectified_points(rect: dict, px: np.ndarray, side: str = "left") -> np.ndarray:
    """Map distorted source pixels (N, 2) to rectified pixels (N, 2)."""
    s = "1" if side == "left" else "2"
    pts = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
    out = cv2.undistortPoints(
        pts, rect["K" + s], rect["D" + s], R=rect["R" + s], P=rect["P" + s], criteria=_CRIT
    )
    return out.reshape(-1, 2)


def rectified_dy(rect: dict, corners_left: dict, corners_right: dict) -> tuple[float, float, int]:
    """Mean and max |v_left - v_right| (px) of matched corners after rectification, and their
    count."""
    dys = []
    for vid, cl in corners_left.items():
        if vid not in corners_right:
            continue
        a = rectified_points(rect, cl, "left")
        b = rectified_points(rect, corners_right[vid], "right")
        dys.append(np.abs(a[:, 1] - b[:, 1]))
    if not dys:
        return float("nan"), float("nan"), 0
    d = np.concatenate(dys)
    return float(d.mean()), float(d.max()), int(d.size)


def check_image(rect: dict, left: np.ndarray, right: np.ndarray, n_lines: int = 16) -> np.ndarray:
    """Side-by-side rectified pair with horizontal lines: matching points must sit on the same
    line."""

    def bgr(im):
        return cv2.cvtColor(im, cv2.COLOR_GRAY2BGR) if im.ndim == 2 else im

    rl = cv2.remap(bgr(left), rect["map_left_fixed"], rect["map_left_interp"], cv2.INTER_LINEAR)
    rr = cv2.remap(bgr(right), rect["map_right_fixed"], rect["map_right_interp"], cv2.INTER_LINEAR)
    img = np.hstack([rl, rr])
    h = img.shape[0]
    for k in range(1, n_lines + 1):
        y = int(round(k * h / (n_lines + 1)))
        cv2.line(img, (0, y), (img.shape[1] - 1, y), (0, 255, 0), 1)
    return img


def _check_title(cal: dict, rect: dict) -> str:
    """The check image's title: the figures that say whether rectification can be trusted."""
    rms = cal.get("rms_px")
    dy = rect.get("dy_mean_px")
    return (
        f"Rectified check ({cal.get('method', 'calibration')}): stereo RMS "
        + (f"{rms:.4f} px" if rms is not None else "n/a")
        + ", mean |dy| of matched corners "
        + (
            f"{dy:.3f} px (max {rect.get('dy_max_px', 0):.3f}, {rect.get('dy_n_points', 0)} points)"
            if dy is not None
            else "n/a (no corners)"
        )
        + "; green lines: matching points must share one"
    )


class RectifyParams(Params):
    alpha: float = Field(
        1.0,
        ge=-1,
        le=1,
        description="stereoRectify free scaling (unitless): 1 keeps the whole field of view so a "
        "ball near the border survives; 0 crops to valid pixels; -1 OpenCV's default.",
    )
    zero_disparity: bool = Field(
        True, description="Same principal point in both rectified images (switch)."
    )
    output_scale: float = Field(
        1.0, gt=0.1, le=4, description="Rectified size relative to the source (unitless)."
    )
    epipolar_lines: int = Field(
        16, ge=0, le=200, description="Horizontal lines drawn on the check image (count)."
    )


@node(
    "rectifier.opencv",
    inputs={
        "calibration": In("StereoCalibration"),
        "views": In(
            "StereoViews", optional=True, description="Calibration views, for the check image."
        ),
    },
    outputs={
        "rectification": Out(
            "Rectification", description="Maps, Q, f_px, baseline_cm, |dy| figures."
        ),
        "check_image": Out("Image", save=True, description="Rectified view with epipolar lines."),
        # the calibration with this rectification's R1 R2 P1 P2 Q (its alpha recorded): what the run
        # used
        **EXPORT_OUTPUTS,
    },
    params=RectifyParams,
    version="1",
)
def opencv(params: RectifyParams, calibration: dict, views: dict | None = None, ctx=None) -> dict:
    """Rectify a calibrated stereo rig: maps computed once, Q, focal length (px) and baseline (cm).

    Quality figure: mean and max |dy| of the calibration's matched chessboard
    corners after rectification (``dy_mean_px``, ``dy_max_px``).
    """
    rect = rectify_calibration(
        calibration, params.alpha, params.zero_disparity, params.output_scale
    )
    cl, cr = calibration.get("corners_left_px"), calibration.get("corners_right_px")
    if cl and cr:
        mean, mx, n = rectified_dy(rect, cl, cr)
        rect["dy_mean_px"], rect["dy_max_px"], rect["dy_n_points"] = mean, mx, n
    img = None
    if views and views.get("views"):
        pick = next((v for v in views["views"] if cl and str(v["id"]) in cl), views["views"][0])
        img = check_image(rect, pick["left"], pick["right"], params.epipolar_lines)
    else:
        # Without views, show where the rectified images hold valid source pixels.
        w, h = calibration["image_size"]
        white = np.full((int(h), int(w)), 200, np.uint8)
        img = check_image(rect, white, white, params.epipolar_lines)
    img = caption(img, [_check_title(calibration, rect)])
    if ctx is not None and rect["dy_mean_px"] is not None and rect["dy_mean_px"] > 0.5:
        ctx.warn(
            f"rectified corners differ by {rect['dy_mean_px']:.2f} px in y on average (> 0.5 px): "
            "the calibration is poor"
        )
    return {"rectification": rect, "check_image": img, **export_texts(calibration, rect)}
