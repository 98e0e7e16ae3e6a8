"""``calibrator.table_frame``: the table frame from one stereo pair of a chessboard lying flat on
the table.

The frame (docs/conventions.md): origin at the board's inner corner nearest the cameras on the
left (as the cameras see it), x along the board's rows to the right, y along its columns away
from the cameras, z up out of the table. It is defined from the board's geometry, not from the
order in which the corner detector lists the corners, so a board turned by 180 degrees (which
``findChessboardCorners`` cannot tell apart when cols + rows is even) gives the same frame.

Both views are used: the board's pose is found in each camera alone (``solvePnP``), the right
camera's pose is carried into the left-camera frame through the stereo calibration, and the
disagreement of the two (translation, cm; rotation, degrees) is reported -- a large one means
that the calibration does not fit these images. The frame itself comes from one pose fitted to
both views at once (least-squares reprojection error over both images).

TableFrame artifact::

    {"T_table_from_left": 4x4 (cm),      # X_table = T @ [X_left, 1]
     "method": "board", "view": str, "board": {"cols", "rows", "square_cm"},
     "disagreement": {"translation_cm": float, "rotation_deg": float},   # left-only vs right-only
                                                                         # pose
     "reprojection_rms_px": {"left": float, "right": float},             # of the joint pose
     "flatness_cm": float,                 # largest |z| of the corners in the table frame
     "rig": {"image_size", "fx_px", "baseline_cm"}}                       # the calibration it used
"""

from __future__ import annotations

from typing import NoReturn

import cv2
import numpy as np
from scipy.optimize import least_squares

from nodes.calibrators._board import board_points, detect_corners, larger_board
from nodes.contracts.calibration_file import rig_fingerprint
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["TableFrameParams", "board_pose", "frame_from_board_pose", "table_frame"]


def _pose(rvec, tvec) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, float).ravel()
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def _angle_deg(Ra, Rb) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(Ra @ Rb.T)[0])))


