"""``report.calibration``: the pictures a person checks after a stereo calibration.

As MATLAB's Stereo Camera Calibrator shows them: the per-view reprojection error as a bar chart
(with the overall mean, and the views the calibrator left out), the detected corners drawn on every
view, and the cameras with every board pose in 3-D. Board poses are not part of a
``StereoCalibration``; they are recovered here from each view's detected left corners with
``cv2.solvePnP`` and the calibrated left intrinsics (so they are what the calibration implies,
not a second calibration). Only the drawing is new: every number comes from the calibration.
"""

from __future__ import annotations

import numpy as np

from nodes.contracts.drawing import caption, figure_bgr, load_figures, new_figure
from stereograph.api import Field, In, Out, Params, node


class CalibrationReportParams(Params):
    """Parameters of ``report.calibration``."""

    tile_width_px: int = Field(
        320, ge=80, le=1280, description="Width of one view in the corners mosaic (px)."
    )
    max_views: int = Field(
        24, ge=1, le=200, description="Views drawn in the corners mosaic (count)."
    )


def error_bars(cal: dict) -> np.ndarray:
    """Per-view stereo reprojection RMS (px) as bars, the overall RMS as a line; rejected views in
    red."""
    per_view = {str(k): float(v) for k, v in (cal.get("per_view_rms_px") or {}).items()}
    rejected = [str(v) for v in cal.get("rejected_views") or []]
    ids = list(per_view) + [r for r in rejected if r not in per_view]
    fig = new_figure(max(6.0, 0.35 * len(ids) + 2), 3.6)
    ax = fig.add_subplot(1, 1, 1)
    vals = [per_view.get(i, 0.0) for i in ids]
    colours = ["#c0392b" if i in rejected else "#2e86c1" for i in ids]
    ax.bar(range(len(ids)), vals, color=colours)
    for k, i in enumerate(ids):
        if i in rejected and i not in per_view:
            ax.text(
                k, 0, "rejected", rotation=90, ha="center", va="bottom", fontsize=7, color="#c0392b"
            )
    used = [per_view[i] for i in ids if i in per_view and i not in rejected]
    if used:
        mean = float(np.mean(used))
        ax.axhline(mean, ls="--", color="k", lw=1, label=f"mean of used views {mean:.3f} px")
    if cal.get("rms_px") is not None:
        ax.axhline(
            float(cal["rms_px"]),
            ls=":",
            color="#7d3c98",
            lw=1.2,
            label=f"overall RMS {cal['rms_px']:.4f} px",
        )
    ax.set_xticks(range(len(ids)), ids, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_xlabel("calibration view" + (" (red: left out by the calibrator)" if rejected else ""))
    ax.set_title(
        f"Per-view reprojection error — {cal.get('method', '')}, {len(used)} views used, "
        f"{len(rejected)} rejected",
        fontsize=10,
    )
    if used or cal.get("rms_px") is not None:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return figure_bgr(fig)


def corners_mosaic(views: dict, cal: dict, tile_w: int, max_views: int) -> np.ndarray:
    """Every view, left | right, with its detected corners drawn (first corner marked), in a
    grid."""
    import cv2

    cl, cr = cal.get("corners_left_px") or {}, cal.get("corners_right_px") or {}
    rejected = {str(v) for v in cal.get("rejected_views") or []}
    board = views.get("board") or {}
    pattern = (int(board.get("cols", 0)), int(board.get("rows", 0)))
    tiles = []
    for v in views.get("views", [])[:max_views]:
        vid = str(v["id"])
        pair = []
        for img, corners in ((v["left"], cl.get(vid)), (v["right"], cr.get(vid))):
            im = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img[..., :3]
            s = tile_w / im.shape[1]  # draw after scaling down, so the marks stay visible
            im = cv2.resize(
                im, (tile_w, max(1, int(round(im.shape[0] * s)))), interpolation=cv2.INTER_AREA
            )
            if corners is not None and len(corners):
                c = np.asarray(corners, np.float32).reshape(-1, 2) * s
                # OpenCV's drawing: rows coloured, joined in order
                if pattern[0] * pattern[1] == len(c):
                    cv2.drawChessboardCorners(im, pattern, c.reshape(-1, 1, 2), True)
                else:  # ChArUco: a subset of corners
                    for p in c:
                        cv2.circle(
                            im,
                            (int(round(p[0])), int(round(p[1]))),
                            2,
                            (0, 200, 0),
                            -1,
                            cv2.LINE_AA,
                        )
                cv2.circle(
                    im, (int(round(c[0, 0])), int(round(c[0, 1]))), 7, (0, 0, 255), 2, cv2.LINE_AA
                )
            pair.append(im)
        both = np.hstack(pair)
        n = len(cl.get(vid, [])) if vid in cl else 0
        status = ("rejected" if vid in rejected else "used") if vid in cl else "no corners found"
        colour = (0, 0, 200) if status != "used" else (0, 0, 0)
        tiles.append(caption(both, [(f"{vid}: {status}, {n} corners", colour)]))
    if not tiles:
        return caption(np.full((60, 2 * tile_w, 3), 255, np.uint8), ["no calibration views"])
    h = max(t.shape[0] for t in tiles)
    tiles = [np.vstack([t, np.full((h - t.shape[0], t.shape[1], 3), 255, np.uint8)]) for t in tiles]
    per_row = 2
    rows = []
    for k in range(0, len(tiles), per_row):
        row = tiles[k : k + per_row]
        row += [np.full_like(tiles[0], 255)] * (per_row - len(row))
        rows.append(np.hstack(row))
    return caption(
        np.vstack(rows),
        ["Detected corners (in detection order; red ring: the first corner), left | right"],
    )


def board_poses(cal: dict, views: dict | None) -> list[tuple[str, np.ndarray]]:
    """Each used view's board corners in the left-camera frame (cm, or squares), from solvePnP on
    its left corners."""
    import cv2

    board = (views or {}).get("board") or cal.get("board") or {}
    cl = cal.get("corners_left_px") or {}
    rejected = {str(v) for v in cal.get("rejected_views") or []}
    if not board.get("cols") or not cl:
        return []
    cols, rows, sq = int(board["cols"]), int(board["rows"]), float(board.get("square_cm", 1.0))
    grid = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2) * sq
    obj = np.hstack([grid, np.zeros((len(grid), 1))]).astype(np.float64)
    out = []
    for vid, c in cl.items():
        c = np.asarray(c, np.float64).reshape(-1, 2)
        if str(vid) in rejected or len(c) != len(obj):
            continue
        ok, rvec, tvec = cv2.solvePnP(
            obj, c, np.asarray(cal["K1"], float), np.asarray(cal["D1"], float)
        )
        if ok:
            R = cv2.Rodrigues(rvec)[0]
            outline = obj[[0, cols - 1, cols * rows - 1, cols * (rows - 1), 0]]
            out.append((str(vid), (R @ outline.T).T + tvec.reshape(1, 3)))
    return out


