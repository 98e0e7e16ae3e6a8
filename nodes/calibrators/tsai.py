"""``calibrator.tsai``: Tsai's two-step calibration (the seed thesis, equations 3.1-3.24).

Model (per camera), in the OpenCV camera frame (x right, y down, z forward)::

    [xc, yc, zc] = R @ Pw + t                                   (3.1)
    Xu = f xc / zc,  Yu = f yc / zc                              (3.2)
    Xu = Xd (1 + k1 r^2),  Yu = Yd (1 + k1 r^2),  r^2 = Xd^2 + Yd^2   (3.3-3.5, 3.7)
    u = sx Xd / dx' + u0,  v = Yd / dy + v0                      (3.6)

The thesis writes (3.6) and (3.8) with minus signs because Tsai's camera axes
point the other way; in the OpenCV frame they vanish. Note that Tsai's k1 maps
*distorted* to *undistorted* coordinates, the inverse of OpenCV's k1, and is in
1/length^2 of the sensor unit.

Assumptions (as in Tsai 1987): the pixel pitch ``dx, dy`` is known (default 1,
so that f comes out in pixels; give the sensor pitch in micrometres for f in
micrometres) and so is the principal point (default: the image centre; give the
true one if known — the radial alignment constraint is exact only about the
true principal point). The target is non-coplanar: 3-D world points (cm) such
as a chessboard seen at several known poses (a multi-plane target).

Steps: (3.8) pixels -> sensor coordinates; (3.16-3.18) the radial alignment
constraint gives a linear least-squares problem in seven unknowns a1..a7;
(3.20) |ty|; its sign from a point far from the image centre (3.21-3.22);
(3.24) sx; r1, r2, tx; r3 = r1 x r2 (then the nearest rotation, by SVD); f and
tz by linear least squares ignoring distortion; finally a Levenberg-Marquardt
refinement of f, tz and k1 (NumPy; SciPy is not needed).

Implementation notes beyond the thesis: the world origin is moved to the target
point imaged farthest from the principal point's row, because the method
divides by ty (a world origin near the optical axis makes ty ~ 0); the
solution is moved back afterwards. Eq. (3.21) writes tx = a4 ty; from (3.18)
it is tx = a4 ty / sx.
"""

from __future__ import annotations

import numpy as np

from nodes.calibrators._board import board_points, detect_views
from nodes.calibrators._calib_io import EXPORT_OUTPUTS, calibration_outputs
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = [
    "TsaiParams",
    "opencv_distortion_from_tsai",
    "tsai",
    "tsai_camera",
    "tsai_k1_of_opencv",
    "tsai_project",
    "tsai_stereo",
]


def _sensor(px, u0, v0, dx, dy, ncx_over_nfx):
    dxp = dx * ncx_over_nfx  # d'x (3.6)
    return (px[:, 0] - u0) * dxp, (px[:, 1] - v0) * dy


def tsai_project(cam: dict, world_cm: np.ndarray) -> np.ndarray:
    """Project world points (N, 3, cm) with a Tsai camera (see :func:`tsai_camera`) to pixels (N, 2)."""
    P = np.asarray(world_cm, float) @ cam["R"].T + cam["t_cm"]
    Xu, Yu = cam["f"] * P[:, 0] / P[:, 2], cam["f"] * P[:, 1] / P[:, 2]
    ru = np.hypot(Xu, Yu)
    rd = ru.copy()
    k1 = cam["k1"]
    for _ in range(30):  # Newton on rd (1 + k1 rd^2) = ru
        g = rd * (1 + k1 * rd * rd) - ru
        rd = rd - g / (1 + 3 * k1 * rd * rd)
    s = np.where(ru > 0, rd / np.where(ru > 0, ru, 1), 1.0)
    Xd, Yd = Xu * s, Yu * s
    dxp = cam["dx"] * cam["ncx_over_nfx"]
    return np.stack([cam["sx"] * Xd / dxp + cam["u0"], Yd / cam["dy"] + cam["v0"]], axis=1)


