"""Ray-cast renderer of a synthetic stereo rig: pure functions, no engine imports.

This module is the physics behind ``source.synthetic``; other nodes and tests
import it to build scenes with exact ground truth. Every pixel's ray is cast
through the camera's distortion model (OpenCV's k1 k2 p1 p2 k3 model, inverted
exactly by Newton iterations) into a 3-D scene: a textured table (plane
``z = 0`` of the table frame), a matte ball, optional clutter objects, lit by a
point light with Lambertian shading and soft cast shadows. The ball's edge is
anti-aliased by supersampling the pixels near its silhouette (10 x 10 rays per
pixel), so that the centroid of its rendered pixels is accurate to about
0.01 px.

Public API (stable)
-------------------
``make_rig(**params) -> rig``
    Build the two cameras, their pose over the table and the light. ``rig`` is a
    dict; ``rig["truth"]`` is the plain-data ``RigTruth`` artifact (see
    ``docs/artifacts.md``). Parameters are those of :data:`RIG_DEFAULTS`.
``make_scene(rig, kind="plain", rng=None, **overrides) -> scene``
    Draw a random scene of a given kind (see :data:`SCENE_KINDS`).
``render_scene(rig, scene, seed=0, noise_sigma=None, coverage=False) -> (left, right, truth)``
    Render one stereo pair (uint8 BGR) and its ground truth (the
    ``StereoPair.truth`` dict; ``None`` when the scene has no ball).
``render_board_view(rig, pose_left_from_board, seed=0, noise_sigma=None) -> (left, right, corners)``
    Render a chessboard calibration view; ``corners`` holds the true corner
    pixels in both images.
``random_board_poses(rig, n, rng) -> list of 4x4``
    Board poses (left-camera frame, cm) fully visible in both cameras.
``silhouette(K, D, center_cam_cm, radius_cm) -> dict``
    The exact outline of a sphere: the ellipse cut by its tangent cone in the
    ideal (undistorted) image, and the area centroid / area of the true
    (distorted) silhouette, computed from a dense polygon of its boundary.
``project_points(K, D, pts_cam)`` / ``undistort_pixels(K, D, px)``
    The camera model and its exact inverse (pixels <-> normalised rays).

Scene description (plain data, JSON/YAML friendly)
--------------------------------------------------
::

    {"kind": "plain",                      # free label, copied into truth
     "ball": {"center_cm": [x, y],         # table frame; resting on the table
              "radius_cm": 2.0,            # (give [x, y, z] to float it)
              "color": "orange"},          # name (see COLORS) or [b, g, r] 0..255
     "objects": [                          # optional clutter, any number
        {"type": "box", "center_cm": [x, y], "size_cm": [sx, sy, sz],
         "yaw_deg": 20, "color": "blue"},
        {"type": "cylinder", "center_cm": [x, y], "radius_cm": 2, "height_cm": 8,
         "color": "green"},
        {"type": "ball", "center_cm": [x, y], "radius_cm": 2.5, "color": "red"}]}

``"ball": None`` renders a scene without the target (truth is then ``None``).

Hard scenes
-----------
Ask :func:`make_scene` for a ``kind`` among :data:`SCENE_KINDS`:
``"plain"`` (ball alone), ``"clutter"`` (boxes and cylinders of other colours
near the ball), ``"second_ball"`` (another ball of another colour),
``"border"`` (ball partly cut by the left or right image border),
``"occluded"`` (a box between the left camera and the ball hides part of it),
``"hidden"`` (the ball is entirely hidden in the left image), ``"empty"`` (no
ball), and issue 15's partial-view / touching kinds of :mod:`._hard_scenes` (``border_cut``,
``occluded_part``, ``touching_box``, ``touching_ball``, ``distractor``, ``same_color``).
``source.synthetic`` exposes them as ``hard_cases: [clutter, border]``
(``n_hard_each`` scenes per kind) and accepts explicit scene dicts in its
``scenes`` parameter. The truth of every pair carries ``kind``,
``visible_fraction_left`` / ``_right`` (visible share of the silhouette) and
``touches_border_left`` / ``_right``.

Frames: the table frame has its origin on the table where the left camera's
optical axis meets it, x to the right (along the baseline), y away from the
cameras, z up. ``T_table_from_left`` maps left-camera points (cm) into it.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import cv2
import numpy as np

from nodes.contracts.board import charuco_board
from nodes.sources._hard_scenes import HARD_KINDS, make_hard_scene

__all__ = [
    "COLORS",
    "RIG_DEFAULTS",
    "SCENE_KINDS",
    "board_corners_3d",
    "color_bgr",
    "distort_normalized",
    "make_rig",
    "make_scene",
    "project_points",
    "random_board_poses",
    "render_board_view",
    "render_table_board",
    "render_scene",
    "silhouette",
    "undistort_normalized",
    "undistort_pixels",
]

#: Default rig parameters (units in the names; angles in degrees).
RIG_DEFAULTS: dict[str, Any] = {
    "image_width_px": 640,
    "image_height_px": 480,
    "focal_length_px": 560.0,
    "focal_ratio_right": 1.006,  # right lens slightly longer: cameras differ
    "principal_offset_left_px": (2.5, -1.5),
    "principal_offset_right_px": (-2.0, 2.0),
    "distortion_left": (-0.12, 0.06, 0.0008, -0.0005),  # k1 k2 p1 p2
    "distortion_right": (-0.10, 0.04, -0.0006, 0.0007),
    "baseline_cm": 8.0,
    "rotation_deg": (0.6, -1.2, 0.4),  # right-from-left rotation vector, degrees
    "camera_height_cm": 32.0,
    "camera_tilt_deg": 45.0,  # optical axis below the horizontal
    "light_cm": (18.0, 12.0, 90.0),  # point light, table frame
    "ambient": 0.35,
    "shadow_strength": 0.7,
    "noise_sigma": 2.0,  # grey levels
    "texture_seed": 7,
}

#: Scene kinds understood by :func:`make_scene`.
SCENE_KINDS = ("plain", "clutter", "second_ball", "border", "occluded", "hidden", "empty", *HARD_KINDS)

#: Named colours (BGR, 0..255) for balls and objects.
COLORS: dict[str, tuple[int, int, int]] = {
    "orange": (20, 120, 245),
    "red": (40, 40, 210),
    "green": (60, 170, 50),
    "blue": (200, 90, 30),
    "yellow": (30, 210, 230),
    "white": (235, 235, 235),
    "purple": (150, 50, 120),
    "grey": (128, 128, 128),
    "black": (30, 30, 30),
    "pink": (180, 120, 250),
    "cyan": (210, 200, 40),
}

_SUPERSAMPLE = 10  # rays per pixel side near a ball's silhouette (100 per pixel)


def color_bgr(color: Any) -> np.ndarray:
    """Albedo (0..1, BGR float) of a colour name or a ``[b, g, r]`` triple (0..255)."""
    if isinstance(color, str):
        if color not in COLORS:
            raise ValueError(f"unknown colour {color!r}; use one of {sorted(COLORS)} or [b, g, r]")
        color = COLORS[color]
    c = np.asarray(color, dtype=float).reshape(3)
    if np.any(c < 0) or np.any(c > 255):
        raise ValueError(f"colour {list(c)} is out of 0..255")
    return c / 255.0


# --------------------------------------------------------------------------------------------
# Camera model
# --------------------------------------------------------------------------------------------


def _dist5(D) -> tuple[float, float, float, float, float]:
    d = np.zeros(5)
    d[: min(5, len(np.ravel(D)))] = np.ravel(D)[:5]
    return tuple(float(x) for x in d)  # type: ignore[return-value]


def distort_normalized(xy: np.ndarray, D) -> np.ndarray:
    """Apply OpenCV's distortion (k1 k2 p1 p2 k3) to normalised points.

    Parameters
    ----------
    xy : (..., 2) array
        Undistorted normalised image coordinates (x/z, y/z).
    D : array-like, (4,) or (5,)
        Distortion coefficients.

    Returns
    -------
    (..., 2) array of distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = _dist5(D)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_normalized(xyd: np.ndarray, D, iterations: int = 12, guess: np.ndarray | None = None) -> np.ndarray:
    """Exact inverse of :func:`distort_normalized` (Newton's method).

    OpenCV's ``undistortPoints`` stops after 5 fixed-point iterations, which
    leaves ~0.01 px errors in the corners of a strongly distorted image; the
    renderer needs the model inverted to machine precision so that its images
    and its ground truth agree.
    """
    k1, k2, p1, p2, k3 = _dist5(D)
    xd, yd = xyd[..., 0].astype(float), xyd[..., 1].astype(float)
    if guess is None:
        x, y = xd.copy(), yd.copy()
    else:
        x, y = guess[..., 0].astype(float), guess[..., 1].astype(float)
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        fx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
        fy = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
        j11 = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x
        j12 = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y
        j22 = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x
        det = j11 * j22 - j12 * j12
        x = x - (j22 * fx - j12 * fy) / det
        y = y - (j11 * fy - j12 * fx) / det
    return np.stack([x, y], axis=-1)


