"""Chessboard corner detection shared by the calibrators (pure functions)."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "board_points",
    "detect_corners",
    "detect_views",
    "larger_board",
    "orient_corners",
    "stereo_calibrate_points",
    "to_gray",
]

_CRIT = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-9)


def to_gray(img: np.ndarray) -> np.ndarray:
    """8-bit single-channel version of a grey or BGR(A) image."""
    img = np.asarray(img)
    if img.ndim == 2:
        return (
            img
            if img.dtype == np.uint8
            else cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
        )
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def board_points(cols: int, rows: int, square_cm: float) -> np.ndarray:
    """Inner corners in the board frame (cm, z = 0), in OpenCV's row-major order: (cols*rows, 3)
    float32."""
    gx, gy = np.meshgrid(np.arange(cols), np.arange(rows))
    pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1) * square_cm
    return pts.astype(np.float32)


def detect_corners(img: np.ndarray, cols: int, rows: int, subpix_window_px: int | None = None):
    """Find a chessboard's inner corners with sub-pixel refinement.

    Parameters
    ----------
    img : uint8 HxW or HxWx3
    cols, rows : int
        Inner corners per row / per column.
    subpix_window_px : int, optional
        Half-size of ``cornerSubPix``'s search window, pixels. Default: 40 % of
        the smallest spacing between neighbouring corners (clamped to 2..11), so
        the window never reaches the next corner whatever the board's size in
        the image.

    Returns
    -------
    (cols*rows, 2) float32 corner pixels, or ``None`` if the board is not found.
    """
    gray = to_gray(img)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=flags)
    if not found or corners is None:
        return None
    c = corners.reshape(-1, 2)
    if subpix_window_px is None:
        g = c.reshape(rows, cols, 2)
        d = np.concatenate(
            [
                np.linalg.norm(np.diff(g, axis=1), axis=2).ravel(),
                np.linalg.norm(np.diff(g, axis=0), axis=2).ravel(),
            ]
        )
        subpix_window_px = int(np.clip(0.4 * d.min(), 2, 11))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    refined = cv2.cornerSubPix(
        gray, corners.astype(np.float32), (subpix_window_px, subpix_window_px), (-1, -1), crit
    )
    return orient_corners(gray, refined.reshape(-1, 2).astype(np.float32), cols, rows)


def larger_board(img: np.ndarray, cols: int, rows: int) -> tuple[int, int] | None:
    """A board one corner wider or taller than ``cols x rows`` found in ``img``, or None.

    ``findChessboardCorners`` finds a ``cols x rows`` part of a larger board in most real images
    (OpenCV's 9x6 sample pairs: 12 of 13 at 8x6). A calibration from that part is still right (the
    squares have their size), but a frame put on the board (its first corner, its centre) is off by
    a square. Two detections of the one image, ~0.1-0.3 s when no larger board is there: a check for
    a frame put on one view (calibrator.table_frame), not for every calibration.
    """
    gray = to_gray(img)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    for size in ((cols + 1, rows), (cols, rows + 1)):
        found, _ = cv2.findChessboardCorners(gray, size, flags=flags)
        if found:
            return size
    return None


def orient_corners(gray: np.ndarray, c: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Put the corners in a fixed order: the square between the first four corners is the light one.

    ``findChessboardCorners`` may start from either end of the board (a 180
    degree turn of the list). Calibrating each view alone does not mind, but
    matching left and right corners, or using known board poses (Tsai), does.
    When ``cols + rows`` is even the board looks the same turned around and the
    order is left as found.
    """
    if (cols + rows) % 2 == 0:
        return c
    g = c.reshape(rows, cols, 2)

    def shade(i, j):
        centre = g[j : j + 2, i : i + 2].reshape(-1, 2).mean(axis=0)
        u, v = int(round(centre[0])), int(round(centre[1]))
        patch = gray[max(v - 1, 0) : v + 2, max(u - 1, 0) : u + 2]
        return float(patch.mean()) if patch.size else 0.0

    if shade(0, 0) < shade(1, 0):
        return np.ascontiguousarray(c[::-1])
    return c