def tsai_camera(world_cm, image_px, image_size, principal_point_px=None, pixel_pitch=(1.0, 1.0),
                ncx_over_nfx: float = 1.0, refine: bool = True) -> dict:
    """Calibrate one camera with Tsai's method from a non-coplanar target.

    Parameters
    ----------
    world_cm : (N, 3) array
        Target points in the world frame, cm; not all in one plane, N >= 7.
    image_px : (N, 2) array
        Their (distorted) pixels.
    image_size : (w, h)
        Pixels.
    principal_point_px : (u0, v0), optional
        Default: the image centre ((w-1)/2, (h-1)/2).
    pixel_pitch : (dx, dy)
        Sensor element spacing (any length unit; 1 = "f in pixels").
    ncx_over_nfx : float
        Ncx / Nfx of (3.6) (sensor elements per sampled pixel in x).
    refine : bool
        Run the non-linear refinement of f, tz and k1.

    Returns
    -------
    dict
        ``f`` (pitch units), ``k1`` (1/pitch-unit^2), ``sx``, ``R`` (3x3),
        ``t_cm`` (3,), ``u0``, ``v0``, ``dx``, ``dy``, ``ncx_over_nfx``,
        ``rms_px`` (reprojection), ``linear`` (f, tz, k1 before refinement),
        ``K`` and ``D`` (the OpenCV equivalent; see
        :func:`opencv_distortion_from_tsai`).
    """
    W = np.asarray(world_cm, float).reshape(-1, 3)
    px = np.asarray(image_px, float).reshape(-1, 2)
    if W.shape[0] != px.shape[0] or W.shape[0] < 7:
        raise ValueError(f"Tsai needs >= 7 matched points, got {W.shape[0]} world and {px.shape[0]} image points")
    w, h = image_size
    u0, v0 = principal_point_px if principal_point_px is not None else ((w - 1) / 2.0, (h - 1) / 2.0)
    dx, dy = (float(v) for v in pixel_pitch)
    Xdp, Yd = _sensor(px, u0, v0, dx, dy, ncx_over_nfx)  # X'd = sx Xd, Yd (3.8, 3.9)

    # Move the world origin to a point far from the row through the principal point (ty ~ its yc).
    i0 = int(np.argmax(np.abs(Yd)))
    p0 = W[i0].copy()
    Pw = W - p0
    if np.linalg.matrix_rank(Pw - Pw.mean(0), tol=1e-6 * np.abs(Pw).max()) < 3:
        raise ValueError("the target points are coplanar; Tsai's non-coplanar method needs points off one plane")

    # (3.16)-(3.17): X'd = [Yd Xw, Yd Yw, Yd Zw, Yd, -X'd Xw, -X'd Yw, -X'd Zw] . a
    A = np.column_stack([Yd * Pw[:, 0], Yd * Pw[:, 1], Yd * Pw[:, 2], Yd,
                         -Xdp * Pw[:, 0], -Xdp * Pw[:, 1], -Xdp * Pw[:, 2]])
    a, *_ = np.linalg.lstsq(A, Xdp, rcond=None)
    ty_abs = 1.0 / np.linalg.norm(a[4:7])  # (3.20)
    sx = np.linalg.norm(a[0:3]) * ty_abs  # (3.24)

    def pose(ty):
        r1 = a[0:3] * ty / sx
        r2 = a[4:7] * ty
        tx = a[3] * ty / sx
        return r1, r2, tx

    # (3.21)-(3.22): with ty > 0, the far point's projection must share the signs of its image point.
    far = int(np.argmax(Xdp ** 2 + Yd ** 2))
    r1, r2, tx = pose(ty_abs)
    xc, yc = r1 @ Pw[far] + tx, r2 @ Pw[far] + ty_abs
    ty = ty_abs if (np.sign(xc) == np.sign(Xdp[far]) and np.sign(yc) == np.sign(Yd[far])) else -ty_abs
    r1, r2, tx = pose(ty)
    r3 = np.cross(r1, r2)
    U, _, Vt = np.linalg.svd(np.vstack([r1, r2, r3]))
    R = U @ Vt  # the nearest rotation: noise makes r1, r2 slightly non-orthogonal
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    Xd = Xdp / sx

    def f_tz(R):
        # Ignoring distortion: Xd (w + tz) = f xc, Yd (w + tz) = f yc, w = r3 . P.
        xcs, ycs, ws = Pw @ R[0] + tx, Pw @ R[1] + ty, Pw @ R[2]
        M = np.concatenate([np.column_stack([xcs, -Xd]), np.column_stack([ycs, -Yd])])
        b = np.concatenate([ws * Xd, ws * Yd])
        sol, *_ = np.linalg.lstsq(M, b, rcond=None)
        return float(sol[0]), float(sol[1])

    f, tz = f_tz(R)
    if f < 0:  # Tsai: the wrong one of two mirror solutions; flip r13, r23, r31, r32
        R = R * np.array([[1, 1, -1], [1, 1, -1], [-1, -1, 1]])
        f, tz = f_tz(R)
    k1 = 0.0
    linear = {"f": f, "tz_cm": tz, "k1": k1}
    xcs, ycs, ws = Pw @ R[0] + tx, Pw @ R[1] + ty, Pw @ R[2]
    r2d = Xd * Xd + Yd * Yd

    def resid(q):
        fq, tzq, kq = q
        z = ws + tzq
        return np.concatenate([Xd * (1 + kq * r2d) - fq * xcs / z, Yd * (1 + kq * r2d) - fq * ycs / z])

    if refine:
        q = np.array([f, tz, k1])
        lam = 1e-3
        e = resid(q)
        cost = e @ e
        for _ in range(100):
            J = np.empty((e.size, 3))
            for j in range(3):
                step = 1e-7 * max(abs(q[j]), 1e-3 / max(r2d.max(), 1e-12) if j == 2 else 1.0)
                dq = np.zeros(3)
                dq[j] = step
                J[:, j] = (resid(q + dq) - e) / step
            H = J.T @ J
            g = J.T @ e
            while True:
                dq = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
                qn = q + dq
                en = resid(qn)
                if en @ en < cost:
                    q, e, cost, lam = qn, en, en @ en, lam * 0.3
                    break
                lam *= 10
                if lam > 1e12:
                    break
            if lam > 1e12 or np.all(np.abs(dq) <= 1e-12 * (np.abs(q) + 1e-12)):
                break
        f, tz, k1 = (float(v) for v in q)
    t = np.array([tx, ty, tz])
    # Back to the caller's world origin: Xc = R (P - p0) + t = R P + (t - R p0).
    cam = {"f": f, "k1": k1, "sx": float(sx), "R": R, "t_cm": t - R @ p0, "u0": float(u0), "v0": float(v0),
           "dx": dx, "dy": dy, "ncx_over_nfx": float(ncx_over_nfx), "linear": linear}
    err = tsai_project(cam, W) - px
    cam["rms_px"] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    cam["K"], cam["D"] = _opencv_equivalent(cam, image_size)
    return cam


