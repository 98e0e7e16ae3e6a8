"""Exact image silhouette of a sphere through the distortion model: its outline, area and
centroid (the ground truth of a rendered ball).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from nodes.sources._lens import project_points


def _cross(a, b) -> np.ndarray:
    """``np.cross`` of two 3-vectors, same arithmetic; the plan calls this hundreds of times and
    ``np.cross``'s axis handling costs ten times the products."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


@functools.lru_cache(maxsize=8)
def _unit_circle(n: int) -> tuple[np.ndarray, np.ndarray]:
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.cos(th)[:, None], np.sin(th)[:, None]


def _cone_boundary(center_cam: np.ndarray, radius: float, n: int) -> np.ndarray:
    """Unit rays on the tangent cone of a sphere seen from the origin: (n, 3)."""
    c = np.asarray(center_cam, float)
    dist = np.linalg.norm(c)
    axis = c / dist
    sin_a = radius / dist
    cos_a = math.sqrt(max(1 - sin_a * sin_a, 0))
    e1 = _cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = _cross(axis, e1)
    cos_th, sin_th = _unit_circle(n)
    return cos_a * axis[None, :] + sin_a * (cos_th * e1 + sin_th * e2)


def _polygon_centroid(poly: np.ndarray) -> tuple[float, np.ndarray]:
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.concatenate((x[1:], x[:1])), np.concatenate((y[1:], y[:1]))  # np.roll(-1), cheaper
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
        "ellipse_px": {
            "center_px": [float(centre[0]), float(centre[1])],
            "axes_px": [float(axes[0]), float(axes[1])],
            "angle_deg": float(ang),
        },
        "centroid_px": [float(cen[0]), float(cen[1])],
        "area_px": float(area),
        "center_px": [float(v) for v in project_points(K, D, c[None, :])[0]],
        "bbox_px": [
            float(poly[:, 0].min()),
            float(poly[:, 1].min()),
            float(poly[:, 0].max()),
            float(poly[:, 1].max()),
        ],
    }