def project_points(K: np.ndarray, D, pts_cam: np.ndarray) -> np.ndarray:
    """Project camera-frame points (cm) to distorted pixels: (N, 3) -> (N, 2)."""
    pts = np.asarray(pts_cam, dtype=float).reshape(-1, 3)
    xy = pts[:, :2] / pts[:, 2:3]
    xyd = distort_normalized(xy, D)
    return np.stack([K[0, 0] * xyd[:, 0] + K[0, 1] * xyd[:, 1] + K[0, 2], K[1, 1] * xyd[:, 1] + K[1, 2]], axis=1)


def undistort_pixels(K: np.ndarray, D, px: np.ndarray, guess: np.ndarray | None = None,
                     iterations: int = 12) -> np.ndarray:
    """Normalised undistorted coordinates (x/z, y/z) of distorted pixels: (N, 2) -> (N, 2).

    ``guess`` (N, 2) optionally starts the Newton iterations closer to the answer.
    """
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    yd = (px[:, 1] - K[1, 2]) / K[1, 1]
    xd = (px[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    return undistort_normalized(np.stack([xd, yd], axis=1), D, iterations=iterations, guess=guess)


def _rotvec(deg3) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.radians(np.asarray(deg3, dtype=float)).reshape(3, 1))
    return R


# --------------------------------------------------------------------------------------------
# Rig
# --------------------------------------------------------------------------------------------


def make_rig(**params: Any) -> dict:
    """Build a synthetic stereo rig looking down at a table.

    Parameters
    ----------
    **params
        Any key of :data:`RIG_DEFAULTS` (units in the names: ``_px``, ``_cm``,
        ``_deg``). ``distortion_*`` are ``(k1, k2, p1, p2)``; ``rotation_deg``
        is the rotation vector of the right camera relative to the left one.

    Returns
    -------
    rig : dict
        ``truth`` (the ``RigTruth`` artifact: K1 D1 K2 D2 R T_cm image_size
        T_table_from_left), ``params`` (the merged parameters), and per-camera
        poses in the table frame (``cams``: origin and rotation) plus the
        light. Plain data except for cached ray grids.
    """
    unknown = set(params) - set(RIG_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown rig parameter(s) {sorted(unknown)}; known: {sorted(RIG_DEFAULTS)}")
    p = {**RIG_DEFAULTS, **params}
    w, h = int(p["image_width_px"]), int(p["image_height_px"])
    f = float(p["focal_length_px"])
    cx0, cy0 = (w - 1) / 2.0, (h - 1) / 2.0

    def K_of(fpx, off):
        return np.array([[fpx, 0.0, cx0 + off[0]], [0.0, fpx, cy0 + off[1]], [0.0, 0.0, 1.0]])

    K1 = K_of(f, p["principal_offset_left_px"])
    K2 = K_of(f * float(p["focal_ratio_right"]), p["principal_offset_right_px"])
    D1 = np.array([*p["distortion_left"], 0.0], dtype=float)
    D2 = np.array([*p["distortion_right"], 0.0], dtype=float)
    R = _rotvec(p["rotation_deg"])
    # The right camera's centre sits baseline_cm along the left camera's x axis.
    C2_left = np.array([float(p["baseline_cm"]), 0.0, 0.0])
    T = -R @ C2_left

    tilt = math.radians(float(p["camera_tilt_deg"]))
    height = float(p["camera_height_cm"])
    # Columns = left camera axes expressed in the table frame (x right, y down-ish, z forward-down).
    R_tl = np.column_stack(
        [[1.0, 0.0, 0.0], [0.0, -math.sin(tilt), -math.cos(tilt)], [0.0, math.cos(tilt), -math.sin(tilt)]]
    )
    C1_table = np.array([0.0, -height / math.tan(tilt), height])
    T_table_from_left = np.eye(4)
    T_table_from_left[:3, :3] = R_tl
    T_table_from_left[:3, 3] = C1_table
    R_tr = R_tl @ R.T  # right camera axes in the table frame
    C2_table = R_tl @ C2_left + C1_table

    truth = {
        "K1": K1,
        "D1": D1,
        "K2": K2,
        "D2": D2,
        "R": R,
        "T_cm": T,
        "image_size": [w, h],
        "T_table_from_left": T_table_from_left,
    }
    return {
        "truth": truth,
        "params": p,
        "cams": [
            {"K": K1, "D": D1, "R_table_from_cam": R_tl, "origin_table": C1_table},
            {"K": K2, "D": D2, "R_table_from_cam": R_tr, "origin_table": C2_table},
        ],
        "light_table": np.asarray(p["light_cm"], dtype=float),
    }


@functools.lru_cache(maxsize=8)
def _ray_grid_cached(key: tuple) -> np.ndarray:
    fx, s, cx, fy, cy, d, w, h = key
    K = np.array([[fx, s, cx], [0, fy, cy], [0, 0, 1.0]])
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    xy = undistort_pixels(K, np.array(d), np.stack([u.ravel(), v.ravel()], axis=1))
    rays = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    rays.setflags(write=False)
    return rays


def _ray_grid(cam: dict, size: tuple[int, int]) -> np.ndarray:
    """Camera-frame ray (x/z, y/z, 1) of every pixel centre, row-major (H*W, 3); cached."""
    K = cam["K"]
    key = (K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], tuple(float(x) for x in cam["D"]), *size)
    return _ray_grid_cached(key)


# --------------------------------------------------------------------------------------------
# Table texture
# --------------------------------------------------------------------------------------------

_TEX_CM = 100.0  # the texture tile covers 100 x 100 cm and repeats
_TEX_PX = 2048


@functools.lru_cache(maxsize=4)
def _table_texture(seed: int) -> np.ndarray:
    """A wood-like BGR float32 texture tile (0..1): grain + mottling + fine speckle."""
    rng = np.random.default_rng(seed)
    n = _TEX_PX

    def noise(cells):
        small = rng.standard_normal((cells, cells)).astype(np.float32)
        return cv2.resize(small, (n, n), interpolation=cv2.INTER_CUBIC)

    yy = np.arange(n, dtype=np.float32)[:, None] * (_TEX_CM / n)
    grain = np.sin(2 * np.pi * (yy / 0.9 + 0.8 * noise(12)))  # planks' grain along x
    tone = 1.0 + 0.10 * noise(8) + 0.10 * grain + 0.06 * noise(200) + 0.05 * noise(700)
    base = np.array([0.42, 0.58, 0.70], dtype=np.float32)  # light wood, BGR
    tex = np.clip(tone[..., None] * base, 0.0, 1.0)
    tex.setflags(write=False)
    return tex


def _sample_texture(tex: np.ndarray, x_cm: np.ndarray, y_cm: np.ndarray) -> np.ndarray:
    scale = _TEX_PX / _TEX_CM
    n = x_cm.size
    cols = 1024  # remap wants maps smaller than 32767 on each side
    pad = (-n) % cols
    # The tile is centred on the table origin so that its seams (at +-50 cm) stay out of view.
    mx = np.pad(((x_cm + _TEX_CM / 2) * scale).astype(np.float32), (0, pad)).reshape(-1, cols)
    my = np.pad(((y_cm + _TEX_CM / 2) * scale).astype(np.float32), (0, pad)).reshape(-1, cols)
    out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return out.reshape(-1, 3)[:n].astype(float)


# --------------------------------------------------------------------------------------------
# Scene objects (table frame, cm)
# --------------------------------------------------------------------------------------------


def _objects_of(scene: dict) -> list[dict]:
    """Normalise the scene into a list of primitives; the target ball (if any) first."""
    objs = []
    ball = scene.get("ball")
    if ball is not None:
        c = list(ball["center_cm"])
        r = float(ball.get("radius_cm", 2.0))
        if len(c) == 2:
            c = [c[0], c[1], r]
        objs.append({"type": "sphere", "c": np.asarray(c, float), "r": r,
                     "albedo": color_bgr(ball.get("color", "orange")), "target": True})
    for o in scene.get("objects", []) or []:
        t = o.get("type", "box")
        col = color_bgr(o.get("color", "grey"))
        if t in ("ball", "sphere"):
            r = float(o.get("radius_cm", 2.0))
            c = list(o["center_cm"])
            if len(c) == 2:
                c = [c[0], c[1], r]
            objs.append({"type": "sphere", "c": np.asarray(c, float), "r": r, "albedo": col, "target": False})
        elif t == "box":
            sx, sy, sz = (float(v) for v in o["size_cm"])
            yaw = math.radians(float(o.get("yaw_deg", 0.0)))
            Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1.0]])
            c = np.array([o["center_cm"][0], o["center_cm"][1], sz / 2.0], float)
            objs.append({"type": "box", "c": c, "half": np.array([sx, sy, sz]) / 2.0, "Rz": Rz, "albedo": col})
        elif t == "cylinder":
            objs.append({"type": "cylinder", "c": np.array([o["center_cm"][0], o["center_cm"][1], 0.0], float),
                         "r": float(o["radius_cm"]), "h": float(o["height_cm"]), "albedo": col})
        else:
            raise ValueError(f"unknown object type {t!r}; use box, cylinder or ball")
    return objs