def _opencv_equivalent(cam: dict, image_size) -> tuple[np.ndarray, np.ndarray]:
    dxp = cam["dx"] * cam["ncx_over_nfx"]
    fx, fy = cam["f"] * cam["sx"] / dxp, cam["f"] / cam["dy"]
    K = np.array([[fx, 0, cam["u0"]], [0, fy, cam["v0"]], [0, 0, 1.0]])
    w, h = image_size
    corner = max(np.hypot(max(cam["u0"], w - 1 - cam["u0"]) / fx, max(cam["v0"], h - 1 - cam["v0"]) / fy), 1e-6)
    # Tsai's k1 in normalised units: r_metric = f * r_normalised (y pitch convention).
    kappa = cam["k1"] * cam["f"] ** 2
    D = opencv_distortion_from_tsai(kappa, corner * 1.05)
    return K, D


def opencv_distortion_from_tsai(kappa_norm: float, r_max: float) -> np.ndarray:
    """OpenCV radial coefficients (k1, k2, 0, 0, k3) equivalent to Tsai's model over 0..r_max.

    Tsai: ``r_u = r_d (1 + kappa r_d^2)`` (normalised units); OpenCV:
    ``r_d = r_u (1 + k1 r_u^2 + k2 r_u^4 + k3 r_u^6)``. Fitted by least squares.
    """
    rd = np.linspace(1e-3, r_max, 400)
    ru = rd * (1 + kappa_norm * rd * rd)
    A = np.column_stack([ru ** 2, ru ** 4, ru ** 6])
    k, *_ = np.linalg.lstsq(A, rd / ru - 1, rcond=None)
    return np.array([k[0], k[1], 0.0, 0.0, k[2]])


def tsai_k1_of_opencv(D, r_max: float) -> float:
    """Tsai's k1 (normalised units) that best matches an OpenCV radial model over 0..r_max (for comparisons)."""
    k1, k2, _, _, k3 = (list(np.ravel(D)) + [0.0] * 5)[:5]
    ru = np.linspace(1e-3, r_max, 400)
    rd = ru * (1 + k1 * ru ** 2 + k2 * ru ** 4 + k3 * ru ** 6)
    # ru = rd (1 + kappa rd^2)  ->  ru / rd - 1 = kappa rd^2
    return float(np.sum((ru / rd - 1) * rd ** 2) / np.sum(rd ** 4))


