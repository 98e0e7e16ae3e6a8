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
true principal point). The target is either non-coplanar (3-D world points, cm,
such as a plane moved by known amounts or a chessboard seen at several known
poses) or coplanar (one flat target, not parallel to the image plane); then sx
cannot be determined and is assumed (``coplanar_sx``, default 1).

Steps (non-coplanar): (3.8) pixels -> sensor coordinates; (3.16-3.18) the radial
alignment constraint gives a linear least-squares problem in seven unknowns
a1..a7; (3.20) |ty|; its sign as in (3.21-3.22), which test one point far from
the image centre (here all points, weighted by that distance); (3.24) sx; r1,
r2, tx; r3 = r1 x r2 (then the nearest rotation, by SVD). Coplanar (Tsai 1987;
not written out in the thesis): the same constraint with z_w = 0 has five
unknowns; |ty| from the 2x2 block of the rotation, r13 and r23 from unit rows
and r1 . r2 = 0 (``_tsai_steps.coplanar_rotation``; a target measured in any
frame is first expressed in its own plane's frame). Then, for both: f and tz by
linear least squares ignoring distortion; finally a Levenberg-Marquardt
refinement of f, tz and k1 (the thesis) or, by default (``refine_pose``), of the
whole pose with them: Tsai's full optimisation, which removes the linear step's
rotation error (NumPy; SciPy is not needed).

Implementation notes beyond the thesis: the world origin is moved to the target
point imaged farthest from the principal point's row, because the method
divides by ty (a world origin near the optical axis makes ty ~ 0); the
solution is moved back afterwards. Eq. (3.21) writes tx = a4 ty; from (3.18)
it is tx = a4 ty / sx.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from nodes.calibrators._board import board_points, detect_views
from nodes.calibrators._calib_io import calibration_outputs
from nodes.calibrators._tsai_steps import (
    coplanar_rotation,
    f_sigma_rel,
    plane_frame,
    refine_camera,
    thickness_ratio,
)
from nodes.contracts.calibration_export import EXPORT_OUTPUTS
from nodes.contracts.tsai_camera import tsai_project
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = [
    "COPLANAR_THICKNESS",
    "TsaiParams",
    "opencv_distortion_from_tsai",
    "tsai",
    "tsai_camera",
    "tsai_k1_of_opencv",
    "tsai_project",
    "tsai_stereo",
]

# A target flatter than this (out-of-plane over in-plane spread) is treated as one plane by target:
# auto. On a nearly flat target the non-coplanar step cannot separate sx from the pose: on a sheet
# bowed by 0.1-1.5 % it fitted to the noise level (RMS 0.28 px at 0.2 px noise) with the baseline
# 4-10 % off, while the coplanar step (sx assumed) was within 0.3 %; at 3-9 % both were.
COPLANAR_THICKNESS = 0.05


def _sensor(px, u0, v0, dx, dy, ncx_over_nfx):
    dxp = dx * ncx_over_nfx  # d'x (3.6)
    return (px[:, 0] - u0) * dxp, (px[:, 1] - v0) * dy


def tsai_camera(
    world_cm,
    image_px,
    image_size,
    principal_point_px=None,
    pixel_pitch=(1.0, 1.0),
    ncx_over_nfx: float = 1.0,
    refine: bool = True,
    target: str = "auto",
    coplanar_sx: float = 1.0,
    refine_pose: bool = True,
) -> dict:
    """Calibrate one camera with Tsai's method from a coplanar or a non-coplanar target.

    Parameters
    ----------
    world_cm : (N, 3) array
        Target points in the world frame, cm; N >= 7 (non-coplanar) or >= 5 (coplanar).
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
        Run the non-linear refinement (f, tz, k1; with ``refine_pose`` also the rest of the pose).
    target : {"auto", "coplanar", "non_coplanar"}
        Which of Tsai's two linear steps to use; ``auto``: coplanar when the points' thickness
        (out-of-plane over in-plane spread) is below ``COPLANAR_THICKNESS``.
    coplanar_sx : float
        The scale factor sx assumed for a coplanar target, which cannot determine it (unitless).
    refine_pose : bool
        Also refine the rotation, tx, ty (and sx for a non-coplanar target) in the non-linear
        step: Tsai's (1987) full optimisation. False: f, tz and k1 only, as in the thesis.

    Returns
    -------
    dict
        ``f`` (pitch units), ``k1`` (1/pitch-unit^2), ``sx``, ``R`` (3x3),
        ``t_cm`` (3,), ``u0``, ``v0``, ``dx``, ``dy``, ``ncx_over_nfx``, ``target``
        ("coplanar" / "non_coplanar"), ``thickness``, ``rms_px`` (reprojection),
        ``linear`` (f, tz, k1 before refinement), ``K`` and ``D`` (the OpenCV equivalent;
        see :func:`opencv_distortion_from_tsai`).
    """
    W, px, thick, coplanar = _target_points(world_cm, image_px, target)
    w, h = image_size
    u0, v0 = (
        principal_point_px if principal_point_px is not None else ((w - 1) / 2.0, (h - 1) / 2.0)
    )
    dx, dy = (float(v) for v in pixel_pitch)
    Xdp, Yd = _sensor(px, u0, v0, dx, dy, ncx_over_nfx)  # X'd = sx Xd, Yd (3.8, 3.9)

    # Move the world origin to a point far from the row through the principal point (ty ~ its yc).
    i0 = int(np.argmax(np.abs(Yd)))
    p0 = W[i0].copy()
    Pw = W - p0
    R, tx, ty, sx, Rpw = _linear_pose(W, Pw, Xdp, Yd, coplanar, coplanar_sx)
    Xd = Xdp / sx

    R, f, tz = _f_and_tz(Pw, R, tx, ty, Xd, Yd, Rpw)
    k1 = 0.0
    linear = {"f": f, "tz_cm": tz, "k1": k1}
    if refine:
        R, tx, ty, tz, f, k1, sx = refine_camera(
            Pw, Xdp, Yd, R, tx, ty, tz, f, sx, not coplanar, refine_pose
        )
    f_sigma = f_sigma_rel(Pw, Xdp, Yd, R, tx, ty, tz, f, k1, sx, not coplanar)
    t = np.array([tx, ty, tz])
    # Back to the caller's world origin: Xc = R (P - p0) + t = R P + (t - R p0).
    cam = {
        "f": f,
        "k1": k1,
        "sx": float(sx),
        "R": R,
        "t_cm": t - R @ p0,
        "u0": float(u0),
        "v0": float(v0),
        "dx": dx,
        "dy": dy,
        "ncx_over_nfx": float(ncx_over_nfx),
        "linear": linear,
        "target": "coplanar" if coplanar else "non_coplanar",
        "thickness": thick,
        "f_sigma_rel": f_sigma,
        # angle between a flat target's normal and the optical axis (0 = seen face-on: f
        # undetermined)
        "tilt_deg": float(np.degrees(np.arccos(min(1.0, abs((R @ Rpw[2])[2])))))
        if coplanar
        else None,
    }
    return _with_fit(cam, W, px, image_size)


def _with_fit(cam: dict, W: np.ndarray, px: np.ndarray, image_size) -> dict:
    """``cam`` with its reprojection RMS (px) over the target and its OpenCV equivalent K, D."""
    err = tsai_project(cam, W) - px
    cam["rms_px"] = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    cam["K"], cam["D"] = _opencv_equivalent(cam, image_size)
    return cam


def _target_points(world_cm, image_px, target: str) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """``(world points (N, 3), pixels (N, 2), thickness, coplanar?)``: the step ``target`` asks
    for (``auto``: coplanar below ``COPLANAR_THICKNESS``), with enough matched points for it."""
    W = np.asarray(world_cm, float).reshape(-1, 3)
    px = np.asarray(image_px, float).reshape(-1, 2)
    thick = thickness_ratio(W) if len(W) >= 3 else 0.0
    if target not in ("auto", "coplanar", "non_coplanar"):
        raise ValueError(f"target must be auto, coplanar or non_coplanar, not {target!r}")
    coplanar = target == "coplanar" or (target == "auto" and thick < COPLANAR_THICKNESS)
    need = 5 if coplanar else 7
    if W.shape[0] != px.shape[0] or W.shape[0] < need:
        raise ValueError(
            f"Tsai needs >= {need} matched points, got {W.shape[0]} world and "
            f"{px.shape[0]} image points"
        )
    return W, px, thick, coplanar


def _f_tz(Pw: np.ndarray, R: np.ndarray, tx: float, ty: float, Xd: np.ndarray, Yd: np.ndarray):
    """Tsai's ``(f, tz)`` by least squares, ignoring distortion: Xd (w + tz) = f xc,
    Yd (w + tz) = f yc, w = r3 . P."""
    xcs, ycs, ws = Pw @ R[0] + tx, Pw @ R[1] + ty, Pw @ R[2]
    M = np.concatenate([np.column_stack([xcs, -Xd]), np.column_stack([ycs, -Yd])])
    b = np.concatenate([ws * Xd, ws * Yd])
    sol, *_ = np.linalg.lstsq(M, b, rcond=None)
    return float(sol[0]), float(sol[1])


def _f_and_tz(Pw, R, tx, ty, Xd, Yd, Rpw) -> tuple[np.ndarray, float, float]:
    """``(R, f, tz)``: with f < 0, the linear step found the wrong one of two mirror solutions;
    flip r13, r23, r31, r32 (in the target's own frame: z along a flat target's normal, where the
    coplanar step chose the sign of r13, r23) and solve again."""
    f, tz = _f_tz(Pw, R, tx, ty, Xd, Yd)
    if f < 0:
        R = (R @ Rpw.T * np.array([[1, 1, -1], [1, 1, -1], [-1, -1, 1]])) @ Rpw
        f, tz = _f_tz(Pw, R, tx, ty, Xd, Yd)
    return R, f, tz


def _linear_pose(
    W: np.ndarray, Pw: np.ndarray, Xdp: np.ndarray, Yd: np.ndarray, coplanar: bool, coplanar_sx
) -> tuple[np.ndarray, float, float, float, np.ndarray]:
    """Tsai's linear step: ``(R, tx, ty, sx, the target plane's frame)`` from a coplanar target
    (sx assumed ``coplanar_sx``; frame: the plane's) or a non-coplanar one (frame: identity)."""
    if coplanar:
        Rpw = plane_frame(W)
        xy = Pw @ Rpw[:2].T
        if np.linalg.matrix_rank(xy - xy.mean(0), tol=1e-6 * max(np.abs(xy).max(), 1e-12)) < 2:
            raise ValueError(
                "the target points lie on one line; Tsai's method needs them spread over a plane "
                "or over several planes"
            )
        sx = float(coplanar_sx)
        Rp, tx, ty = coplanar_rotation(Xdp / sx, Yd, xy)
        R = Rp @ Rpw  # world -> plane -> camera
    else:
        if np.linalg.matrix_rank(Pw - Pw.mean(0), tol=1e-6 * np.abs(Pw).max()) < 3:
            raise ValueError(
                "the target points are coplanar; Tsai's non-coplanar method needs points "
                "off one plane "
                "(use target: coplanar or auto)"
            )
        R, tx, ty, sx = _noncoplanar_rotation(Xdp, Yd, Pw)
        Rpw = np.eye(3)
    return R, tx, ty, sx, Rpw


def _noncoplanar_rotation(Xdp, Yd, Pw):
    """The thesis's linear step (3.16)-(3.24): R, tx, ty, sx from a non-coplanar target."""
    # (3.16)-(3.17): X'd = [Yd Xw, Yd Yw, Yd Zw, Yd, -X'd Xw, -X'd Yw, -X'd Zw] . a
    A = np.column_stack(
        [
            Yd * Pw[:, 0],
            Yd * Pw[:, 1],
            Yd * Pw[:, 2],
            Yd,
            -Xdp * Pw[:, 0],
            -Xdp * Pw[:, 1],
            -Xdp * Pw[:, 2],
        ]
    )
    a, *_ = np.linalg.lstsq(A, Xdp, rcond=None)
    ty_abs = 1.0 / np.linalg.norm(a[4:7])  # (3.20)
    sx = np.linalg.norm(a[0:3]) * ty_abs  # (3.24)

    def pose(ty):
        r1 = a[0:3] * ty / sx
        r2 = a[4:7] * ty
        tx = a[3] * ty / sx
        return r1, r2, tx

    # (3.21)-(3.22): with ty > 0, the projections must share the signs of their image points.
    # Checked on every point, weighted by its distance from the centre (one far point near an image
    # axis can have the wrong sign by noise): with the right sign (xc, yc) points the way (X'd, Yd)
    # does.
    r1, r2, tx = pose(ty_abs)
    xc, yc = Pw @ r1 + tx, Pw @ r2 + ty_abs
    ty = ty_abs if float(xc @ Xdp + yc @ Yd) > 0 else -ty_abs
    r1, r2, tx = pose(ty)
    r3 = np.cross(r1, r2)
    U, _, Vt = np.linalg.svd(np.vstack([r1, r2, r3]))
    R = U @ Vt  # the nearest rotation: noise makes r1, r2 slightly non-orthogonal
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    return R, float(tx), float(ty), float(sx)


def _opencv_equivalent(cam: dict, image_size) -> tuple[np.ndarray, np.ndarray]:
    dxp = cam["dx"] * cam["ncx_over_nfx"]
    fx, fy = cam["f"] * cam["sx"] / dxp, cam["f"] / cam["dy"]
    K = np.array([[fx, 0, cam["u0"]], [0, fy, cam["v0"]], [0, 0, 1.0]])
    w, h = image_size
    corner = max(
        np.hypot(max(cam["u0"], w - 1 - cam["u0"]) / fx, max(cam["v0"], h - 1 - cam["v0"]) / fy),
        1e-6,
    )
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
    A = np.column_stack([ru**2, ru**4, ru**6])
    k, *_ = np.linalg.lstsq(A, rd / ru - 1, rcond=None)
    return np.array([k[0], k[1], 0.0, 0.0, k[2]])


def tsai_k1_of_opencv(D, r_max: float) -> float:
    """Tsai's k1 (normalised units) that best matches an OpenCV radial model over 0..r_max (for
    comparisons)."""
    k1, k2, _, _, k3 = (list(np.ravel(D)) + [0.0] * 5)[:5]
    ru = np.linspace(1e-3, r_max, 400)
    rd = ru * (1 + k1 * ru**2 + k2 * ru**4 + k3 * ru**6)
    # ru = rd (1 + kappa rd^2)  ->  ru / rd - 1 = kappa rd^2
    return float(np.sum((ru / rd - 1) * rd**2) / np.sum(rd**4))


def tsai_stereo(
    world_cm,
    left_px,
    right_px,
    image_size,
    principal_left=None,
    principal_right=None,
    pixel_pitch=(1.0, 1.0),
    ncx_over_nfx=1.0,
    refine=True,
    target="auto",
    coplanar_sx=1.0,
    refine_pose=True,
) -> dict:
    """Calibrate both cameras against the same world points and derive the stereo pose.

    Two single-camera calibrations (:func:`tsai_camera`, same keyword meanings), then the
    relative pose ``R = R_r R_l^T``, ``T = t_r - R t_l``.

    Returns a ``StereoCalibration`` (OpenCV-equivalent K, D; ``R``, ``T_cm`` with
    ``X_right = R X_left + T``) plus ``tsai_left`` / ``tsai_right`` (the raw
    Tsai parameters) and ``T_world_from_left`` (4x4, cm).
    """
    kw = dict(
        pixel_pitch=pixel_pitch,
        ncx_over_nfx=ncx_over_nfx,
        refine=refine,
        target=target,
        coplanar_sx=coplanar_sx,
        refine_pose=refine_pose,
    )
    cl = tsai_camera(world_cm, left_px, image_size, principal_left, **kw)
    cr = tsai_camera(world_cm, right_px, image_size, principal_right, **kw)
    R = cr["R"] @ cl["R"].T
    T = cr["t_cm"] - R @ cl["t_cm"]
    Tw = np.eye(4)
    Tw[:3, :3] = cl["R"].T
    Tw[:3, 3] = -cl["R"].T @ cl["t_cm"]
    raw = {
        s: {k: v for k, v in c.items() if k not in ("K", "D")}
        for s, c in (("left", cl), ("right", cr))
    }
    return {
        "K1": cl["K"],
        "D1": cl["D"],
        "K2": cr["K"],
        "D2": cr["D"],
        "R": R,
        "T_cm": T,
        "image_size": [int(image_size[0]), int(image_size[1])],
        "rms_px": float(np.sqrt((cl["rms_px"] ** 2 + cr["rms_px"] ** 2) / 2)),
        "per_view_rms_px": {},
        "rejected_views": [],
        "method": "tsai",
        "tsai_left": raw["left"],
        "tsai_right": raw["right"],
        "T_world_from_left": Tw,
    }


class TsaiParams(Params):
    principal_point_left_px: tuple[float, float] | None = Field(
        None, description="Left principal point (u0, v0), pixels; default the image centre."
    )
    principal_point_right_px: tuple[float, float] | None = Field(
        None, description="Right principal point (u0, v0), pixels; default the image centre."
    )
    pixel_pitch: tuple[float, float] = Field(
        (1.0, 1.0), description="Sensor pitch (dx, dy), any length unit; (1, 1) gives f in pixels."
    )
    ncx_over_nfx: float = Field(1.0, gt=0, description="Ncx / Nfx of eq. (3.6) (unitless).")
    refine: bool = Field(True, description="Non-linear refinement of f, tz and k1 (switch).")
    refine_pose: bool = Field(
        True,
        description="Also refine the rotation, tx, ty (and sx for a non-coplanar target) in the "
        "non-linear "
        "step: Tsai 1987's full optimisation (switch); false = f, tz, k1 only, as in the thesis.",
    )
    target: Literal["auto", "coplanar", "non_coplanar"] = Field(
        "auto",
        description="Tsai's coplanar or non-coplanar linear step; auto: coplanar when the points' "
        "out-of-plane spread is under 5 % of their in-plane spread (unitless choice).",
    )
    coplanar_sx: float = Field(
        1.0,
        gt=0.5,
        lt=2.0,
        description="Horizontal scale factor sx (unitless) assumed for a coplanar target, which "
        "cannot determine it (Tsai 1987); 1 = square pixels.",
    )
    max_f_sigma_pct: float = Field(
        0.5,
        gt=0,
        description="Refuse a calibration whose focal length the points leave uncertain by more "
        "than "
        "this (1 sigma from the fit's covariance, % of f): e.g. a flat target seen face-on.",
    )
    max_rms_px: float = Field(
        2.0,
        gt=0,
        description="Refuse a calibration whose reprojection RMS exceeds this (pixels): the "
        "points do "
        "not fit one camera (mismatched rows, wrong unit or principal point).",
    )


def _points_of(points: dict):
    """The arrays of a ``CalibrationPoints`` artifact, checked (NodeError naming the bad key)."""
    try:
        W = np.asarray(points["world_cm"], float).reshape(-1, 3)
        L = np.asarray(points["left_px"], float).reshape(-1, 2)
        Rr = np.asarray(points["right_px"], float).reshape(-1, 2)
        size = [int(v) for v in points["image_size"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise NodeError(
            f"calibrator.tsai: the `points` input is not a CalibrationPoints artifact ({exc!r}).",
            hint="wire it to source.target_points, or give world_cm Nx3, left_px Nx2, "
            "right_px Nx2 and "
            "image_size [w, h] (docs/artifacts.md)",
        ) from exc
    if not (len(W) == len(L) == len(Rr)) or len(size) != 2:
        raise NodeError(
            f"calibrator.tsai: the `points` input has {len(W)} world, {len(L)} left and "
            f"{len(Rr)} right "
            "points; they must match one to one.",
            hint="give every 3-D point both of its image points",
        )
    if not (np.isfinite(W).all() and np.isfinite(L).all() and np.isfinite(Rr).all()):
        raise NodeError(
            "calibrator.tsai: the `points` input holds NaN or infinite coordinates.",
            hint="drop the points a camera did not see",
        )
    return W, L, Rr, size


@node(
    "calibrator.tsai",
    inputs={
        "views": In(
            "StereoViews",
            optional=True,
            description="Chessboard views with known board poses (board_poses_table): a "
            "multi-plane "
            "target.",
        ),
        "points": In(
            "CalibrationPoints",
            optional=True,
            description="{world_cm: Nx3, left_px: Nx2, right_px: Nx2, image_size}.",
        ),
    },
    outputs={"calibration": Out("StereoCalibration", save=True), **EXPORT_OUTPUTS},
    params=TsaiParams,
    version="2",
)
def tsai(
    params: TsaiParams, views: dict | None = None, points: dict | None = None, ctx=None
) -> dict:
    """Calibrate the stereo rig with Tsai's method (the seed thesis; coplanar or non-coplanar
    target)."""
    corners_l, corners_r = {}, {}
    origin = "the views' board corners"
    if points is not None:
        W, L, Rr, size = _points_of(points)
        origin = ", ".join(points.get("files") or []) or "the `points` input"
        rejected = {}
    elif views is not None:
        W, L, Rr, size, rejected = _board_target(views, corners_l, corners_r)
    else:
        raise NodeError(
            "calibrator.tsai: wire `views` (with board poses) or `points`.",
            hint="see docs/rig.md, 'Tsai calibration'",
        )
    try:
        cal = tsai_stereo(
            W,
            L,
            Rr,
            size,
            params.principal_point_left_px,
            params.principal_point_right_px,
            params.pixel_pitch,
            params.ncx_over_nfx,
            params.refine,
            params.target,
            params.coplanar_sx,
            params.refine_pose,
        )
    except ValueError as exc:
        raise NodeError(
            f"calibrator.tsai: {exc} ({origin}).",
            hint="spread the target points over the whole image, on one tilted plane or on several "
            "planes (target: auto picks the method)",
        ) from exc
    for side in ("left", "right"):
        _check_camera(side, cal[f"tsai_{side}"], W, origin, params, ctx)
    cal["target"] = cal["tsai_left"]["target"]
    if ctx is not None:
        _warn_assumptions(cal, params, ctx)
    cal["rejected_views"] = sorted(rejected)
    cal["rejected_reasons"] = rejected
    if corners_l:
        cal["corners_left_px"], cal["corners_right_px"] = corners_l, corners_r
    return calibration_outputs(cal, ctx, (views or {}).get("board"))


def _warn_assumptions(cal: dict, params: TsaiParams, ctx) -> None:
    """Warn of what the result rests on: principal points assumed at the image centre, a nearly
    flat target fitted by the non-coplanar step."""
    assumed = [
        s
        for s, pp in (
            ("left", params.principal_point_left_px),
            ("right", params.principal_point_right_px),
        )
        if pp is None
    ]
    # Tsai's method does not estimate it (docs/rig.md: 1-3 % on T when it is off)
    if assumed:
        ctx.warn(
            f"the {' and '.join(assumed)} principal "
            f"point{'s are' if len(assumed) > 1 else ' is'} assumed at the "
            "image centre; give principal_point_*_px (from a chessboard calibration of "
            "the same camera, say) "
            "if it is known"
        )
    thick = cal["tsai_left"]["thickness"]
    if cal["target"] == "non_coplanar" and thick < COPLANAR_THICKNESS:
        ctx.warn(
            f"the target is nearly flat (out-of-plane spread {100 * thick:.1f} % of its "
            "size): the non-coplanar "
            "step cannot separate sx from the pose; target: auto would use the coplanar one"
        )


def _board_target(
    views: dict, corners_l: dict, corners_r: dict
) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any, dict]:
    """``(world_cm, left_px, right_px, image_size, rejected views)`` of a multi-plane target: the
    board corners of every view whose pose is known (``board_poses_table``); fills the corners
    per view."""
    poses = views.get("board_poses_table") or {}
    if not poses:
        raise NodeError(
            "calibrator.tsai: the views carry no board poses, so their corners have "
            "no 3-D world "
            "coordinates.",
            hint="give a `points` input (world_cm + pixels) or views with "
            "board_poses_table, e.g. from source.synthetic",
        )
    b = views["board"]
    ids, left, right, rejected = detect_views(views["views"], int(b["cols"]), int(b["rows"]))
    ids_ok = [i for i in ids if i in poses]
    if len(ids_ok) < 2:
        raise NodeError(
            f"calibrator.tsai: {len(ids_ok)} usable view(s) with a known pose; a "
            "multi-plane target "
            "needs at least 2.",
            hint="add views (different board poses)",
        )
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
    return W, L, Rr, views["image_size"], rejected


def _check_camera(
    side: str, c: dict, W: np.ndarray, origin: str, params: TsaiParams, ctx: Any
) -> None:
    """A wrong calibration is worse than none: refuse a camera whose points do not fit it, whose
    focal length the target leaves uncertain, or that sees points behind it."""
    if not (c["rms_px"] <= params.max_rms_px and c["f"] > 0):
        raise NodeError(
            f"calibrator.tsai: the {side} camera's reprojection RMS is "
            f"{c['rms_px']:.2f} px (limit "
            f"max_rms_px = {params.max_rms_px:g}) with {len(W)} points from {origin}: "
            "the points do not fit one "
            "camera.",
            hint="check that each row's 3-D point and pixels belong together, the length "
            "unit, the "
            "principal point and image_size_px; raise max_rms_px only for a coarse target",
        )
    sig = 100 * c["f_sigma_rel"]
    if not sig <= params.max_f_sigma_pct:
        tilt = f" (seen {c['tilt_deg']:.1f}° from face-on)" if c.get("tilt_deg") is not None else ""
        raise NodeError(
            f"calibrator.tsai: the points from {origin} leave the {side} camera's "
            "focal length uncertain by "
            f"±{sig:.2g} % (1 sigma; limit max_f_sigma_pct = "
            f"{params.max_f_sigma_pct:g}): the target does not "
            f"separate f from its distance{tilt}.",
            hint="tilt a flat target 30° or more to the cameras, or add points at other "
            "depths; spread the "
            "points over the whole image",
        )
    if sig > params.max_f_sigma_pct / 2 and ctx is not None:
        ctx.warn(
            f"the {side} camera's f is uncertain by ±{sig:.2f} % (1 sigma) and every "
            "depth with it; a more "
            "tilted target or more points would tighten it"
        )
    if np.any((W @ c["R"].T + c["t_cm"])[:, 2] <= 0):
        raise NodeError(
            f"calibrator.tsai: some target points from {origin} come out behind the {side} camera.",
            hint="check that u (column) and v (row) are not swapped and the 3-D axes are "
            "right-handed",
        )