def detect_views(views: list[dict], cols: int, rows: int, subpix_window_px: int | None = None):
    """Detect the board in both images of every view.

    Returns
    -------
    ids : list of view ids where both images gave a full detection
    left, right : lists of (N, 2) float32 corner arrays (same order as ``ids``)
    rejected : dict {view_id: reason}
    """
    ids, left, right, rejected = [], [], [], {}
    for v in views:
        cl = detect_corners(v["left"], cols, rows, subpix_window_px)
        cr = detect_corners(v["right"], cols, rows, subpix_window_px)
        if cl is None or cr is None:
            which = [s for s, c in (("left", cl), ("right", cr)) if c is None]
            names = [str(v.get(f"{s}_path", s + " image")) for s in which]
            rejected[str(v["id"])] = f"no {cols}x{rows} board found in {' and '.join(names)}"
            continue
        ids.append(str(v["id"]))
        left.append(cl)
        right.append(cr)
    return ids, left, right, rejected


def stereo_calibrate_points(
    ids: list[str],
    obj: list[np.ndarray],
    left: list[np.ndarray],
    right: list[np.ndarray],
    image_size,
    refine: str = "joint",
    fix_k3: bool = False,
    mono_left=None,
    mono_right=None,
) -> dict:
    """Calibrate a stereo pair from matched board points (Zhang / OpenCV).

    Each camera is calibrated alone (``calibrateCamera``), then
    ``stereoCalibrate`` finds the pose of the right camera; with
    ``refine="joint"`` it also refines both cameras' intrinsics from all the
    stereo constraints (``CALIB_USE_INTRINSIC_GUESS``), with ``"fix_intrinsic"``
    it keeps the per-camera results.

    Parameters
    ----------
    ids : list of str
        View ids, one per point array.
    obj : list of (N_i, 3) float32
        Board-frame points of each view, cm (``T_cm`` comes out in this unit).
    left, right : list of (N_i, 2) float32
        The same points' pixels in the left / right images.
    image_size : (w, h)
        Pixels.
    refine : {"joint", "fix_intrinsic"}
    fix_k3 : bool
        Keep k3 = 0 (fewer parameters for mild lenses).
    mono_left, mono_right : (obj list, pixel list), optional
        Points for the per-camera calibrations when a camera saw more than
        the points common to both (partial views); default: the stereo points.

    Returns
    -------
    dict
        ``K1 D1 K2 D2 R T_cm image_size rms_px per_view_rms_px rejected_views``
        (a ``StereoCalibration`` without ``method``) plus ``mono_rms_px``.
    """
    size = (int(image_size[0]), int(image_size[1]))
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    ol, pl = mono_left if mono_left is not None else (obj, left)
    orr, pr = mono_right if mono_right is not None else (obj, right)
    rms1, K1, D1, _, _ = cv2.calibrateCamera(ol, pl, size, None, None, flags=flags, criteria=_CRIT)
    rms2, K2, D2, _, _ = cv2.calibrateCamera(orr, pr, size, None, None, flags=flags, criteria=_CRIT)
    sflags = flags | (
        cv2.CALIB_USE_INTRINSIC_GUESS if refine == "joint" else cv2.CALIB_FIX_INTRINSIC
    )
    R0, T0 = np.eye(3), np.zeros((3, 1))
    out = cv2.stereoCalibrateExtended(
        obj, left, right, K1, D1, K2, D2, size, R0, T0, flags=sflags, criteria=_CRIT
    )
    rms, K1, D1, K2, D2, R, T, _E, _F, _rv, _tv, per_view = out
    per_view = np.asarray(per_view).reshape(len(ids), 2)
    return {
        "K1": K1,
        "D1": D1.ravel(),
        "K2": K2,
        "D2": D2.ravel(),
        "R": R,
        "T_cm": T.ravel(),
        "image_size": list(size),
        "rms_px": float(rms),
        "per_view_rms_px": {
            i: float(np.sqrt((e[0] ** 2 + e[1] ** 2) / 2)) for i, e in zip(ids, per_view)
        },
        "rejected_views": [],
        "mono_rms_px": [float(rms1), float(rms2)],
    }