def tsai_stereo(world_cm, left_px, right_px, image_size, principal_left=None, principal_right=None,
                pixel_pitch=(1.0, 1.0), ncx_over_nfx=1.0, refine=True) -> dict:
    """Calibrate both cameras against the same world points and derive the stereo pose.

    Returns a ``StereoCalibration`` (OpenCV-equivalent K, D; ``R``, ``T_cm`` with
    ``X_right = R X_left + T``) plus ``tsai_left`` / ``tsai_right`` (the raw
    Tsai parameters) and ``T_world_from_left`` (4x4, cm).
    """
    cl = tsai_camera(world_cm, left_px, image_size, principal_left, pixel_pitch, ncx_over_nfx, refine)
    cr = tsai_camera(world_cm, right_px, image_size, principal_right, pixel_pitch, ncx_over_nfx, refine)
    R = cr["R"] @ cl["R"].T
    T = cr["t_cm"] - R @ cl["t_cm"]
    Tw = np.eye(4)
    Tw[:3, :3] = cl["R"].T
    Tw[:3, 3] = -cl["R"].T @ cl["t_cm"]
    raw = {s: {k: v for k, v in c.items() if k not in ("K", "D")} for s, c in (("left", cl), ("right", cr))}
    return {"K1": cl["K"], "D1": cl["D"], "K2": cr["K"], "D2": cr["D"], "R": R, "T_cm": T,
            "image_size": [int(image_size[0]), int(image_size[1])],
            "rms_px": float(np.sqrt((cl["rms_px"] ** 2 + cr["rms_px"] ** 2) / 2)),
            "per_view_rms_px": {}, "rejected_views": [], "method": "tsai",
            "tsai_left": raw["left"], "tsai_right": raw["right"], "T_world_from_left": Tw}


class TsaiParams(Params):
    principal_point_left_px: tuple[float, float] | None = Field(
        None, description="Left principal point (u0, v0), pixels; default the image centre.")
    principal_point_right_px: tuple[float, float] | None = Field(
        None, description="Right principal point (u0, v0), pixels; default the image centre.")
    pixel_pitch: tuple[float, float] = Field(
        (1.0, 1.0), description="Sensor pitch (dx, dy), any length unit; (1, 1) gives f in pixels.")
    ncx_over_nfx: float = Field(1.0, gt=0, description="Ncx / Nfx of eq. (3.6) (unitless).")
    refine: bool = Field(True, description="Non-linear refinement of f, tz and k1 (switch).")


@node(
    "calibrator.tsai",
    inputs={"views": In("StereoViews", optional=True,
                        description="Chessboard views with known board poses (board_poses_table): a multi-plane "
                                    "target."),
            "points": In("CalibrationPoints", optional=True,
                         description="{world_cm: Nx3, left_px: Nx2, right_px: Nx2, image_size}.")},
    outputs={"calibration": Out("StereoCalibration", save=True), **EXPORT_OUTPUTS},
    params=TsaiParams,
    version="1",
)
def tsai(params: TsaiParams, views: dict | None = None, points: dict | None = None, ctx=None) -> dict:
    """Calibrate the stereo rig with the seed thesis's Tsai method (non-coplanar 3-D target)."""
    corners_l, corners_r = {}, {}
    if points is not None:
        W = np.asarray(points["world_cm"], float)
        L = np.asarray(points["left_px"], float)
        Rr = np.asarray(points["right_px"], float)
        size = points["image_size"]
        rejected = {}
    elif views is not None:
        poses = views.get("board_poses_table") or {}
        if not poses:
            raise NodeError("calibrator.tsai: the views carry no board poses, so their corners have no 3-D world "
                            "coordinates.", hint="give a `points` input (world_cm + pixels) or views with "
                                                 "board_poses_table, e.g. from source.synthetic")
        b = views["board"]
        ids, left, right, rejected = detect_views(views["views"], int(b["cols"]), int(b["rows"]))
        ids_ok = [i for i in ids if i in poses]
        if len(ids_ok) < 2:
            raise NodeError(f"calibrator.tsai: {len(ids_ok)} usable view(s) with a known pose; a multi-plane target "
                            "needs at least 2.", hint="add views (different board poses)")
        obj = board_points(int(b["cols"]), int(b["rows"]), float(b["square_cm"])).astype(float)
        Ws, Ls, Rs = [], [], []
        for i, cl, cr in zip(ids, left, right):
            if i not in poses:
                continue
            T = np.asarray(poses[i], float)
            Ws.append(obj @ T[:3, :3].T + T[:3, 3])
            Ls.append(cl)
            Rs.append(cr)
            corners_l[i], corners_r[i] = cl, cr
        W, L, Rr = np.concatenate(Ws), np.concatenate(Ls), np.concatenate(Rs)
        size = views["image_size"]
    else:
        raise NodeError("calibrator.tsai: wire `views` (with board poses) or `points`.",
                        hint="see docs/rig.md, 'Tsai calibration'")
    try:
        cal = tsai_stereo(W, L, Rr, size, params.principal_point_left_px, params.principal_point_right_px,
                          params.pixel_pitch, params.ncx_over_nfx, params.refine)
    except ValueError as exc:
        raise NodeError(f"calibrator.tsai: {exc}.", hint="use points on two or more planes") from exc
    cal["rejected_views"] = sorted(rejected)
    cal["rejected_reasons"] = rejected
    if corners_l:
        cal["corners_left_px"], cal["corners_right_px"] = corners_l, corners_r
    return calibration_outputs(cal, ctx, (views or {}).get("board"))
