"""``calibrator.chessboard``: Zhang's method through OpenCV (per camera, then the stereo pair)."""

from __future__ import annotations

from typing import Literal, NoReturn

import numpy as np

from nodes.calibrators._board import (
    board_points,
    detect_views,
    drop_outlier_views,
    stereo_calibrate_points,
)
from nodes.calibrators._calib_io import board_calibration_outputs
from nodes.contracts.calibration_export import EXPORT_OUTPUTS
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["ChessboardParams", "calibrate_stereo", "chessboard"]


def calibrate_stereo(
    ids: list[str],
    left: list[np.ndarray],
    right: list[np.ndarray],
    image_size,
    cols: int,
    rows: int,
    square_cm: float,
    refine: str = "joint",
    fix_k3: bool = False,
) -> dict:
    """Calibrate a stereo pair from chessboard corners (Zhang / OpenCV).

    See :func:`nodes.calibrators._board.stereo_calibrate_points` (per camera,
    then ``stereoCalibrate``; ``refine`` "joint" or "fix_intrinsic").

    Parameters
    ----------
    ids : list of str
        View ids, one per corner array.
    left, right : list of (N, 2) float32
        Corner pixels in the left / right images.
    image_size : (w, h)
        Pixels.
    cols, rows : int
        Inner corners of the board.
    square_cm : float
        Square size, cm (``T_cm`` comes out in this unit).
    refine : {"joint", "fix_intrinsic"}
    fix_k3 : bool
        Keep k3 = 0 (fewer parameters for mild lenses).

    Returns
    -------
    dict
        A ``StereoCalibration`` (see ``docs/artifacts.md``) plus
        ``mono_rms_px`` ([left, right]), ``corners_left_px`` /
        ``corners_right_px`` ({view_id: (N, 2)}) and ``board``.
    """
    obj = [board_points(cols, rows, square_cm)] * len(ids)
    cal = stereo_calibrate_points(ids, obj, left, right, image_size, refine, fix_k3)
    cal.update(
        {
            "method": f"chessboard/{refine}",
            "corners_left_px": dict(zip(ids, left)),
            "corners_right_px": dict(zip(ids, right)),
            "board": {"cols": cols, "rows": rows, "square_cm": float(square_cm)},
        }
    )
    return cal


class ChessboardParams(Params):
    refine: Literal["joint", "fix_intrinsic"] = Field(
        "joint",
        description="stereoCalibrate mode: 'joint' refines both cameras' intrinsics together "
        "with the "
        "pose (lower RMS and rectified |dy| here); 'fix_intrinsic' keeps per-camera results.",
    )
    fix_k3: bool = Field(
        False, description="Hold the 6th-order radial term k3 at 0 (unitless switch)."
    )
    subpix_window_px: int | None = Field(
        None,
        ge=2,
        le=30,
        description="Half-size of cornerSubPix's window, pixels (default: 40 % of the corner "
        "spacing).",
    )
    min_views: int = Field(3, ge=2, description="Fewest usable views to calibrate from (count).")
    max_view_rms_px: float | None = Field(
        None,
        gt=0,
        description="Drop the worst view while its reprojection RMS exceeds this (px), "
        "recalibrating "
        "after each; default: a view fitting 5x worse than the median view and over 0.5 px.",
    )
    max_rms_px: float = Field(
        2.0,
        gt=0,
        description="Refuse a calibration whose overall reprojection RMS exceeds this (px): its "
        "views do "
        "not fit one pair of cameras (a mismatched pair, a camera moved); good is < 0.5.",
    )


@node(
    "calibrator.chessboard",
    inputs={"views": In("StereoViews", description="Chessboard pairs.")},
    outputs={
        "calibration": Out(
            "StereoCalibration", save=True, description="Both cameras and their pose."
        ),
        **EXPORT_OUTPUTS,
    },
    params=ChessboardParams,
    version="1",
)
def chessboard(params: ChessboardParams, views: dict, ctx=None) -> dict:
    """Calibrate the stereo rig from chessboard views (OpenCV, Zhang's method).

    Views where the board is not found in either image are rejected and
    named (``rejected_views``; the reasons in ``rejected_reasons``).
    """
    board = views["board"]
    cols, rows, sq = int(board["cols"]), int(board["rows"]), float(board["square_cm"])
    vlist = views["views"]
    if not vlist:
        raise NodeError(
            "calibrator.chessboard: the view set is empty.",
            hint="point the source at chessboard images",
        )
    ids, left, right, rejected = detect_views(vlist, cols, rows, params.subpix_window_px)
    rejected = {**(views.get("rejected") or {}), **rejected}  # views the source could not read
    if len(ids) < params.min_views:
        _refuse_too_few_views(params, ids, rejected, len(vlist), cols, rows)
    at = {i: k for k, i in enumerate(ids)}

    def calibrate(keep: list[str]) -> dict:
        return calibrate_stereo(
            keep,
            [left[at[i]] for i in keep],
            [right[at[i]] for i in keep],
            views["image_size"],
            cols,
            rows,
            sq,
            params.refine,
            params.fix_k3,
        )

    cal = drop_outlier_views(
        calibrate, ids, params.min_views, params.max_view_rms_px, rejected, ctx, params.max_rms_px
    )
    return board_calibration_outputs(
        cal, rejected, board, params.max_rms_px, "calibrator.chessboard", ctx
    )


def _refuse_too_few_views(
    params: ChessboardParams, ids: list, rejected: dict, n_views: int, cols: int, rows: int
) -> NoReturn:
    """Too few views show the board: none (the board's size?), too few in all (add views), or
    some rejected (both), with each rejected view's reason."""
    named = f" ({'; '.join(f'{k}: {v}' for k, v in rejected.items())})" if rejected else ""
    board_hint = (
        "check board cols/rows (inner corners, e.g. 9x6 for a 10x7-square board) and "
        "that the whole "
        "board is visible in both images"
    )
    add_hint = (
        f"add chessboard views: at least {params.min_views} are needed (10-20 "
        "recommended, the board "
        "at several distances and tilts across the working range)"
    )
    if not ids:
        msg = (
            f"calibrator.chessboard: no {cols}x{rows} chessboard was found in any of "
            f"the {n_views} "
            f"views{named}."
        )
        hint = board_hint
    elif not rejected:  # every view shows the board: there are just too few of them
        msg = (
            f"calibrator.chessboard: all {n_views} views show the {cols}x{rows} board, but "
            f"{params.min_views} are needed."
        )
        hint = add_hint
    else:
        msg = (
            f"calibrator.chessboard: only {len(ids)} of {n_views} views show the "
            f"{cols}x{rows} board; "
            f"{params.min_views} are needed{named}."
        )
        hint = f"{board_hint}; or {add_hint}"
    raise NodeError(msg, hint=hint)