def _show(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV camera frame (x right, y down, z forward) to plot axes (x, depth, up)."""
    p = np.asarray(p, float).reshape(-1, 3)
    return p[:, 0], p[:, 2], -p[:, 1]


def poses_3d(cal: dict, views: dict | None) -> np.ndarray:
    """Both cameras (pyramids) and the board poses, left-camera frame, in the calibration's length
    unit.

    cm, or board squares when the calibration was made without a square size (``length_unit``).
    """
    unit = str(cal.get("length_unit") or "cm")
    fig = new_figure(7, 5.5)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    w, h = cal["image_size"]
    boards = board_poses(cal, views)
    depth = float(np.median([b[:, 2].mean() for _, b in boards])) * 0.2 if boards else 5.0
    R, T = np.asarray(cal["R"], float), np.asarray(cal["T_cm"], float).reshape(3)
    for name, K, Rw, C, colour, ls in (
        ("left", cal["K1"], np.eye(3), np.zeros(3), "#2e86c1", "-"),
        ("right", cal["K2"], R.T, -R.T @ T, "#c0392b", "--"),
    ):
        Kinv = np.linalg.inv(np.asarray(K, float))
        corners = [
            Kinv @ np.array([u, v, 1.0]) * depth for u, v in ((0, 0), (w, 0), (w, h), (0, h))
        ]
        pts = [C + Rw @ p for p in corners]
        for p in pts:
            ax.plot(*_show(np.array([C, p])), color=colour, lw=1, ls=ls)
        ax.plot(
            *_show(np.array(pts + [pts[0]])), color=colour, lw=1.5, ls=ls, label=f"{name} camera"
        )
    for vid, b in boards:
        ax.plot(*_show(b), lw=1, color="#555")
        ax.text(*[c[0] for c in _show(b[:1])], vid, fontsize=6)
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"z, depth ({unit})")
    ax.set_zlabel(f"-y, up ({unit})")
    ax.view_init(elev=20, azim=-60)
    try:
        ax.set_aspect("equal")
    except (NotImplementedError, ValueError):
        pass
    ax.legend(fontsize=8, loc="upper left")
    squares = "\nno square size given: lengths in board squares" if unit != "cm" else ""
    ax.set_title(
        f"Cameras and {len(boards)} board poses (left-camera frame, baseline "
        f"{float(np.linalg.norm(T)):.2f} {unit}){squares}",
        fontsize=10,
    )
    return figure_bgr(fig)


@node(
    "report.calibration",
    inputs={
        "calibration": In("StereoCalibration"),
        "views": In(
            "StereoViews",
            optional=True,
            description="The calibration views, for the corners mosaic.",
        ),
    },
    outputs={
        "reprojection_errors": Out(
            "Image",
            save=True,
            headline=True,
            description="Per-view reprojection RMS bar chart (px).",
        ),
        "corners": Out("Image", save=True, description="Detected corners drawn on every view."),
        "poses": Out(
            "Image", save=True, description="Cameras and board poses in 3-D (cm, or board squares)."
        ),
    },
    params=CalibrationReportParams,
    version="2",
    prepare=load_figures,
)
def calibration(
    params: CalibrationReportParams, calibration: dict, views: dict | None = None, ctx=None
) -> dict:
    """Calibration pictures: per-view reprojection error bars, corners on each view, cameras and
    boards in 3-D."""
    mosaic = (
        corners_mosaic(views, calibration, params.tile_width_px, params.max_views)
        if views
        else caption(np.full((40, 400, 3), 255, np.uint8), ["no views wired: corners not drawn"])
    )
    return {
        "reprojection_errors": error_bars(calibration),
        "corners": mosaic,
        "poses": poses_3d(calibration, views),
    }
