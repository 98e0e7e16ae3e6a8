"""Camera model of the synthetic rig: OpenCV's k1 k2 p1 p2 k3 distortion, its exact inverse by
Newton iterations, and point projection.
"""

from __future__ import annotations

import cv2
import numpy as np


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


def undistort_normalized(
    xyd: np.ndarray, D, iterations: int = 12, guess: np.ndarray | None = None
) -> np.ndarray:
    """Exact inverse of :func:`distort_normalized` (Newton's method).

    OpenCV's ``undistortPoints`` stops after 5 fixed-point iterations, which
    leaves ~0.01 px errors in the corners of a strongly distorted image; the
    renderer needs the model inverted to machine precision so that its images
    and its ground truth agree.
    """
    xd, yd = xyd[..., 0].astype(float), xyd[..., 1].astype(float)
    if guess is None:
        x, y = xd.copy(), yd.copy()
    else:
        x, y = guess[..., 0].astype(float), guess[..., 1].astype(float)
    shape = x.shape
    x, y, xd, yd = x.ravel(), y.ravel(), xd.ravel(), yd.ravel()
    # Each point's iterations are its own, so blocks give the same bits; a block's dozen
    # temporaries stay in the CPU's cache instead of being fresh multi-MB arrays (a 640x480 ray
    # grid: ~0.09 -> ~0.05 s).
    D5 = _dist5(D)
    for i in range(0, x.size, _BLOCK):
        _newton(
            x[i : i + _BLOCK],
            y[i : i + _BLOCK],
            xd[i : i + _BLOCK],
            yd[i : i + _BLOCK],
            D5,
            iterations,
        )
    return np.stack([x.reshape(shape), y.reshape(shape)], axis=-1)


_BLOCK = 32768  # points per block of undistort_normalized


def _newton(
    x: np.ndarray, y: np.ndarray, xd: np.ndarray, yd: np.ndarray, D5: tuple, iterations: int
) -> None:
    """Newton's iterations of :func:`undistort_normalized` on 1-D views ``x``, ``y`` (the start,
    overwritten with the answer) towards the distorted ``xd``, ``yd``."""
    k1, k2, p1, p2, k3 = D5
    # Points whose Newton step came out exactly zero are fixed points: every later iteration would
    # compute the same zero step, so they leave the active set and the result is bit for bit that of
    # running all ``iterations`` on every point (most of a 640x480 grid converges in ~4).
    active = np.arange(x.size)
    xa, ya, xda, yda = x, y, xd, yd
    for _ in range(iterations):
        r2 = xa * xa + ya * ya
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        fx = xa * radial + 2 * p1 * xa * ya + p2 * (r2 + 2 * xa * xa) - xda
        fy = ya * radial + p1 * (r2 + 2 * ya * ya) + 2 * p2 * xa * ya - yda
        j11 = radial + 2 * xa * xa * dradial + 2 * p1 * ya + 6 * p2 * xa
        j12 = 2 * xa * ya * dradial + 2 * p1 * xa + 2 * p2 * ya
        j22 = radial + 2 * ya * ya * dradial + 6 * p1 * ya + 2 * p2 * xa
        det = j11 * j22 - j12 * j12
        sx = (j22 * fx - j12 * fy) / det
        sy = (j11 * fy - j12 * fx) / det
        xa, ya = xa - sx, ya - sy
        x[active], y[active] = xa, ya
        moving = (sx != 0) | (sy != 0) | np.isnan(sx) | np.isnan(sy)
        if not moving.all():
            active, xa, ya, xda, yda = (
                active[moving],
                xa[moving],
                ya[moving],
                xda[moving],
                yda[moving],
            )
            if not active.size:
                break


def project_points(K: np.ndarray, D, pts_cam: np.ndarray) -> np.ndarray:
    """Project camera-frame points (cm) to distorted pixels: (N, 3) -> (N, 2)."""
    pts = np.asarray(pts_cam, dtype=float).reshape(-1, 3)
    xy = pts[:, :2] / pts[:, 2:3]
    xyd = distort_normalized(xy, D)
    return np.stack(
        [K[0, 0] * xyd[:, 0] + K[0, 1] * xyd[:, 1] + K[0, 2], K[1, 1] * xyd[:, 1] + K[1, 2]], axis=1
    )


def undistort_pixels(
    K: np.ndarray, D, px: np.ndarray, guess: np.ndarray | None = None, iterations: int = 12
) -> np.ndarray:
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