def _hit_sphere(O, D, c, r):
    """Nearest positive ray parameter (inf if missed) for rays O + t D, D not normalised."""
    oc = O - c  # O is a single point (3,)
    a = np.einsum("ij,ij->i", D, D)
    b = D @ oc
    cc = oc @ oc - r * r
    disc = b * b - a * cc
    t = np.full(D.shape[0], np.inf)
    ok = disc >= 0
    if np.any(ok):
        sq = np.sqrt(disc[ok])
        t0 = (-b[ok] - sq) / a[ok]
        t1 = (-b[ok] + sq) / a[ok]
        tt = np.where(t0 > 1e-9, t0, np.where(t1 > 1e-9, t1, np.inf))
        t[ok] = tt
    return t


def _hit_box(O, D, obj, tmin=1e-9):
    """Slab test in the box's frame; O may be (3,) or (N, 3). Returns t (N,) and the hit axis (N,)."""
    Rz, c, half = obj["Rz"], obj["c"], obj["half"]
    o = (np.atleast_2d(O) - c) @ Rz  # rotate into the box frame (R^T x == x @ R)
    d = D @ Rz
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-half - o) * inv
        t2 = (half - o) * inv
    tn = np.minimum(t1, t2)
    tf = np.maximum(t1, t2)
    tnear = np.nanmax(tn, axis=1)
    tfar = np.nanmin(tf, axis=1)
    axis = np.nanargmax(tn, axis=1)
    hit = (tnear <= tfar) & (tfar > tmin)
    t = np.where(hit, np.where(tnear > tmin, tnear, tfar), np.inf)
    return t, axis


