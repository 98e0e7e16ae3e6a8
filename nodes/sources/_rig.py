"""The synthetic rig: two cameras over a table and a light, from :data:`RIG_DEFAULTS` and
overrides, and the cached per-pixel ray grids of its cameras.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from nodes.sources._lens import _rotvec, undistort_pixels

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
        raise ValueError(
            f"unknown rig parameter(s) {sorted(unknown)}; known: {sorted(RIG_DEFAULTS)}"
        )
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
        [
            [1.0, 0.0, 0.0],
            [0.0, -math.sin(tilt), -math.cos(tilt)],
            [0.0, math.cos(tilt), -math.sin(tilt)],
        ]
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
