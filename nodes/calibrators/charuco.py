"""``calibrator.charuco``: Zhang's method on a ChArUco board (OpenCV's aruco module).

A ChArUco board is a chessboard with an ArUco marker in every light square:
each inner corner has an id, so a view where part of the board is hidden or
out of the frame still gives the corners that are seen, and left and right
corners are matched by id.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from nodes.calibrators._board import stereo_calibrate_points, to_gray
from nodes.calibrators._calib_io import board_calibration_outputs
from nodes.contracts.board import charuco_board
from nodes.contracts.calibration_export import EXPORT_OUTPUTS
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["CharucoParams", "calibrate_charuco", "charuco", "detect_charuco"]


def detect_charuco(img: np.ndarray, detector) -> tuple[np.ndarray, np.ndarray]:
    """ChArUco corners in one image.

    Parameters
    ----------
    img : uint8 HxW or HxWx3
    detector : cv2.aruco.CharucoDetector
        Its ``detectBoard`` finds the markers, interpolates the inner corners
        from the markers around them (at least two) and refines them with
        ``cornerSubPix`` (window limited by the distance to the next corner).

    Returns
    -------
    ids : (N,) int
        Corner ids (row-major over the inner corners: ``id = row * cols + col``).
    px : (N, 2) float32
        Corner pixels; both empty when nothing is found.
    """
    corners, ids, _mc, _mi = detector.detectBoard(to_gray(img))
    if ids is None or corners is None or len(ids) == 0:
        return np.zeros(0, int), np.zeros((0, 2), np.float32)
    ids = ids.ravel().astype(int)
    order = np.argsort(ids)
    return ids[order], corners.reshape(-1, 2)[order].astype(np.float32)


def _spans_plane(ids: np.ndarray, cols: int) -> bool:
    # Corners on one line (one row, one column, a diagonal) do not fix a board pose: homography is
    # degenerate.
    if len(ids) < 4:
        return False
    g = np.stack([ids % cols, ids // cols], axis=1).astype(float)
    return bool(np.linalg.svd(g - g.mean(axis=0), compute_uv=False)[-1] > 1e-6)


def calibrate_charuco(
    views: list[dict],
    image_size,
    cols: int,
    rows: int,
    square_cm: float,
    dictionary: str = "DICT_4X4_50",
    marker_fraction: float = 0.7,
    refine: str = "joint",
    fix_k3: bool = False,
    min_corners: int = 8,
) -> tuple[dict | None, dict, int]:
    """Detect ChArUco corners in every view and calibrate the stereo pair on the corners seen by
    both cameras.

    Parameters
    ----------
    views : list of {"id", "left", "right"}
    image_size : (w, h)
        Pixels.
    cols, rows : int
        Inner corners of the board (the board has ``cols+1 x rows+1`` squares).
    square_cm : float
        Square size, cm.
    dictionary : str
        OpenCV ArUco dictionary name, e.g. ``"DICT_4X4_50"``.
    marker_fraction : float
        Marker side / square side (unitless).
    refine : {"joint", "fix_intrinsic"}
    fix_k3 : bool
    min_corners : int
        Fewest corners seen in both images for a view to count (count).

    Returns
    -------
    calibration : dict or None
        A ``StereoCalibration`` (``None`` when fewer than 3 views are usable)
        plus ``corners_left_px`` / ``corners_right_px`` / ``corner_ids``
        ({view_id: array}) and ``board``.
    rejected : dict
        {view_id: reason}.
    n_used : int
        Views used.
    """
    board = charuco_board(cols, rows, square_cm, dictionary, marker_fraction)
    ids, obj, left, right, rejected, mono = _common_corners(views, board, cols, min_corners)
    if len(ids) < 3 or min(len(mono["left"][0]), len(mono["right"][0])) < 3:
        return None, rejected, len(ids)
    cal = stereo_calibrate_points(
        ids,
        obj,
        left,
        right,
        image_size,
        refine,
        fix_k3,
        mono_left=mono["left"],
        mono_right=mono["right"],
    )
    cal.update(
        {
            "method": f"charuco/{refine}",
            "corners_left_px": dict(zip(ids, left)),
            "corners_right_px": dict(zip(ids, right)),
            "corner_ids": {
                i: np.round(o[:, 0] / square_cm).astype(int)
                + cols * np.round(o[:, 1] / square_cm).astype(int)
                for i, o in zip(ids, obj)
            },
            "board": {
                "cols": cols,
                "rows": rows,
                "square_cm": float(square_cm),
                "type": "charuco",
                "dictionary": dictionary,
                "marker_fraction": float(marker_fraction),
            },
        }
    )
    return cal, rejected, len(ids)


class CharucoParams(Params):
    dictionary: str | None = Field(
        None,
        description="ArUco dictionary name (e.g. DICT_4X4_50, DICT_5X5_100); default: the views' "
        "board "
        "description.",
    )
    marker_fraction: float | None = Field(
        None,
        gt=0.1,
        lt=1.0,
        description="Marker side / square side (unitless); default: the views' board "
        "description, else 0.7.",
    )
    refine: Literal["joint", "fix_intrinsic"] = Field(
        "joint",
        description="stereoCalibrate mode: 'joint' refines both cameras' intrinsics with the pose; "
        "'fix_intrinsic' keeps the per-camera results.",
    )
    fix_k3: bool = Field(
        False, description="Hold the 6th-order radial term k3 at 0 (unitless switch)."
    )
    min_corners: int = Field(
        8, ge=4, description="Fewest corners seen in both images for a view to count (count)."
    )
    min_views: int = Field(3, ge=3, description="Fewest usable views to calibrate from (count).")
    max_rms_px: float = Field(
        2.0,
        gt=0,
        description="Refuse a calibration whose overall reprojection RMS exceeds this (px): its "
        "views do "
        "not fit one pair of cameras (a mismatched pair, a camera moved); good is < 0.5.",
    )


@node(
    "calibrator.charuco",
    inputs={
        "views": In("StereoViews", description="ChArUco board pairs (partial views are fine).")
    },
    outputs={
        "calibration": Out(
            "StereoCalibration", save=True, description="Both cameras and their pose."
        ),
        **EXPORT_OUTPUTS,
    },
    params=CharucoParams,
    version="1",
)
def charuco(params: CharucoParams, views: dict, ctx=None) -> dict:
    """Calibrate the stereo rig from ChArUco board views (OpenCV aruco + Zhang's method).

    Corners are matched between the images by id, so views where the board
    is partly hidden or out of the frame still count; views with fewer than
    ``min_corners`` common corners are rejected and named.
    """
    board = views.get("board") or {}
    vlist = views.get("views") or []
    if not vlist:
        raise NodeError(
            "calibrator.charuco: the view set is empty.", hint="point the source at ChArUco images"
        )
    btype = board.get("type", "chessboard")
    dictionary = params.dictionary or board.get("dictionary")
    if btype != "charuco" and params.dictionary is None:
        raise NodeError(
            f"calibrator.charuco: the views show a {btype} board, not a ChArUco board.",
            hint="render ChArUco views (source.synthetic: --set rig.board_type=charuco), or set "
            "calib.dictionary for ChArUco images, or use calibrator.chessboard",
        )
    dictionary = dictionary or "DICT_4X4_50"
    frac = params.marker_fraction or float(board.get("marker_fraction", 0.7))
    cols, rows, sq = int(board["cols"]), int(board["rows"]), float(board["square_cm"])
    try:
        cal, rejected, n_used = calibrate_charuco(
            vlist,
            views["image_size"],
            cols,
            rows,
            sq,
            dictionary,
            frac,
            params.refine,
            params.fix_k3,
            params.min_corners,
        )
    except ValueError as exc:
        raise NodeError(
            f"calibrator.charuco: {exc}.",
            hint="set calib.dictionary to the printed board's dictionary, or use a smaller board",
        ) from exc
    rejected = {**(views.get("rejected") or {}), **rejected}  # views the source could not read
    if cal is None or n_used < params.min_views:
        named = "; ".join(f"{k}: {v}" for k, v in rejected.items())
        raise NodeError(
            f"calibrator.charuco: only {n_used} of {len(vlist)} views show at least "
            f"{params.min_corners} "
            f"{cols}x{rows} ChArUco corners ({dictionary}, markers {frac:g} of a square) "
            "in both images; "
            f"{params.min_views} are needed" + (f" ({named})." if named else "."),
            hint="check the board's inner-corner count, dictionary and marker fraction, the "
            "lighting and focus; "
            "or add views (10-20, the board at several distances and tilts)",
        )
    return board_calibration_outputs(
        cal, rejected, board, params.max_rms_px, "calibrator.charuco", ctx
    )


def _common_corners(views: list[dict], board, cols: int, min_corners: int):
    """``(view ids, board points, left px, right px, rejected, per-camera points)``: the ChArUco
    corners each view shows in both images (views with too few, or all on one line, rejected
    with why), and each camera's own corners for its intrinsics."""
    detector = cv2.aruco.CharucoDetector(board)
    pts3 = np.asarray(board.getChessboardCorners(), np.float32).reshape(-1, 3)
    # OpenCV's board frame starts at the outer corner of the first square; ours at the first inner
    # corner.
    pts3 = pts3 - pts3[0]
    ids, obj, left, right, rejected = [], [], [], [], {}
    mono = {"left": ([], []), "right": ([], [])}
    for v in views:
        vid = str(v["id"])
        found = {}
        for side in ("left", "right"):
            cid, px = detect_charuco(v[side], detector)
            found[side] = (cid, px)
            if len(cid) >= min_corners and _spans_plane(cid, cols):
                mono[side][0].append(pts3[cid])
                mono[side][1].append(px)
        (il, pl), (ir, pr) = found["left"], found["right"]
        common, kl, kr = np.intersect1d(il, ir, assume_unique=True, return_indices=True)
        if len(common) < min_corners or not _spans_plane(common, cols):
            names = {s: str(v.get(f"{s}_path", s + " image")) for s in ("left", "right")}
            rejected[vid] = (
                f"{len(common)} corners seen in both images ({names['left']}: {len(il)}, "
                f"{names['right']}: {len(ir)}); {min_corners} not all on one line are needed"
            )
            continue
        ids.append(vid)
        obj.append(pts3[common])
        left.append(pl[kl])
        right.append(pr[kr])
    return ids, obj, left, right, rejected, mono