def _hit_cylinder(O, D, obj, tmin=1e-9):
    """Vertical capped cylinder standing on the table; O (3,) or (N, 3). Returns t and a 'side' flag."""
    O2 = np.atleast_2d(O)
    ox, oy, oz = O2[:, 0] - obj["c"][0], O2[:, 1] - obj["c"][1], O2[:, 2]
    dx, dy, dz = D[:, 0], D[:, 1], D[:, 2]
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    cc = ox * ox + oy * oy - obj["r"] ** 2
    disc = b * b - a * cc
    t = np.full(D.shape[0], np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(disc, 0))
        ts = (-b - sq) / a
        z = oz + ts * dz
        side = (disc >= 0) & (ts > tmin) & (z >= 0) & (z <= obj["h"])
        t = np.where(side, ts, t)
        tc = (obj["h"] - oz) / dz
        xc, yc = ox + tc * dx, oy + tc * dy
        cap = (tc > tmin) & (xc * xc + yc * yc <= obj["r"] ** 2) & (tc < t)
        t = np.where(cap, tc, t)
    return t, ~cap


def _occlusion(P: np.ndarray, L: np.ndarray, objs: list[dict], own: np.ndarray) -> np.ndarray:
    """Fraction (0..1) of the light blocked for surface points P (N, 3)."""
    occ = np.zeros(P.shape[0])
    if not objs:
        return occ
    S = L[None, :] - P  # segment to the light, t in (0, 1)
    for k, o in enumerate(objs):
        mask = own != k
        if o["type"] == "sphere":
            # Closest approach of the segment to the centre; a penumbra of 10 % of the radius
            # (the light has a size) instead of a hard edge.
            cp = o["c"][None, :] - P
            ss = np.einsum("ij,ij->i", S, S)
            tt = np.einsum("ij,ij->i", cp, S) / ss
            dist2 = np.einsum("ij,ij->i", cp, cp) - tt * tt * ss
            dist = np.sqrt(np.maximum(dist2, 0))
            soft = np.clip((o["r"] * 1.1 - dist) / (o["r"] * 0.2), 0, 1)
            val = np.where((tt > 0) & (tt < 1) & mask, soft, 0.0)
        elif o["type"] == "box":
            t, _ = _hit_box(P, S, o, tmin=1e-6)
            val = ((t < 1) & mask).astype(float)
        else:
            t, _ = _hit_cylinder(P, S, o, tmin=1e-6)
            val = ((t < 1) & mask).astype(float)
        occ = np.maximum(occ, val)
    return occ