def board_pose(obj: np.ndarray, px_left: np.ndarray, px_right: np.ndarray, cal: dict) -> dict:
    """The board's pose in the left-camera frame from each view alone and from both together.

    Parameters
    ----------
    obj : (N, 3)
        Board-frame corner positions, cm.
    px_left, px_right : (N, 2)
        The corners' pixels in the (distorted) left / right images.
    cal : dict
        A ``StereoCalibration`` (``X_right = R X_left + T_cm``).

    Returns
    -------
    dict
        ``T_left_from_board`` (joint, 4x4 cm), ``left_only`` / ``right_only`` (4x4),
        ``translation_cm`` / ``rotation_deg`` (their disagreement), ``rms_px`` ({left, right}).
    """
    K1, D1, K2, D2 = (np.asarray(cal[k], float) for k in ("K1", "D1", "K2", "D2"))
    T_rl = np.eye(4)
    T_rl[:3, :3], T_rl[:3, 3] = np.asarray(cal["R"], float), np.asarray(cal["T_cm"], float).ravel()
    obj = np.asarray(obj, np.float64)
    poses = []
    for K, D, px in ((K1, D1, px_left), (K2, D2, px_right)):
        # IPPE gives the planar pose without a local-minimum guess; the iterative refinement
        # polishes it.
        ok, rv, tv = cv2.solvePnP(obj, np.asarray(px, np.float64), K, D, flags=cv2.SOLVEPNP_IPPE)
        ok2, rv, tv = cv2.solvePnP(
            obj,
            np.asarray(px, np.float64),
            K,
            D,
            rv,
            tv,
            useExtrinsicGuess=True,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not (ok and ok2):
            raise ValueError("solvePnP found no pose for the board")
        poses.append(_pose(rv, tv))
    T_left = poses[0]
    T_right_in_left = _inv(T_rl) @ poses[1]

    def residual(x):
        T = _pose(x[:3], x[3:])
        rl, tl = cv2.Rodrigues(T[:3, :3])[0], T[:3, 3]
        Tr = T_rl @ T
        rr, tr = cv2.Rodrigues(Tr[:3, :3])[0], Tr[:3, 3]
        a = cv2.projectPoints(obj, rl, tl, K1, D1)[0].reshape(-1, 2) - px_left
        b = cv2.projectPoints(obj, rr, tr, K2, D2)[0].reshape(-1, 2) - px_right
        return np.concatenate([a.ravel(), b.ravel()])

    x0 = np.concatenate([cv2.Rodrigues(T_left[:3, :3])[0].ravel(), T_left[:3, 3]])
    sol = least_squares(residual, x0, method="lm", xtol=1e-12, ftol=1e-12)
    T = _pose(sol.x[:3], sol.x[3:])
    r = sol.fun.reshape(2, -1, 2)
    return {
        "T_left_from_board": T,
        "left_only": T_left,
        "right_only": T_right_in_left,
        "translation_cm": float(np.linalg.norm(T_left[:3, 3] - T_right_in_left[:3, 3])),
        "rotation_deg": _angle_deg(T_left[:3, :3], T_right_in_left[:3, :3]),
        "rms_px": {
            "left": float(np.sqrt((r[0] ** 2).sum(1).mean())),
            "right": float(np.sqrt((r[1] ** 2).sum(1).mean())),
        },
    }


def _paths(view: dict) -> str:
    """`` (LEFT_FILE, RIGHT_FILE)`` when the source says which files the view came from, else ''."""
    files = [str(view[k]) for k in ("left_path", "right_path") if view.get(k)]
    return f" ({', '.join(files)})" if files else ""


def _poses_agree(pose: dict, params: TableFrameParams) -> bool:
    """Whether the left-only and right-only board poses agree within the parameters' tolerances."""
    distance_cm = float(np.linalg.norm(pose["T_left_from_board"][:3, 3]))
    return (
        pose["translation_cm"] <= params.max_disagreement_fraction * distance_cm
        and pose["rotation_deg"] <= params.max_disagreement_deg
    )


def frame_from_board_pose(
    T_left_from_board: np.ndarray,
    cols: int,
    rows: int,
    square_cm: float,
    min_axis_margin_deg: float = 10.0,
) -> np.ndarray:
    """``T_table_from_left`` of a board lying on the table, by the conventions' rule.

    z is the board's normal on the cameras' side; y is the board axis (±rows, ±columns) closest
    to the horizontal direction the left camera looks in ("away from the cameras"); x = y × z;
    the origin is the extreme inner corner with the smallest x and y.

    Raises
    ------
    ValueError
        The board is turned so that two of its axes point away from the cameras about equally
        (within ``min_axis_margin_deg``), or it is seen nearly edge-on: the frame would be a guess.
    """
    Rb, tb = T_left_from_board[:3, :3], T_left_from_board[:3, 3]
    n = Rb[:, 2]
    z = n if n @ (-tb) > 0 else -n  # the normal on the cameras' side is "up out of the table"
    view = -tb / np.linalg.norm(tb)
    if abs(z @ view) < np.sin(np.radians(10)):
        raise ValueError(
            "the board is seen nearly edge-on (less than 10 degrees), so its plane is not reliable"
        )
    away = np.array([0.0, 0.0, 1.0]) - z[2] * z  # the optical axis, projected onto the table
    if np.linalg.norm(away) < 0.2:  # looking (almost) straight down: "away" is up in the image
        away = np.array([0.0, -1.0, 0.0]) - (-z[1]) * z
    away /= np.linalg.norm(away)
    cands = [Rb[:, 0], -Rb[:, 0], Rb[:, 1], -Rb[:, 1]]
    angles = np.degrees(np.arccos(np.clip([c @ away for c in cands], -1, 1)))
    order = np.argsort(angles)
    if angles[order[1]] - angles[order[0]] < min_axis_margin_deg:
        raise ValueError(
            f"the board is turned about {angles[order[0]]:.0f} degrees from the viewing "
            "direction, so "
            "which of its edges points away from the cameras is ambiguous"
        )
    y = cands[order[0]]
    x = np.cross(y, z)
    obj = board_points(cols, rows, square_cm).astype(float)
    ends = obj[[0, cols - 1, (rows - 1) * cols, rows * cols - 1]]
    P = ends @ Rb.T + tb
    origin = P[np.argmin(P @ x + P @ y)]  # axis-aligned rectangle: min x and min y at one corner
    T_left_from_table = np.eye(4)
    T_left_from_table[:3, :3] = np.column_stack([x, y, z])
    T_left_from_table[:3, 3] = origin
    return _inv(T_left_from_table)


class TableFrameParams(Params):
    view: str | None = Field(
        None,
        description="Id of the view that shows the board lying on the table "
        "(default: the only view).",
    )
    max_disagreement_fraction: float = Field(
        0.01,
        gt=0,
        le=0.5,
        description="Refuse the frame when the left-only and right-only board positions differ "
        "by more than this fraction of the board's distance (unitless; 0.01 = 1 %): "
        "the calibration does not fit these images.",
    )
    max_disagreement_deg: float = Field(
        1.0, gt=0, description="Same, for the board's orientation (degrees)."
    )
    min_axis_margin_deg: float = Field(
        10.0,
        gt=0,
        le=45,
        description="Refuse a board turned so that two edges point away from the cameras "
        "within this many degrees of each other (ambiguous axes).",
    )


@node(
    "calibrator.table_frame",
    inputs={
        "views": In(
            "StereoViews",
            description="One stereo pair of the calibration board lying on the table.",
        ),
        "calibration": In("StereoCalibration", description="The rig's calibration."),
    },
    outputs={
        "table_frame": Out(
            "TableFrame", save=True, description="T_table_from_left (cm) and checks."
        )
    },
    params=TableFrameParams,
    version="1",
)
def table_frame(params: TableFrameParams, views: dict, calibration: dict, ctx=None) -> dict:
    """The table frame from a chessboard lying on the table (solvePnP in both views, checked against
    the rig)."""
    label = "calibrator.table_frame"
    v = _the_view(params, views, label)
    board = views.get("board") or {}
    if board.get("type", "chessboard") != "chessboard":
        raise NodeError(
            f"{label}: the views show a {board.get('type')} board; the table frame needs "
            "a chessboard.",
            hint="lay the chessboard on the table",
        )
    cols, rows, sq = int(board["cols"]), int(board["rows"]), float(board["square_cm"])
    _check_size_and_units(v, board, calibration, label)
    pl, pr = _board_corners(v, cols, rows, label)
    obj = board_points(cols, rows, sq).astype(float)
    try:
        pose = board_pose(obj, pl.astype(float), pr.astype(float), calibration)
        T = frame_from_board_pose(
            pose["T_left_from_board"], cols, rows, sq, params.min_axis_margin_deg
        )
    except ValueError as exc:
        raise NodeError(
            f"{label}: view {v['id']}: {exc}.",
            hint="lay the board flat with its edges roughly along and across the viewing "
            "direction, "
            "fully visible in both images",
        ) from None
    dt, dr = pose["translation_cm"], pose["rotation_deg"]
    cal_sq = (calibration.get("board") or {}).get("square_cm")
    other_square = cal_sq is not None and abs(float(cal_sq) - sq) > 1e-6 * sq
    if not _poses_agree(pose, params):
        other_sq = float(cal_sq) if other_square else None
        _refuse_disagreement(label, v, pose, obj, (pl, pr), calibration, params, other_sq, sq)
    if other_square and ctx is not None:
        ctx.warn(
            f"the calibration was made with {float(cal_sq):g} cm squares, this board's "
            f"square_cm is {sq:g}: "
            "if it is the same board, the table frame is scaled wrong"
        )
    corners_table = (
        obj @ pose["T_left_from_board"][:3, :3].T + pose["T_left_from_board"][:3, 3]
    ) @ T[:3, :3].T + T[:3, 3]
    if ctx is not None:
        ctx.warn(
            f"left vs right board pose: {dt:.3f} cm, {dr:.3f} deg; reprojection RMS "
            f"{pose['rms_px']['left']:.3f} / {pose['rms_px']['right']:.3f} px"
        )
    return {
        "table_frame": {
            "T_table_from_left": T,
            "method": "board",
            "view": str(v["id"]),
            "board": {"cols": cols, "rows": rows, "square_cm": sq},
            "disagreement": {"translation_cm": dt, "rotation_deg": dr},
            "reprojection_rms_px": pose["rms_px"],
            "flatness_cm": float(np.abs(corners_table[:, 2]).max()),
            "rig": rig_fingerprint(calibration),
        }
    }


def _board_corners(v: dict, cols: int, rows: int, label: str) -> tuple[np.ndarray, np.ndarray]:
    """The board's inner corners in both images of view ``v``; NodeError when either lacks the
    board, or when a larger board is seen (the frame would sit on a part of it)."""
    pl, pr = detect_corners(v["left"], cols, rows), detect_corners(v["right"], cols, rows)
    if pl is None or pr is None:
        which = " and ".join(
            str(v.get(f"{s}_path", f"the {s} image"))
            for s, c in (("left", pl), ("right", pr))
            if c is None
        )
        raise NodeError(
            f"{label}: no {cols}x{rows} chessboard found in {which} of view {v['id']}.",
            hint="the whole board must be visible and sharp in both images; check cols/rows (inner "
            "corners) of the source's board",
        )
    bigger = larger_board(v["left"], cols, rows)
    if bigger is not None:  # the frame would sit on a part of the board, a square or more off
        raise NodeError(
            f"{label}: view {v['id']} shows a board with more inner corners than {cols}x{rows} (a "
            f"{bigger[0]}x{bigger[1]} board is found too): the table frame would be put "
            "on a part of it, "
            "a square or more away from where you expect it.",
            hint="set the source's board cols/rows to the whole board's inner corners (the "
            "points where "
            "four squares meet, e.g. 9x6 on a board of 10x7 squares)",
        )
    return pl, pr


def _the_view(params: TableFrameParams, views: dict, label: str) -> dict:
    """The one pair that shows the board on the table (``params.view``, or the only one)."""
    vlist = views.get("views") or []
    if params.view is not None:
        vlist = [v for v in vlist if str(v["id"]) == params.view]
        if not vlist:
            raise NodeError(
                f"{label}: no view {params.view!r} among "
                f"{', '.join(str(v['id']) for v in views.get('views') or []) or 'none'}.",
                hint="set view to the id of the pair showing the board on the table",
            )
    if len(vlist) != 1:
        raise NodeError(
            f"{label}: {len(vlist)} views given; the table frame needs exactly one, the "
            "board lying on "
            "the table.",
            hint="set `view` to its id, or point the source at a folder with that pair only",
        )
    return vlist[0]


def _check_size_and_units(v: dict, board: dict, calibration: dict, label: str) -> None:
    """The view is of the calibration's image size, and board and calibration measure in one
    unit."""
    if list(calibration["image_size"]) != [int(v["left"].shape[1]), int(v["left"].shape[0])]:
        raise NodeError(
            f"{label}: view {v['id']} is {v['left'].shape[1]}x{v['left'].shape[0]} px but the "
            f"calibration is for {calibration['image_size'][0]}x{calibration['image_size'][1]} px.",
            hint="use the calibration of these cameras at this resolution",
        )
    cal_unit, board_unit = calibration.get("length_unit", "cm"), board.get("length_unit", "cm")
    # a pose in squares against a calibration in cm (or the reverse) never agrees
    if cal_unit != board_unit:
        raise NodeError(
            f"{label}: the calibration's lengths are in {cal_unit} but the board's square "
            "size is in "
            f"{board_unit}{' (no square_cm given)' if board_unit == 'squares' else ''}.",
            hint="calibrate with the board's square_cm, or load the calibration with "
            "cm_per_unit = the "
            "square's size in cm"
            if cal_unit == "squares"
            else "give the board's square_cm (cm) to the source of the table pair",
        )


def _refuse_disagreement(
    label: str,
    v: dict,
    pose: dict,
    obj: np.ndarray,
    corners: tuple[np.ndarray, np.ndarray],
    calibration: dict,
    params: TableFrameParams,
    other_sq: float | None,
    sq: float,
) -> NoReturn:
    """The board's poses from the two images disagree: say why, most likely cause first (images
    swapped, another board's square size, else the calibration). ``other_sq``: the calibration
    board's square size (cm) when it differs from this board's ``sq``."""
    pl, pr = corners
    dt, dr = pose["translation_cm"], pose["rotation_deg"]
    distance_cm = float(np.linalg.norm(pose["T_left_from_board"][:3, 3]))
    msg = (
        f"{label}: the board's pose from the left image and from the right image "
        "(carried through the "
        f"calibration) differ by {dt:.3f} cm ({100 * dt / distance_cm:.2f} % of its distance "
        f"{distance_cm:.1f} cm) and {dr:.3f} deg"
    )
    try:
        swapped = board_pose(obj, pr.astype(float), pl.astype(float), calibration)
    except ValueError:
        swapped = None
    # (it was blamed on the calibration)
    if swapped is not None and _poses_agree(swapped, params):
        raise NodeError(
            f"{msg}; exchanged, the two images agree ({swapped['translation_cm']:.3f} "
            "cm): the left "
            f"and right images of view {v['id']} are swapped{_paths(v)}.",
            hint="swap the table pair's left and right files (or the source's left_glob / "
            "right_glob): the left image is the left camera's as the cameras look",
        )
    if other_sq is not None:
        raise NodeError(
            f"{msg}; the calibration was made with a board of {other_sq:g} cm "
            "squares, and this "
            f"board's square_cm is {sq:g}.",
            hint="give the table pair's source the square size of the board lying on the table "
            f"(--set board.square_cm={other_sq:g} if it is the calibration board)",
        )
    raise NodeError(
        f"{msg}.",
        hint="the calibration does not fit these images: calibrate again with these "
        "cameras as they stand, or check the board's square size",
    )