#: A view fitting this many times worse than the median view is an outlier (a mismatched pair, a
#: board that moved between the two exposures, a wrong corner order) -- above an absolute floor, so
#: that a calibration at 0.05 px does not drop a 0.2 px view.
OUTLIER_VIEW_FACTOR = 5.0
OUTLIER_VIEW_FLOOR_PX = 0.5
#: ... or, in a calibration over ``max_rms_px``, this many times worse than the next worst view.
OUTLIER_VIEW_DOMINANT = 2.0


def drop_outlier_views(
    calibrate,
    ids: list[str],
    min_views: int,
    max_view_rms_px: float | None,
    rejected: dict[str, str],
    ctx=None,
    max_rms_px: float | None = None,
) -> dict:
    """Calibrate from ``ids`` (``calibrate(ids) -> StereoCalibration``), then drop the worst-fitting
    view and calibrate again while it fits worse than ``max_view_rms_px`` (default: 5x the median
    view and 0.5 px), one view at a time, since one bad view pulls every other view's error up with
    it. A view can pull them up so far (a pair with left and right swapped) that it is not 5x the
    median any more: with the default limit, while the overall RMS is over ``max_rms_px`` (the
    calibration would be refused) a view fitting over twice as badly as the next worst is dropped
    too. Dropped views are added to ``rejected`` with the reason; never below ``min_views`` (said by
    a warning).
    """
    keep = list(ids)
    cal = calibrate(keep)
    while True:
        per = {i: e for i, e in cal["per_view_rms_px"].items() if i in keep}
        if not per:
            return cal
        worst = max(per, key=per.get)
        if max_view_rms_px is not None:
            limit, why = max_view_rms_px, f"max_view_rms_px {max_view_rms_px:g}"
        else:
            limit = max(
                OUTLIER_VIEW_FLOOR_PX, OUTLIER_VIEW_FACTOR * float(np.median(list(per.values())))
            )
            why = f"{OUTLIER_VIEW_FACTOR:g}x the median view"
        if (
            per[worst] <= limit
            and max_view_rms_px is None
            and max_rms_px is not None
            and cal["rms_px"] > max_rms_px
            and len(per) > 1
        ):
            second = sorted(per.values())[-2]
            if per[worst] > OUTLIER_VIEW_DOMINANT * second:
                limit = OUTLIER_VIEW_DOMINANT * second
                why = (
                    f"{OUTLIER_VIEW_DOMINANT:g}x the next worst view, overall RMS "
                    f"{cal['rms_px']:.2f} px"
                )
        if per[worst] <= limit:
            return cal
        if len(keep) - 1 < min_views:
            if ctx is not None:
                ctx.warn(
                    f"view {worst} fits at {per[worst]:.2f} px (over {limit:.2f} px, "
                    f"{why}) but is kept: "
                    f"dropping it would leave fewer than min_views ({min_views}) views"
                )
            return cal
        rejected[worst] = f"reprojection RMS {per[worst]:.3f} px > {limit:.3f} px ({why}), dropped"
        keep.remove(worst)
        cal = calibrate(keep)


def check_overall_rms(cal: dict, max_rms_px: float, label: str) -> None:
    """Refuse a calibration whose views do not fit one rig (RMS over ``max_rms_px``), naming the
    worst views."""
    from stereograph.api import NodeError

    if cal["rms_px"] <= max_rms_px:
        return
    per = sorted(cal["per_view_rms_px"].items(), key=lambda kv: -kv[1])[:3]
    raise NodeError(
        f"{label}: the reprojection RMS is {cal['rms_px']:.2f} px (over max_rms_px "
        f"{max_rms_px:g}; a good "
        f"calibration is under 0.5 px): the views do not fit one pair of cameras; worst views "
        + ", ".join(f"{i} ({e:.2f} px)" for i, e in per)
        + ".",
        hint="check that each left image and its right image were taken at the same moment "
        "and belong "
        "together (file names, order), that the cameras did not move during the captures, and the "
        "board's cols/rows/square_cm; drop the worst views, or raise max_rms_px for a poor lens",
    )