def _trace(rig: dict, cam_index: int, rays_cam: np.ndarray, objs: list[dict], tex: np.ndarray):
    """Shade rays given in camera coordinates. Returns BGR radiance (N, 3) in 0..1 and the hit id.

    Hit ids: -2 background (no table), -1 table, k >= 0 index into ``objs``.
    """
    cam = rig["cams"][cam_index]
    p = rig["params"]
    O = cam["origin_table"]
    D = rays_cam @ cam["R_table_from_cam"].T
    n = D.shape[0]
    t_best = np.full(n, np.inf)
    ids = np.full(n, -2, dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_tab = np.where(D[:, 2] < 0, -O[2] / D[:, 2], np.inf)
    sel = t_tab < t_best
    t_best[sel], ids[sel] = t_tab[sel], -1
    aux = {}
    for k, o in enumerate(objs):
        if o["type"] == "sphere":
            t = _hit_sphere(O, D, o["c"], o["r"])
        elif o["type"] == "box":
            t, aux[k] = _hit_box(O, D, o)
        else:
            t, aux[k] = _hit_cylinder(O, D, o)
        sel = t < t_best
        t_best[sel], ids[sel] = t[sel], k
    hit = ids > -2
    P = O[None, :] + np.where(hit, t_best, 0.0)[:, None] * D
    normal = np.zeros_like(P)
    albedo = np.zeros_like(P)
    normal[:, 2] = 1.0
    tabm = ids == -1
    if np.any(tabm):
        albedo[tabm] = _sample_texture(tex, P[tabm, 0], P[tabm, 1])
    for k, o in enumerate(objs):
        m = ids == k
        if not np.any(m):
            continue
        albedo[m] = o["albedo"]
        if o["type"] == "sphere":
            normal[m] = (P[m] - o["c"]) / o["r"]
        elif o["type"] == "box":
            local = (P[m] - o["c"]) @ o["Rz"]
            ax = aux[k][m]
            nl = np.zeros_like(local)
            nl[np.arange(nl.shape[0]), ax] = np.sign(local[np.arange(nl.shape[0]), ax])
            normal[m] = nl @ o["Rz"].T
        else:
            side = aux[k][m]
            rad = P[m] - o["c"]
            rad[:, 2] = 0
            nn = rad / np.maximum(np.linalg.norm(rad, axis=1, keepdims=True), 1e-12)
            nn[~side] = [0.0, 0.0, 1.0]
            normal[m] = nn
    L = rig["light_table"]
    to_l = L[None, :] - P
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    lam = np.clip(np.einsum("ij,ij->i", normal, to_l / dist), 0, None)
    shadow = 1.0 - float(p["shadow_strength"]) * _occlusion(P[hit], L, objs, ids[hit])
    lam[hit] *= shadow
    amb = float(p["ambient"])
    # Light falls off gently with distance from the lamp so the table is not flat-shaded.
    fall = (np.linalg.norm(L - np.array([0, 0, 0.0])) / dist[:, 0]) ** 0.5
    radiance = albedo * (amb + (1.0 - amb) * lam * fall)[:, None]
    radiance[~hit] = 0.55  # grey wall beyond the table
    return radiance, ids


def _to_uint8(img: np.ndarray, noise_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Radiance (0..1) to 8-bit with Gaussian sensor noise, rounded and saturated.

    OpenCV's generator and saturating add are ~5x faster than NumPy's here (the noise was
    a third of a pair's render time); its global generator is seeded from ``rng``, so
    images stay a deterministic function of the seed.
    """
    img = cv2.multiply(img.astype(np.float32), 255.0)
    if noise_sigma > 0:
        noise = np.empty_like(img)
        cv2.setRNGSeed(int(rng.integers(0, 2**31 - 1)))
        cv2.randn(noise, 0.0, float(noise_sigma))
        return cv2.add(img, noise, dtype=cv2.CV_8U)
    return cv2.add(img, 0.0, dtype=cv2.CV_8U)


# --------------------------------------------------------------------------------------------
# Silhouette of a sphere
# --------------------------------------------------------------------------------------------


def _cone_boundary(center_cam: np.ndarray, radius: float, n: int) -> np.ndarray:
    """Unit rays on the tangent cone of a sphere seen from the origin: (n, 3)."""
    c = np.asarray(center_cam, float)
    dist = np.linalg.norm(c)
    axis = c / dist
    sin_a = radius / dist
    cos_a = math.sqrt(max(1 - sin_a * sin_a, 0))
    e1 = np.cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return cos_a * axis[None, :] + sin_a * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)


def _polygon_centroid(poly: np.ndarray) -> tuple[float, np.ndarray]:
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    cx = ((x + xn) * cross).sum() / (6 * area)
    cy = ((y + yn) * cross).sum() / (6 * area)
    return abs(area), np.array([cx, cy])


def silhouette(K: np.ndarray, D, center_cam_cm, radius_cm: float, n_boundary: int = 4096) -> dict:
    """Exact outline of a sphere in a camera.

    Parameters
    ----------
    K, D : camera matrix and distortion.
    center_cam_cm : (3,) sphere centre in the camera frame, cm.
    radius_cm : float
        Sphere radius, cm.

    Returns
    -------
    dict
        ``ellipse_px`` -- the ideal (undistorted, pinhole ``K``) outline, the conic
        cut by the tangent cone: ``center_px``, ``axes_px`` (semi-axes, major
        first), ``angle_deg`` (major axis from +u); ``centroid_px`` and
        ``area_px`` of the true *distorted* silhouette (dense boundary polygon;
        without distortion ``centroid_px`` equals the ellipse centre);
        ``center_px`` the image of the sphere's centre (it differs from both).
    """
    c = np.asarray(center_cam_cm, float)
    dist2 = c @ c
    # Points x = (X, Y, 1) on the cone satisfy x^T M x = 0.
    M = np.outer(c, c) - (dist2 - radius_cm**2) * np.eye(3)
    Kinv = np.linalg.inv(K)
    A = Kinv.T @ M @ Kinv
    A = -A if A[0, 0] < 0 else A
    a, b, cc = A[0, 0], A[0, 1], A[1, 1]
    d, e, f0 = A[0, 2], A[1, 2], A[2, 2]
    Q = np.array([[a, b], [b, cc]])
    centre = np.linalg.solve(Q, -np.array([d, e]))
    k = -(f0 + d * centre[0] + e * centre[1])  # conic value at the centre, sign-flipped
    evals, evecs = np.linalg.eigh(Q)
    axes = np.sqrt(k / evals)  # ascending eigenvalues -> major axis first
    major = evecs[:, 0]
    ang = math.degrees(math.atan2(major[1], major[0]))
    ang = (ang + 90.0) % 180.0 - 90.0
    rays = _cone_boundary(c, radius_cm, n_boundary)
    poly = project_points(K, D, rays)
    area, cen = _polygon_centroid(poly)
    return {
        "ellipse_px": {"center_px": [float(centre[0]), float(centre[1])],
                       "axes_px": [float(axes[0]), float(axes[1])], "angle_deg": float(ang)},
        "centroid_px": [float(cen[0]), float(cen[1])],
        "area_px": float(area),
        "center_px": [float(v) for v in project_points(K, D, c[None, :])[0]],
        "bbox_px": [float(poly[:, 0].min()), float(poly[:, 1].min()), float(poly[:, 0].max()),
                    float(poly[:, 1].max())],
    }


# --------------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------------


def _table_to_cam(rig: dict, cam_index: int, pts_table: np.ndarray) -> np.ndarray:
    cam = rig["cams"][cam_index]
    return (np.atleast_2d(pts_table) - cam["origin_table"]) @ cam["R_table_from_cam"]


def _bbox_inside(rig, sil: dict, margin: float) -> bool:
    w, h = rig["truth"]["image_size"]
    u0, v0, u1, v1 = sil["bbox_px"]
    return u0 >= margin and v0 >= margin and u1 <= w - 1 - margin and v1 <= h - 1 - margin


def _ball_sils(rig, center_table, radius):
    out = []
    for i in (0, 1):
        cc = _table_to_cam(rig, i, np.asarray(center_table, float))[0]
        if cc[2] <= radius:
            return None
        out.append(silhouette(rig["cams"][i]["K"], rig["cams"][i]["D"], cc, radius, n_boundary=256))
    return out


def make_scene(rig: dict, kind: str = "plain", rng: np.random.Generator | int | None = None,
               radius_cm: float = 2.0, color: Any = "orange", min_distance_cm: float = 30.0,
               max_distance_cm: float = 60.0, border_margin_px: float = 4.0,
               region_cm: tuple[float, float, float, float] | None = None) -> dict:
    """Draw a random scene of a given kind (see the module docstring).

    Parameters
    ----------
    rig : dict
        From :func:`make_rig`.
    kind : str
        One of :data:`SCENE_KINDS`.
    rng : Generator or int or None
        Random source (or seed).
    radius_cm : float
        Ball radius, cm.
    color : str or [b, g, r]
        Ball colour.
    min_distance_cm, max_distance_cm : float
        Range of the ball centre's distance from the left camera, cm.
    border_margin_px : float
        For non-border kinds, the ball's silhouette stays this far inside both images.
    region_cm : (x, y, r_min, r_max) or None
        Keep the ball centre in this annulus of the table plane (table frame, cm): e.g. the
        part of the table a robot arm standing at (x, y) can reach.

    Returns
    -------
    scene : dict (plain data)
    """
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; use one of {SCENE_KINDS}")
    rng = np.random.default_rng(rng)
    ball = {"radius_cm": float(radius_cm), "color": color}
    C1 = rig["cams"][0]["origin_table"]
    w, h = rig["truth"]["image_size"]

    def draw_ball(accept):
        for _ in range(4000):
            # Uniform in distance and bearing, then checked against both images.
            dist = rng.uniform(min_distance_cm, max_distance_cm)
            dz = C1[2] - radius_cm
            if dist <= dz:
                continue
            ground = math.sqrt(dist * dist - dz * dz)
            bearing = rng.uniform(-0.7, 0.7)
            c = np.array([C1[0] + ground * math.sin(bearing), C1[1] + ground * math.cos(bearing), radius_cm])
            if region_cm is not None:
                rho = math.hypot(c[0] - region_cm[0], c[1] - region_cm[1])
                if not region_cm[2] <= rho <= region_cm[3]:
                    continue
            sils = _ball_sils(rig, c, radius_cm)
            if sils is not None and accept(c, sils):
                return c, sils
        raise RuntimeError(f"could not place a ball for scene kind {kind!r}; widen the distance range"
                           + (" or the placement region" if region_cm is not None else ""))

    def inside_both(c, sils):
        return all(_bbox_inside(rig, s, border_margin_px) for s in sils)

    if kind in HARD_KINDS:  # issue 15's kinds, measured visibility (nodes/sources/_hard_scenes.py)
        return make_hard_scene(rig, kind, rng, radius_cm, color, draw_ball, inside_both)
    scene: dict = {"kind": kind, "ball": None, "objects": []}
    others = [n for n in COLORS if n not in (color if isinstance(color, str) else "", "white", "black")]
    if kind == "empty":
        c, _ = draw_ball(inside_both)
        scene["objects"].append({"type": "box", "center_cm": [float(c[0]), float(c[1])],
                                 "size_cm": [5.0, 4.0, 3.0], "yaw_deg": float(rng.uniform(0, 90)),
                                 "color": str(rng.choice(others))})
        return scene
    if kind == "border":
        side = rng.choice([0, 1])

        def cut(c, sils):
            s = sils[0]
            u0, v0, u1, v1 = s["bbox_px"]
            inside_v = v0 > border_margin_px and v1 < h - 1 - border_margin_px
            if side == 0:  # cut by the left border of the left image
                return inside_v and u0 < 0 < (u0 + u1) / 2 and _bbox_inside(rig, sils[1], -1e9)
            return inside_v and (u0 + u1) / 2 < w - 1 < u1
        c, _ = draw_ball(cut)
    else:
        c, _ = draw_ball(inside_both)
    ball["center_cm"] = [float(c[0]), float(c[1])]
    scene["ball"] = ball
    r = radius_cm
    if kind == "clutter":
        for _ in range(int(rng.integers(2, 5))):
            ang = rng.uniform(0, 2 * np.pi)
            d = rng.uniform(3.5 * r, 8 * r)
            pos = [float(c[0] + d * math.cos(ang)), float(c[1] + d * math.sin(ang))]
            if rng.random() < 0.5:
                scene["objects"].append({"type": "box", "center_cm": pos,
                                         "size_cm": [float(rng.uniform(2, 6)), float(rng.uniform(2, 6)),
                                                     float(rng.uniform(1.5, 6))],
                                         "yaw_deg": float(rng.uniform(0, 90)), "color": str(rng.choice(others))})
            else:
                scene["objects"].append({"type": "cylinder", "center_cm": pos,
                                         "radius_cm": float(rng.uniform(1, 2.5)),
                                         "height_cm": float(rng.uniform(2, 8)), "color": str(rng.choice(others))})
    elif kind == "second_ball":
        ang = rng.uniform(0, 2 * np.pi)
        d = rng.uniform(3 * r, 7 * r)
        scene["objects"].append({"type": "ball", "center_cm": [float(c[0] + d * math.cos(ang)),
                                                               float(c[1] + d * math.sin(ang))],
                                 "radius_cm": float(r * rng.uniform(0.8, 1.3)), "color": str(rng.choice(others))})
    elif kind in ("occluded", "hidden"):
        # A box on the line of sight from the left camera, between it and the ball.
        to_cam = C1[:2] - c[:2]
        dist_xy = np.linalg.norm(to_cam)
        u = to_cam / dist_xy
        perp = np.array([-u[1], u[0]])
        gap = r + 2.0
        pos = c[:2] + u * (gap + 1.5)
        # Height the line of sight needs to be blocked at that position, plus margin.
        frac = (gap + 1.5) / dist_xy
        sight = c[2] + (C1[2] - c[2]) * frac
        if kind == "occluded":
            pos = pos + perp * rng.choice([-1, 1]) * r * rng.uniform(1.0, 1.5)
            size = [2.0 * r, 2.0, sight + r * rng.uniform(0.5, 1.2)]
        else:
            size = [4.0 * r, 2.0, sight + 2.0 * r]
        scene["objects"].append({"type": "box", "center_cm": [float(pos[0]), float(pos[1])],
                                 "size_cm": [float(s) for s in size],
                                 "yaw_deg": float(math.degrees(math.atan2(perp[1], perp[0]))),
                                 "color": str(rng.choice(others))})
    return scene


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


def _empty_table(rig: dict, i: int, tex: np.ndarray) -> np.ndarray:
    """The lit, empty table as seen by camera ``i`` (H, W, 3 float32); cached in the rig."""
    cache = rig.setdefault("_cache", {})
    key = ("table", i)
    if key not in cache:
        w, h = rig["truth"]["image_size"]
        img, _ = _trace(rig, i, _ray_grid(rig["cams"][i], (w, h)), [], tex)
        cache[key] = img.reshape(h, w, 3).astype(np.float32)
    return cache[key]


def _object_points(o: dict) -> np.ndarray:
    """Points whose convex hull bounds an object (table frame), for screen-space bounding boxes."""
    if o["type"] == "sphere":
        g = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)], float)
        return o["c"] + 1.8 * o["r"] * g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1)
    if o["type"] == "box":
        s = np.linspace(-1, 1, 7)
        g = np.array([[x, y, z] for x in s for y in s for z in s if int(abs(x) == 1) + int(abs(y) == 1) + int(abs(z) == 1) >= 2])
        return o["c"] + (g * o["half"]) @ o["Rz"].T
    th = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    ring = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], axis=1) * o["r"] * 1.05
    return np.concatenate([o["c"] + ring, o["c"] + ring + [0, 0, o["h"]]])


def _roi(rig: dict, i: int, objs: list[dict]) -> tuple[int, int, int, int] | None:
    """Pixel rectangle (u0, v0, u1, v1 inclusive) containing every object and its shadow."""
    w, h = rig["truth"]["image_size"]
    cam = rig["cams"][i]
    L = rig["light_table"]
    pts = []
    for o in objs:
        q = _object_points(o)
        pts.append(q)
        if np.any(q[:, 2] >= L[2] - 1e-6):
            return 0, 0, w - 1, h - 1
        # Shadow outline: the object's points projected from the lamp onto the table.
        s = L[2] / (L[2] - q[:, 2])
        sh = L + (q - L) * s[:, None]
        sh[:, 2] = 0.0
        pts.append(sh)
    if not pts:
        return None
    P = _table_to_cam(rig, i, np.concatenate(pts))
    if np.any(P[:, 2] <= 1e-3):
        return 0, 0, w - 1, h - 1
    px = project_points(cam["K"], cam["D"], P)
    m = 4  # px: bowing of straight edges under distortion, soft shadow edges
    u0, v0 = int(max(np.floor(px[:, 0].min()) - m, 0)), int(max(np.floor(px[:, 1].min()) - m, 0))
    u1, v1 = int(min(np.ceil(px[:, 0].max()) + m, w - 1)), int(min(np.ceil(px[:, 1].max()) + m, h - 1))
    if u0 > u1 or v0 > v1:
        return None
    return u0, v0, u1, v1


def _render_camera(rig, i, objs, tex):
    """Radiance image (H, W, 3 float) of camera ``i`` and the target ball's coverage (or None)."""
    w, h = rig["truth"]["image_size"]
    cam = rig["cams"][i]
    rays = _ray_grid(cam, (w, h))
    img = _empty_table(rig, i, tex).astype(float)
    has_target = bool(objs) and bool(objs[0].get("target"))
    cov = np.zeros((h, w)) if has_target else None
    roi = _roi(rig, i, objs)
    if roi is None:
        return img, cov
    u0, v0, u1, v1 = roi
    # Only the rectangle holding the objects and their shadows differs from the empty table.
    sub = rays.reshape(h, w, 3)[v0: v1 + 1, u0: u1 + 1].reshape(-1, 3)
    rad, ids = _trace(rig, i, sub, objs, tex)
    img[v0: v1 + 1, u0: u1 + 1] = rad.reshape(v1 - v0 + 1, u1 - u0 + 1, 3)
    if has_target:
        cov[v0: v1 + 1, u0: u1 + 1] = (ids == 0).reshape(v1 - v0 + 1, u1 - u0 + 1)
    # Supersample the band of pixels around every sphere's silhouette (analytic cone test).
    S = _SUPERSAMPLE
    off = (np.arange(S) + 0.5) / S - 0.5
    ou, ov = np.meshgrid(off, off)
    ou, ov = ou.ravel(), ov.ravel()
    fmin = min(cam["K"][0, 0], cam["K"][1, 1])
    for o in objs:
        if o["type"] != "sphere":
            continue
        cc = _table_to_cam(rig, i, o["c"])[0]
        dist = np.linalg.norm(cc)
        if dist <= o["r"] * 1.01 or cc[2] <= o["r"]:
            continue
        half = math.asin(o["r"] / dist)
        sil = silhouette(cam["K"], cam["D"], cc, o["r"], n_boundary=256)
        su0, sv0, su1, sv1 = sil["bbox_px"]
        iu0, iv0 = max(int(math.floor(su0)) - 2, 0), max(int(math.floor(sv0)) - 2, 0)
        iu1, iv1 = min(int(math.ceil(su1)) + 2, w - 1), min(int(math.ceil(sv1)) + 2, h - 1)
        if iu0 > iu1 or iv0 > iv1:
            continue
        box = rays.reshape(h, w, 3)[iv0: iv1 + 1, iu0: iu1 + 1].reshape(-1, 3)
        ang = np.arccos(np.clip(box @ (cc / dist) / np.linalg.norm(box, axis=1), -1, 1))
        # A pixel's half-diagonal spans ~0.71/f rad (a little more where distortion stretches
        # the image): pixels whose centre ray is farther than 1.1/f from the cone are pure.
        band = np.abs(ang - half) < 1.1 / fmin
        if not np.any(band):
            continue
        vv, uu = np.nonzero(band.reshape(iv1 - iv0 + 1, iu1 - iu0 + 1))
        uu, vv = uu + iu0, vv + iv0
        pu = (uu[:, None] + ou[None, :]).ravel()
        pv = (vv[:, None] + ov[None, :]).ravel()
        # Start Newton from the pixel centre's exact ray: two steps then reach machine precision.
        guess = np.repeat(rays.reshape(h, w, 3)[vv, uu, :2], S * S, axis=0)
        guess[:, 0] += (pu - np.repeat(uu, S * S)) / cam["K"][0, 0]
        guess[:, 1] += (pv - np.repeat(vv, S * S)) / cam["K"][1, 1]
        xy = undistort_pixels(cam["K"], cam["D"], np.stack([pu, pv], axis=1), guess=guess, iterations=3)
        srays = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
        sc, sid = _trace(rig, i, srays, objs, tex)
        img[vv, uu] = sc.reshape(-1, S * S, 3).mean(axis=1)
        if cov is not None:
            cov[vv, uu] = (sid == 0).reshape(-1, S * S).mean(axis=1)
    return img, cov


def render_scene(rig: dict, scene: dict, seed: int = 0, noise_sigma: float | None = None,
                 coverage: bool = False) -> tuple[np.ndarray, np.ndarray, dict | None]:
    """Render a stereo pair of a scene with its ground truth.

    Parameters
    ----------
    rig : dict
        From :func:`make_rig`.
    scene : dict
        Scene description (module docstring).
    seed : int
        Seed of the image noise.
    noise_sigma : float, optional
        Gaussian noise, grey levels; default the rig's ``noise_sigma``.
    coverage : bool
        Also return the ball's per-pixel coverage (0..1 float, occlusions
        included) as ``truth["coverage_left"]`` / ``["coverage_right"]``.

    Returns
    -------
    left, right : uint8 HxWx3 BGR images
    truth : dict or None
        ``center_left_cm``, ``center_table_cm``, ``radius_cm``,
        ``center_px_left`` / ``_right`` (image of the centre, distorted
        pixels), ``silhouette_left`` / ``_right`` (see :func:`silhouette`),
        ``visible_fraction_left`` / ``_right``, ``touches_border_left`` /
        ``_right``, ``kind``, ``color``. ``None`` if the scene has no ball.
    """
    objs = _objects_of(scene)
    tex = _table_texture(int(rig["params"]["texture_seed"]))
    sigma = float(rig["params"]["noise_sigma"] if noise_sigma is None else noise_sigma)
    rng = np.random.default_rng(seed)
    imgs, covs = [], []
    for i in (0, 1):
        img, cov = _render_camera(rig, i, objs, tex)
        imgs.append(_to_uint8(img, sigma, rng))
        covs.append(cov)
    truth = None
    if objs and objs[0].get("target"):
        b = objs[0]
        T = rig["truth"]["T_table_from_left"]
        c_left = (b["c"] - T[:3, 3]) @ T[:3, :3]
        c_right = rig["truth"]["R"] @ c_left + rig["truth"]["T_cm"]
        sils = [silhouette(rig["cams"][0]["K"], rig["cams"][0]["D"], c_left, b["r"]),
                silhouette(rig["cams"][1]["K"], rig["cams"][1]["D"], c_right, b["r"])]
        truth = {
            "kind": scene.get("kind", "custom"),
            "center_left_cm": [float(v) for v in c_left],
            "center_table_cm": [float(v) for v in b["c"]],
            "radius_cm": float(b["r"]),
            "color": scene["ball"].get("color", "orange") if isinstance(scene["ball"].get("color", "orange"), str)
            else [int(v) for v in scene["ball"]["color"]],
            "center_px_left": sils[0]["center_px"],
            "center_px_right": sils[1]["center_px"],
            "silhouette_left": sils[0],
            "silhouette_right": sils[1],
        }
        for side, s, cov in (("left", sils[0], covs[0]), ("right", sils[1], covs[1])):
            truth[f"visible_fraction_{side}"] = float(min(cov.sum() / s["area_px"], 1.0))
            truth[f"touches_border_{side}"] = bool(not _bbox_inside(rig, s, 0.5))
            if coverage:
                truth[f"coverage_{side}"] = cov.astype(np.float32)
    return imgs[0], imgs[1], truth


# --------------------------------------------------------------------------------------------
# Chessboard calibration views
# --------------------------------------------------------------------------------------------


def board_corners_3d(cols: int, rows: int, square_cm: float) -> np.ndarray:
    """Inner corners in the board frame (cm), row-major as OpenCV reports them: (cols*rows, 3)."""
    gx, gy = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.stack([gx.ravel() * square_cm, gy.ravel() * square_cm, np.zeros(gx.size)], axis=1)


def _board_extent(cols, rows, square_cm):
    # Printed squares span [-1, cols] x [-1, rows] (in squares); a one-square white margin around.
    return np.array([-2.0, -2.0]) * square_cm, np.array([cols + 1.0, rows + 1.0]) * square_cm


def random_board_poses(rig: dict, n: int, rng, cols: int = 9, rows: int = 6, square_cm: float = 2.5,
                       min_distance_cm: float = 30.0, max_distance_cm: float = 60.0,
                       max_tilt_deg: float = 35.0, margin_px: float = 12.0) -> list[np.ndarray]:
    """Board poses ``T_left_from_board`` (4x4, cm) fully visible in both cameras.

    Distances are spread evenly over the range and tilts alternate in sign so
    that the views constrain the focal length and the distortion.
    """
    rng = np.random.default_rng(rng)
    lo, hi = _board_extent(cols, rows, square_cm)
    outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    edge = np.concatenate([outline + (np.roll(outline, -1, 0) - outline) * s for s in np.linspace(0, 1, 9)])
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    w, h = rig["truth"]["image_size"]
    R, T = rig["truth"]["R"], rig["truth"]["T_cm"]
    poses = []
    for i in range(n):
        for _ in range(2000):
            z = rng.uniform(min_distance_cm, max_distance_cm)
            sgn = 1 if i % 2 == 0 else -1
            tilt = np.radians([sgn * rng.uniform(5, max_tilt_deg), rng.uniform(-max_tilt_deg, max_tilt_deg),
                               rng.uniform(-20, 20)])
            Rb, _ = cv2.Rodrigues(tilt.reshape(3, 1))
            spread = 0.35 * z
            pos = np.array([rng.uniform(-spread, spread) + 4.0, rng.uniform(-0.7, 0.7) * spread, z])
            t = pos - Rb @ centre
            pl = edge @ Rb.T + t
            pr = pl @ R.T + T
            if pl[:, 2].min() < 5 or pr[:, 2].min() < 5:
                continue
            ok = True
            for K, D, pts in ((rig["truth"]["K1"], rig["truth"]["D1"], pl), (rig["truth"]["K2"], rig["truth"]["D2"], pr)):
                px = project_points(K, D, pts)
                if (px[:, 0].min() < margin_px or px[:, 1].min() < margin_px or px[:, 0].max() > w - 1 - margin_px
                        or px[:, 1].max() > h - 1 - margin_px):
                    ok = False
                    break
            if ok:
                Tm = np.eye(4)
                Tm[:3, :3], Tm[:3, 3] = Rb, t
                poses.append(Tm)
                break
        else:
            raise RuntimeError("could not place a calibration board fully inside both images")
    return poses


def _tri(x):
    """Antiderivative of the unit square wave sign(sin(pi x)) (a triangle wave)."""
    return 1.0 - np.abs(np.mod(x, 2.0) - 1.0)


def _filtered_square(x, w):
    w = np.maximum(w, 1e-4)
    return (_tri(x + w / 2) - _tri(x - w / 2)) / w


_CHARUCO_PX_PER_SQUARE = 84  # texture resolution of a ChArUco board's markers (6 texels per 4x4 marker cell at 0.7)


@functools.lru_cache(maxsize=4)
def charuco_texture(cols: int, rows: int, dictionary: str = "DICT_4X4_50", marker_fraction: float = 0.7,
                    px_per_square: int = _CHARUCO_PX_PER_SQUARE) -> tuple[np.ndarray, int]:
    """OpenCV's ChArUco board image (``CharucoBoard.generateImage``) for ``cols x rows`` inner corners.

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
    tex, parity = charuco_texture(cols, rows, str(charuco.get("dictionary", "DICT_4X4_50")),
                                  float(charuco.get("marker_fraction", 0.7)))
    wx = np.abs(gu[0]) + np.abs(gv[0])
    wy = np.abs(gu[1]) + np.abs(gv[1])
    # sign(sin(pi bx)) * sign(sin(pi by)) is +1 on the squares whose (i + j) is even (i = floor(bx) + 1)
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


def render_board_view(rig: dict, pose_left_from_board: np.ndarray, cols: int = 9, rows: int = 6,
                      square_cm: float = 2.5, seed: int = 0, noise_sigma: float | None = None,
                      charuco: dict | None = None):
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
        rays_all = _ray_grid(cam, (w, h)).reshape(h, w, 3)
        img = _empty_table(rig, i, tex).astype(float)
        # Only the board's screen rectangle is traced (outline projected, plus a margin).
        outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
        edge = np.concatenate([outline + (np.roll(outline, -1, 0) - outline) * f for f in np.linspace(0, 1, 9)])
        epx = project_points(cam["K"], cam["D"], edge @ Rcb.T + tcb)
        u0, v0 = int(max(epx[:, 0].min() - 3, 0)), int(max(epx[:, 1].min() - 3, 0))
        u1, v1 = int(min(epx[:, 0].max() + 3, w - 1)), int(min(epx[:, 1].max() + 3, h - 1))
        sh = (v1 - v0 + 1, u1 - u0 + 1)
        rays = rays_all[v0: v1 + 1, u0: u1 + 1].reshape(-1, 3)
        # Ray-plane intersection in the board frame: X(t) = t * ray, board z = 0.
        n = Rcb[:, 2]
        denom = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (n @ tcb) / denom
        P = t[:, None] * rays
        B = (P - tcb) @ Rcb  # board coordinates (cm)
        bx = (B[:, 0] / square_cm).reshape(sh)
        by = (B[:, 1] / square_cm).reshape(sh)
        inside = ((t > 0) & (B[:, 0] >= lo[0]) & (B[:, 0] <= hi[0]) & (B[:, 1] >= lo[1]) & (B[:, 1] <= hi[1]))
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
        roi = img[v0: v1 + 1, u0: u1 + 1].reshape(-1, 3)
        roi[inside] = shade[inside, None]
        img[v0: v1 + 1, u0: u1 + 1] = roi.reshape(*sh, 3)
        imgs.append(_to_uint8(img, sigma, rng))
        corners["left_px" if i == 0 else "right_px"] = project_points(cam["K"], cam["D"], pts_b @ Rcb.T + tcb)
    corners["T_table_from_board"] = T_tl @ pose_left_from_board
    return imgs[0], imgs[1], corners


def render_table_board(rig: dict, cols: int = 9, rows: int = 6, square_cm: float = 2.5, yaw_deg: float = 0.0,
                       centre_table_cm=(0.0, 5.0), seed: int = 1):
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
    left, right, corners = render_board_view(rig, np.linalg.inv(T_tl) @ T_tb, cols, rows, square_cm, seed=seed)
    P = corners["board_cm"] @ T_tb[:3, :3].T + T_tb[:3, 3]
    T = np.eye(4)
    T[:3, 3] = -P[np.argmin(P[:, 0] + P[:, 1])]
    return left, right, T @ T_tl
