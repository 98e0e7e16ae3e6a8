"""Calibration boards of the synthetic rig: chessboard and ChArUco views at random poses and a
board lying on the table.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from nodes.contracts.board import charuco_board
from nodes.sources._lens import project_points
from nodes.sources._materials import _table_texture
from nodes.sources._raycast import _to_uint8
from nodes.sources._render import _empty_table
from nodes.sources._rig import _ray_grid


def board_corners_3d(cols: int, rows: int, square_cm: float) -> np.ndarray:
    """Inner corners in the board frame (cm), row-major as OpenCV reports them: (cols*rows, 3)."""
    gx, gy = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.stack([gx.ravel() * square_cm, gy.ravel() * square_cm, np.zeros(gx.size)], axis=1)


def _board_extent(cols, rows, square_cm):
    # Printed squares span [-1, cols] x [-1, rows] (in squares); a one-square white margin around.
    return np.array([-2.0, -2.0]) * square_cm, np.array([cols + 1.0, rows + 1.0]) * square_cm


def board_distance_range(
    rig: dict, cols: int, rows: int, square_cm: float, margin_px: float = 12.0
) -> tuple[float, float]:
    """Distances (cm) a person would hold this board at to calibrate this rig: from just farther
    than where the printed board (with its margin) first fits the left image face-on, to twice
    that -- the board filling most of the view, then about half of it. Never nearer than 30 cm
    or a narrower span than 30-60 cm (what a 640x480 rig of ~60 degrees and an A4 board use): a
    long lens or a large board moves the range out instead of failing to place the board."""
    lo, hi = _board_extent(cols, rows, square_cm)
    K = rig["truth"]["K1"]
    w, h = rig["truth"]["image_size"]
    fits_cm = max(
        K[0, 0] * (hi[0] - lo[0]) / max(w - 2 * margin_px, 1.0),
        K[1, 1] * (hi[1] - lo[1]) / max(h - 2 * margin_px, 1.0),
    )
    return max(30.0, 1.05 * float(fits_cm)), max(60.0, 2.1 * float(fits_cm))


def random_board_poses(
    rig: dict,
    n: int,
    rng,
    cols: int = 9,
    rows: int = 6,
    square_cm: float = 2.5,
    min_distance_cm: float | None = None,
    max_distance_cm: float | None = None,
    max_tilt_deg: float = 35.0,
    margin_px: float = 12.0,
) -> list[np.ndarray]:
    """Board poses ``T_left_from_board`` (4x4, cm) fully visible in both cameras.

    Distances are spread evenly over the range (default :func:`board_distance_range`) and tilts
    alternate in sign so that the views constrain the focal length and the distortion.
    """
    rng = np.random.default_rng(rng)
    near, far = board_distance_range(rig, cols, rows, square_cm, margin_px)
    min_distance_cm = near if min_distance_cm is None else min_distance_cm
    max_distance_cm = far if max_distance_cm is None else max_distance_cm
    lo, hi = _board_extent(cols, rows, square_cm)
    outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    edge = np.concatenate(
        [outline + (np.roll(outline, -1, 0) - outline) * s for s in np.linspace(0, 1, 9)]
    )
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    R, T = rig["truth"]["R"], rig["truth"]["T_cm"]
    poses = []
    for i in range(n):
        for _ in range(2000):
            z = rng.uniform(min_distance_cm, max_distance_cm)
            sgn = 1 if i % 2 == 0 else -1
            tilt = np.radians(
                [
                    sgn * rng.uniform(5, max_tilt_deg),
                    rng.uniform(-max_tilt_deg, max_tilt_deg),
                    rng.uniform(-20, 20),
                ]
            )
            Rb, _ = cv2.Rodrigues(tilt.reshape(3, 1))
            spread = 0.35 * z
            pos = np.array([rng.uniform(-spread, spread) + 4.0, rng.uniform(-0.7, 0.7) * spread, z])
            t = pos - Rb @ centre
            pl = edge @ Rb.T + t
            pr = pl @ R.T + T
            if pl[:, 2].min() < 5 or pr[:, 2].min() < 5:
                continue
            if _inside_both(rig, pl, pr, margin_px):
                Tm = np.eye(4)
                Tm[:3, :3], Tm[:3, 3] = Rb, t
                poses.append(Tm)
                break
        else:
            raise RuntimeError("could not place a calibration board fully inside both images")
    return poses


def _inside_both(rig: dict, pl: np.ndarray, pr: np.ndarray, margin_px: float) -> bool:
    """Whether points ``pl`` (left camera, cm) and ``pr`` (right camera) all project at least
    ``margin_px`` inside their images."""
    w, h = rig["truth"]["image_size"]
    for K, D, pts in (
        (rig["truth"]["K1"], rig["truth"]["D1"], pl),
        (rig["truth"]["K2"], rig["truth"]["D2"], pr),
    ):
        px = project_points(K, D, pts)
        if (
            px[:, 0].min() < margin_px
            or px[:, 1].min() < margin_px
            or px[:, 0].max() > w - 1 - margin_px
            or px[:, 1].max() > h - 1 - margin_px
        ):
            return False
    return True


def _tri(x):
    """Antiderivative of the unit square wave sign(sin(pi x)) (a triangle wave)."""
    return 1.0 - np.abs(np.mod(x, 2.0) - 1.0)


def _filtered_square(x, w):
    w = np.maximum(w, 1e-4)
    return (_tri(x + w / 2) - _tri(x - w / 2)) / w


# texture resolution of a ChArUco board's markers (6 texels per 4x4 marker cell at 0.7)
_CHARUCO_PX_PER_SQUARE = 84


@functools.lru_cache(maxsize=4)
def charuco_texture(
    cols: int,
    rows: int,
    dictionary: str = "DICT_4X4_50",
    marker_fraction: float = 0.7,
    px_per_square: int = _CHARUCO_PX_PER_SQUARE,
) -> tuple[np.ndarray, int]:
    """OpenCV's ChArUco board image (``CharucoBoard.generateImage``) for ``cols x rows`` inner
    corners.

    Returns the uint8 image ((rows+1)*px, (cols+1)*px), no margin, and the
    parity of the black squares (square (i, j) is black when ``(i + j) % 2 ==
    parity``). Square (0, 0) is the board's top-left square, i.e. board-frame
    squares [-1, 0] x [-1, 0] in the renderer's frame (inner corner 0 at the origin).
    """
    board = charuco_board(cols, rows, 1.0, dictionary, marker_fraction)
    size = ((cols + 1) * px_per_square, (rows + 1) * px_per_square)
    img = board.generateImage(size, marginSize=0, borderBits=1)
    img.setflags(write=False)
    h = px_per_square // 2
    parity = 0 if img[h, h] < 128 else 1
    return img, parity


def _charuco_reflectance(bx, by, gu, gv, cols, rows, charuco: dict) -> np.ndarray:
    """Reflectance (0..1) of a ChArUco board at board coordinates ``bx, by`` (squares).

    The squares are box-filtered analytically like the chessboard's (so the
    ChArUco corners are as exact); the markers are sampled from OpenCV's board
    image at 4x4 points spread over each pixel's footprint (``gu`` / ``gv``:
    d(bx, by)/du and /dv).
    """
    tex, parity = charuco_texture(
        cols,
        rows,
        str(charuco.get("dictionary", "DICT_4X4_50")),
        float(charuco.get("marker_fraction", 0.7)),
    )
    wx = np.abs(gu[0]) + np.abs(gv[0])
    wy = np.abs(gu[1]) + np.abs(gv[1])
    # sign(sin(pi bx)) * sign(sin(pi by)) is +1 on the squares whose (i + j) is even (i = floor(bx)
    # + 1)
    s = _filtered_square(bx, wx) * _filtered_square(by, wy)
    light = 0.5 + 0.5 * s if parity == 1 else 0.5 - 0.5 * s
    px = tex.shape[0] // (rows + 1)
    dark = np.zeros_like(bx)
    offs = (-0.375, -0.125, 0.125, 0.375)
    for ou in offs:
        for ov in offs:
            sx = bx + ou * gu[0] + ov * gv[0] + 1.0
            sy = by + ou * gu[1] + ov * gv[1] + 1.0
            ix = np.clip(np.floor(sx * px), 0, tex.shape[1] - 1).astype(np.intp)
            iy = np.clip(np.floor(sy * px), 0, tex.shape[0] - 1).astype(np.intp)
            light_square = (np.floor(sx) + np.floor(sy)) % 2 != parity
            dark += (tex[iy, ix] < 128) & light_square
    return np.clip(light - dark / len(offs) ** 2, 0.0, 1.0)


def render_board_view(
    rig: dict,
    pose_left_from_board: np.ndarray,
    cols: int = 9,
    rows: int = 6,
    square_cm: float = 2.5,
    seed: int = 0,
    noise_sigma: float | None = None,
    charuco: dict | None = None,
):
    """Render a chessboard (rigid plate, matte) floating over the table, seen by both cameras.

    The checker pattern is box-filtered analytically over each pixel's
    footprint, so corners are anti-aliased like a real camera's. With
    ``charuco={"dictionary": "DICT_4X4_50", "marker_fraction": 0.7}`` the
    board is OpenCV's ChArUco board instead (ArUco markers in the light
    squares; ``cols x rows`` inner corners, corner ``k`` is ChArUco id ``k``).

    Returns
    -------
    left, right : uint8 HxWx3 BGR
    corners : dict
        ``left_px`` / ``right_px`` -- (cols*rows, 2) true corner pixels
        (distorted images), ``board_cm`` -- (cols*rows, 3) board-frame points.
    """
    tex = _table_texture(int(rig["params"]["texture_seed"]))
    sigma = float(rig["params"]["noise_sigma"] if noise_sigma is None else noise_sigma)
    rng = np.random.default_rng(seed)
    w, h = rig["truth"]["image_size"]
    T_tl = rig["truth"]["T_table_from_left"]
    lo, hi = _board_extent(cols, rows, square_cm)
    imgs = []
    pts_b = board_corners_3d(cols, rows, square_cm)
    corners = {"board_cm": pts_b}
    for i in (0, 1):
        cam = rig["cams"][i]
        # Board pose in this camera's frame.
        if i == 0:
            Rcb, tcb = pose_left_from_board[:3, :3], pose_left_from_board[:3, 3]
        else:
            R, T = rig["truth"]["R"], rig["truth"]["T_cm"]
            Rcb, tcb = R @ pose_left_from_board[:3, :3], R @ pose_left_from_board[:3, 3] + T
        img = _board_image(rig, i, (Rcb, tcb), (lo, hi), cols, rows, square_cm, charuco, tex)
        imgs.append(_to_uint8(img, sigma, rng))
        corners["left_px" if i == 0 else "right_px"] = project_points(
            cam["K"], cam["D"], pts_b @ Rcb.T + tcb
        )
    corners["T_table_from_board"] = T_tl @ pose_left_from_board
    return imgs[0], imgs[1], corners


def _board_image(rig, i, pose, extent, cols, rows, square_cm, charuco, tex) -> np.ndarray:
    """Radiance image (H, W, 3 float) of camera ``i``: the table with the board at ``pose``
    (``(R, t)``, board to camera, cm) over it, its pattern box-filtered over each pixel."""
    cam = rig["cams"][i]
    w, h = rig["truth"]["image_size"]
    Rcb, tcb = pose
    lo, hi = extent
    rays_all = _ray_grid(cam, (w, h)).reshape(h, w, 3)
    img = _empty_table(rig, i, tex).astype(float)
    # Only the board's screen rectangle is traced (outline projected, plus a margin).
    outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    edge = np.concatenate(
        [outline + (np.roll(outline, -1, 0) - outline) * f for f in np.linspace(0, 1, 9)]
    )
    epx = project_points(cam["K"], cam["D"], edge @ Rcb.T + tcb)
    u0, v0 = int(max(epx[:, 0].min() - 3, 0)), int(max(epx[:, 1].min() - 3, 0))
    u1, v1 = int(min(epx[:, 0].max() + 3, w - 1)), int(min(epx[:, 1].max() + 3, h - 1))
    sh = (v1 - v0 + 1, u1 - u0 + 1)
    rays = rays_all[v0 : v1 + 1, u0 : u1 + 1].reshape(-1, 3)
    # Ray-plane intersection in the board frame: X(t) = t * ray, board z = 0.
    n = Rcb[:, 2]
    denom = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (n @ tcb) / denom
    P = t[:, None] * rays
    B = (P - tcb) @ Rcb  # board coordinates (cm)
    bx = (B[:, 0] / square_cm).reshape(sh)
    by = (B[:, 1] / square_cm).reshape(sh)
    inside = (
        (t > 0) & (B[:, 0] >= lo[0]) & (B[:, 0] <= hi[0]) & (B[:, 1] >= lo[1]) & (B[:, 1] <= hi[1])
    )
    # Footprint of a pixel in board squares (for the box filter).
    gxu, gxv = np.gradient(bx, axis=1), np.gradient(bx, axis=0)
    gyu, gyv = np.gradient(by, axis=1), np.gradient(by, axis=0)
    wx = np.abs(gxu) + np.abs(gxv)
    wy = np.abs(gyu) + np.abs(gyv)
    if charuco is None:
        checker = 0.5 + 0.5 * _filtered_square(bx, wx) * _filtered_square(by, wy)
    else:
        checker = _charuco_reflectance(bx, by, (gxu, gyu), (gxv, gyv), cols, rows, charuco)
    pattern = (bx >= -1) & (bx <= cols) & (by >= -1) & (by <= rows)
    refl = np.where(pattern, 0.10 + 0.80 * checker, 0.92).ravel()
    # Two-sided matte plate lit by the rig's lamp (table frame -> camera frame).
    L_cam = (rig["light_table"] - cam["origin_table"]) @ cam["R_table_from_cam"]
    to_l = L_cam[None, :] - P
    lam = np.abs(to_l @ n) / np.linalg.norm(to_l, axis=1)
    # Boards are held up facing the cameras, so they get more ambient light than the table.
    shade = (0.6 + 0.4 * lam) * refl
    roi = img[v0 : v1 + 1, u0 : u1 + 1].reshape(-1, 3)
    roi[inside] = shade[inside, None]
    img[v0 : v1 + 1, u0 : u1 + 1] = roi.reshape(*sh, 3)
    return img


def render_table_board(
    rig: dict,
    cols: int = 9,
    rows: int = 6,
    square_cm: float = 2.5,
    yaw_deg: float = 0.0,
    centre_table_cm=(0.0, 5.0),
    seed: int = 1,
):
    """Render a chessboard lying flat on the table, turned ``yaw_deg`` about the vertical.

    Returns
    -------
    left, right : uint8 HxWx3 BGR
    T_frame_from_left : 4x4 (cm)
        The table frame this board defines by docs/conventions.md (origin at its inner corner
        nearest the cameras on the left, x right, y away, z up) -- exact when ``yaw_deg`` is a
        multiple of 90, i.e. when the board's edges run along and across the view.
    """
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    T_tb = np.eye(4)
    T_tb[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    centre = np.array([(cols - 1) * square_cm / 2, (rows - 1) * square_cm / 2, 0.0])
    T_tb[:3, 3] = np.array([*centre_table_cm, 0.0]) - T_tb[:3, :3] @ centre
    T_tl = np.asarray(rig["truth"]["T_table_from_left"], float)
    left, right, corners = render_board_view(
        rig, np.linalg.inv(T_tl) @ T_tb, cols, rows, square_cm, seed=seed
    )
    P = corners["board_cm"] @ T_tb[:3, :3].T + T_tb[:3, 3]
    T = np.eye(4)
    T[:3, 3] = -P[np.argmin(P[:, 0] + P[:, 1])]
    return left, right, T @ T_tl
