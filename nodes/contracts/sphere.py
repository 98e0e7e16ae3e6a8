"""The image of a sphere: silhouette conic and the image of its centre.

A contract between kinds: segmenters check a region's size against the stereo distance with it,
disparity estimators (``disparity.ellipse``) measure the sphere's centre with it. A sphere's
silhouette centroid is not the image of its centre; the silhouette is a conic whose cone axis is.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ellipse_to_conic", "sphere_from_silhouette"]


def ellipse_to_conic(center_px, axes_px, angle_deg) -> np.ndarray:
    """3x3 symmetric conic E of an ellipse (pixel coordinates): [u v 1] E [u v 1]^T = 0.

    Parameters
    ----------
    center_px : (u, v)
    axes_px : (a, b) semi-axes (px), ``a`` along ``angle_deg``.
    angle_deg : float
        Direction of the ``a`` axis, degrees from the u axis towards v (image y down).
    """
    th = math.radians(angle_deg)
    c, s = math.cos(th), math.sin(th)
    Rm = np.array([[c, s], [-s, c]])
    M = Rm.T @ np.diag([1.0 / axes_px[0] ** 2, 1.0 / axes_px[1] ** 2]) @ Rm
    c0 = np.asarray(center_px, float)
    E = np.zeros((3, 3))
    E[:2, :2] = M
    E[:2, 2] = E[2, :2] = -M @ c0
    E[2, 2] = c0 @ M @ c0 - 1.0
    return E


def sphere_from_silhouette(E: np.ndarray, K: np.ndarray) -> dict:
    """Image of a sphere's centre (and its direction / angular radius) from its silhouette conic.

    Parameters
    ----------
    E : 3x3 conic of the silhouette (pixels), see :func:`ellipse_to_conic`.
    K : 3x3 camera matrix of the (rectified) view.

    Returns
    -------
    dict with ``center_px`` [u, v] (image of the sphere's centre), ``axis`` unit 3-vector
    (camera frame), ``half_angle_rad`` (alpha) and ``anisotropy`` (relative mismatch of the
    two equal eigenvalues; 0 for a perfect sphere image).
    """
    M = K.T @ E @ K
    M = 0.5 * (M + M.T)
    w, V = np.linalg.eigh(M)
    # The lone eigenvalue has the sign that the other two do not share.
    signs = np.sign(w)
    if (signs > 0).sum() == 1:
        i = int(np.argmax(w))
    elif (signs < 0).sum() == 1:
        i = int(np.argmin(w))
        w = -w
    else:
        raise ValueError("conic is not the image of a cone in front of the camera")
    others = w[[j for j in range(3) if j != i]]
    lam1, lam2 = w[i], float(others[0] + others[1]) / 2  # as np.mean of the two
    a = V[:, i]
    if a[2] < 0:
        a = -a
    tan2 = -lam1 / lam2
    alpha = math.atan(math.sqrt(max(tan2, 0.0)))
    p = K @ a
    return {
        "center_px": [float(p[0] / p[2]), float(p[1] / p[2])],
        "axis": a.tolist(),
        "half_angle_rad": float(alpha),
        "anisotropy": float(abs(others[0] - others[1]) / max(abs(lam2), 1e-12)),
    }
