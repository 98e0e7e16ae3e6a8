"""Building blocks of Tsai's method shared by the coplanar and the non-coplanar case.

* :func:`plane_frame` — a frame whose z is the normal of a (nearly) flat target, so that the
  coplanar equations, written for z_w = 0, apply to a target measured in any frame.
* :func:`coplanar_rotation` — Tsai (1987), section on the coplanar case: the radial alignment
  constraint with z_w = 0 has five unknowns; |ty| from the 2x2 sub-matrix of the rotation, then
  r13, r23 from unit-norm rows and r1 . r2 = 0, and r3 = r1 x r2. The seed thesis writes out only
  the non-coplanar case (its eqs. 3.16-3.24); the coplanar one is the same idea with the z_w
  terms gone and sx assumed known (a single plane cannot separate it from the rotation).
* :func:`refine_camera` — Tsai's non-linear step (f, tz, k1, and optionally the whole pose and sx),
  :func:`f_sigma_rel` — how well the data determine f.
* :func:`levenberg_marquardt` — a small damped Gauss-Newton with a forward-difference Jacobian
  (NumPy only), used by the final non-linear step; :func:`relative_sigma` — how well the fit
  determines one parameter (from its covariance), to refuse a focal length the target leaves free.

Lengths in cm (world), sensor coordinates in the pixel-pitch unit (docs/conventions.md).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

__all__ = [
    "coplanar_rotation",
    "f_sigma_rel",
    "jacobian",
    "levenberg_marquardt",
    "plane_frame",
    "refine_camera",
    "relative_sigma",
    "thickness_ratio",
]


def thickness_ratio(world_cm: np.ndarray) -> float:
    """Out-of-plane spread of the points over their second in-plane spread (0 = exactly flat)."""
    P = np.asarray(world_cm, float)
    s = np.linalg.svd(P - P.mean(0), compute_uv=False)
    return float(s[2] / s[1]) if s[1] > 0 else 0.0


def plane_frame(world_cm: np.ndarray) -> np.ndarray:
    """Rotation ``R_pw`` (3x3) whose rows are the best-fit plane's two in-plane axes and its normal.

    ``(W - p0) @ R_pw.T`` has z ~ 0 for points on the plane (any origin p0 on it).
    """
    P = np.asarray(world_cm, float)
    _, _, Vt = np.linalg.svd(P - P.mean(0))
    if np.linalg.det(Vt) < 0:
        Vt = Vt * np.array([[1.0], [1.0], [-1.0]])
    return Vt


def coplanar_rotation(
    Xd: np.ndarray, Yd: np.ndarray, xy_plane: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """Rotation and (tx, ty) of a camera seeing a flat target, by Tsai's radial alignment
    constraint.

    The constraint uses only the direction of each image point from the principal point, which
    radial distortion does not change: this step needs neither f nor k1.

    Parameters
    ----------
    Xd, Yd : (N,) arrays
        Distorted sensor coordinates relative to the principal point, with sx already divided out.
    xy_plane : (N, 2) array
        The target points in the plane's frame (z = 0), cm; their origin must not be near the
        optical axis.

    Returns
    -------
    R : (3, 3)
        Rotation plane -> camera (r13, r23 signs as Tsai: fixed later by the sign of f).
    tx, ty : float
        cm.
    """
    xw, yw = xy_plane[:, 0], xy_plane[:, 1]
    # Radial alignment with z_w = 0: Xd = [Yd xw, Yd yw, Yd, -Xd xw, -Xd yw] . (r11, r12, tx, r21,
    # r22) / ty
    A = np.column_stack([Yd * xw, Yd * yw, Yd, -Xd * xw, -Xd * yw])
    a, *_ = np.linalg.lstsq(A, Xd, rcond=None)
    a1, a2, a3, a4, a5 = a
    sr = a1 * a1 + a2 * a2 + a4 * a4 + a5 * a5
    det = a1 * a5 - a4 * a2
    if abs(det) > 1e-12 * sr:
        ty2 = (sr - np.sqrt(max(sr * sr - 4 * det * det, 0.0))) / (2 * det * det)
    else:  # a row or column of the 2x2 block vanishes: the other one has unit norm
        ty2 = 1.0 / max(a1 * a1 + a2 * a2, a4 * a4 + a5 * a5, a1 * a1 + a4 * a4, a2 * a2 + a5 * a5)
    ty_abs = float(np.sqrt(ty2))

    def pose(ty):
        return a1 * ty, a2 * ty, a4 * ty, a5 * ty, a3 * ty

    # Sign of ty (as in the non-coplanar case): with the right sign every point's (xc, yc) points
    # the way its (Xd, Yd) does; summed over all points, not decided by one.
    r11, r12, r21, r22, tx = pose(ty_abs)
    xc, yc = r11 * xw + r12 * yw + tx, r21 * xw + r22 * yw + ty_abs
    ty = ty_abs if float(xc @ Xd + yc @ Yd) > 0 else -ty_abs
    r11, r12, r21, r22, tx = pose(ty)
    r13 = np.sqrt(max(1.0 - r11 * r11 - r12 * r12, 0.0))
    r23 = -np.sign(r11 * r21 + r12 * r22) * np.sqrt(max(1.0 - r21 * r21 - r22 * r22, 0.0))
    r1, r2 = np.array([r11, r12, r13]), np.array([r21, r22, r23])
    U, _, Vt = np.linalg.svd(np.vstack([r1, r2, np.cross(r1, r2)]))
    R = U @ Vt  # noise leaves r1, r2 slightly non-orthogonal: take the nearest rotation
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    return R, float(tx), float(ty)


def jacobian(
    resid: Callable[[np.ndarray], np.ndarray],
    q: np.ndarray,
    steps: np.ndarray,
    e: np.ndarray | None = None,
) -> np.ndarray:
    """Forward-difference Jacobian of ``resid`` at ``q`` (``e`` = ``resid(q)`` if already known)."""
    e = resid(q) if e is None else e
    J = np.empty((e.size, q.size))
    for j in range(q.size):
        dq = np.zeros(q.size)
        dq[j] = steps[j]
        J[:, j] = (resid(q + dq) - e) / steps[j]
    return J


def relative_sigma(
    resid: Callable[[np.ndarray], np.ndarray], q: np.ndarray, steps: np.ndarray, index: int
) -> float:
    """1-sigma of parameter ``index`` over its value, from the fit's covariance ``s^2 (J^T J)^-1``.

    ``s^2`` is the residual variance (sum of squares over the degrees of freedom): how well the data
    determine that parameter, whatever the noise level (a flat target seen face-on leaves f free).
    """
    e = resid(q)
    J = jacobian(resid, q, steps, e)
    dof = max(e.size - q.size, 1)
    # Normalise the columns first: the parameters differ by ~1e9 in scale (k1 vs f), and an unscaled
    # inverse would lose exactly the near-degenerate direction this is meant to find.
    norms = np.linalg.norm(J, axis=0)
    if np.any(norms == 0):
        return float("inf")
    Jn = J / norms
    try:
        cov_n = np.linalg.inv(Jn.T @ Jn)
    except np.linalg.LinAlgError:
        return float("inf")
    var = float(e @ e) / dof * cov_n[index, index] / norms[index] ** 2
    return float(np.sqrt(var)) / max(abs(float(q[index])), 1e-300) if var >= 0 else float("inf")


def levenberg_marquardt(
    resid: Callable[[np.ndarray], np.ndarray],
    q0: np.ndarray,
    steps: np.ndarray,
    iterations: int = 100,
) -> np.ndarray:
    """Minimise ``|resid(q)|^2`` from ``q0``; ``steps`` are the forward-difference steps per
    parameter."""
    q = np.asarray(q0, float).copy()
    e = resid(q)
    cost, lam = float(e @ e), 1e-3
    for _ in range(iterations):
        J = jacobian(resid, q, steps, e)
        H, g = J.T @ J, J.T @ e
        d = np.diag(H).copy()
        d[d <= 0] = 1e-30
        while True:
            dq = np.linalg.solve(H + lam * np.diag(d), -g)
            en = resid(q + dq)
            if en @ en < cost:
                q, e, cost, lam = q + dq, en, float(en @ en), lam * 0.3
                break
            lam *= 10
            if lam > 1e12:
                return q
        if np.all(np.abs(dq) <= 1e-12 * (np.abs(q) + 1e-12)):
            break
    return q


def _residual(Pw, Xdp, Yd, R0, sx, with_pose: bool, with_sx: bool):
    """Tsai's non-linear objective X'd/sx (1 + k1 r^2) - f xc/zc (and Yd likewise), sensor units.

    Parameters q = (tx, ty, tz, f, k1[, rotation increment (3, rad) if with_pose][, sx if with_sx]).
    Returns ``(resid, unpack)``; ``unpack(q) -> (R, tx, ty, tz, f, k1, sx)``.
    """

    def unpack(q):
        R = R0 if not with_pose else cv2.Rodrigues(q[5:8])[0] @ R0
        s = q[8 if with_pose else 5] if with_sx else sx
        return R, q[0], q[1], q[2], q[3], q[4], s

    def resid(q):
        R, txq, tyq, tzq, fq, kq, s = unpack(q)
        Xd = Xdp / s
        r2d = Xd * Xd + Yd * Yd
        xc, yc, z = Pw @ R[0] + txq, Pw @ R[1] + tyq, Pw @ R[2] + tzq
        return np.concatenate(
            [Xd * (1 + kq * r2d) - fq * xc / z, Yd * (1 + kq * r2d) - fq * yc / z]
        )

    return resid, unpack


def _steps(Xdp, Yd, tz, f, sx, with_pose: bool, with_sx: bool) -> np.ndarray:
    r2max = max(float(np.max((Xdp / sx) ** 2 + Yd**2)), 1e-12)
    return np.array(
        [1e-7 * max(abs(tz), 1.0)] * 3
        + [1e-7 * max(abs(f), 1.0), 1e-7 * 1e-3 / r2max]
        + [1e-8] * (3 if with_pose else 0)
        + ([1e-8] if with_sx else [])
    )


def refine_camera(Pw, Xdp, Yd, R0, tx, ty, tz, f, sx, with_sx: bool, with_pose: bool):
    """Tsai's non-linear step over f, tz, k1; with ``with_pose`` also over a rotation increment, tx,
    ty, and with ``with_sx`` over sx. Returns ``(R, tx, ty, tz, f, k1, sx)``."""
    resid, unpack = _residual(Pw, Xdp, Yd, R0, sx, with_pose, with_pose and with_sx)
    steps = _steps(Xdp, Yd, tz, f, sx, with_pose, with_pose and with_sx)
    q = np.array(
        [tx, ty, tz, f, 0.0]
        + ([0.0, 0.0, 0.0] if with_pose else [])
        + ([sx] if with_pose and with_sx else []),
        float,
    )
    if with_pose:
        q = levenberg_marquardt(resid, q, steps)
    else:  # the thesis: f, tz and k1 only (tx, ty stay as the linear step found them)

        def sub(p):
            return resid(np.array([tx, ty, p[0], p[1], p[2]]))

        p = levenberg_marquardt(sub, np.array([tz, f, 0.0]), steps[2:5])
        q = np.array([tx, ty, *p])
    R, txq, tyq, tzq, fq, kq, s = unpack(q)
    return R, float(txq), float(tyq), float(tzq), float(fq), float(kq), float(s)


def f_sigma_rel(Pw, Xdp, Yd, R, tx, ty, tz, f, k1, sx, with_sx: bool) -> float:
    """Relative 1-sigma of f given the data, with the whole pose (and sx if estimated) free."""
    resid, _ = _residual(Pw, Xdp, Yd, R, sx, True, with_sx)
    q = np.array([tx, ty, tz, f, k1, 0.0, 0.0, 0.0] + ([sx] if with_sx else []), float)
    return relative_sigma(resid, q, _steps(Xdp, Yd, tz, f, sx, True, with_sx), 3)
