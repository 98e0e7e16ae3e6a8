"""Shared pieces of the disparity estimators: parameters, range checks, the output record,
and the sphere geometry used by ``disparity.ellipse``.

Sphere-aware centre (the math)
------------------------------
A sphere of radius R with centre C seen from a camera centre O is bounded by a right
circular *tangent cone* with apex O, axis along C - O and half-angle alpha, sin(alpha) = R/|C|.
In normalised camera coordinates x = K^-1 [u, v, 1]^T the cone is

    x^T (a a^T - cos^2(alpha) I) x = 0,          a = C / |C|  (unit axis),

so its image -- the silhouette -- is the conic  E = K^-T (a a^T - cos^2 alpha I) K^-1  (up to
scale): an ellipse whose centre is *not* K a, the image of the sphere's centre (it is pushed
away from the principal point by about |Ka - c| tan^2(alpha)). Going back: from the fitted
ellipse's conic E (3x3 symmetric, pixel coordinates) form the cone matrix M = K^T E K. Its
eigenvalues are (up to a common factor) sin^2 alpha once and -cos^2 alpha twice; the
eigenvector of the lone-signed eigenvalue is the axis a, hence the image of the centre
K a, and tan^2 alpha = -lambda_1 / lambda_2 gives the distance |C| = R / sin(alpha) without
any second view. ``disparity.ellipse`` applies this to both rectified views
(K = P1[:, :3], P2[:, :3]) and returns the disparity of the two centre images, which is exactly
f B / Z_c for the sphere's centre -- no perspective bias, unlike the silhouette centroids.
"""

from __future__ import annotations

import math

import numpy as np

from stereograph.api import Field, Params, PositiveRange


class DisparityParams(Params):
    """Parameters shared by every disparity estimator."""

    working_range_cm: PositiveRange = Field(
        (20.0, 80.0), description="Nearest and farthest plausible object distance (cm); outside -> not found."
    )
    range_slack: float = Field(
        0.25, ge=0, le=2, description="Relative slack on the working range before rejecting a disparity (ratio)."
    )
    min_sigma_disparity_px: float = Field(
        0.02, gt=0, description="Floor of the reported disparity uncertainty (px)."
    )


def disparity_range_px(rectification: dict | None, params: DisparityParams) -> tuple[float, float] | None:
    """Plausible disparity range (px) from f*B and the working range, or None without calibration."""
    if rectification is None:
        return None
    fb = float(rectification["f_px"]) * float(rectification["baseline_cm"])
    z0, z1 = sorted(params.working_range_cm)
    return fb / (z1 * (1 + params.range_slack)), fb / (z0 * (1 - min(params.range_slack, 0.9)))


def not_found(seg_or_id, reason: str, method: str) -> dict:
    """A Disparity record with ``found: False``."""
    sid = seg_or_id["id"] if isinstance(seg_or_id, dict) else str(seg_or_id)
    split = seg_or_id.get("split") if isinstance(seg_or_id, dict) else None
    return {
        "id": sid, "found": False, "reason": reason, "u_left_px": None, "v_left_px": None,
        "disparity_px": None, "sigma_disparity_px": None, "method": method, "split": split,
        "depth_offset_cm": 0.0,
    }


def finish(seg: dict, u: float, v: float, d: float, sigma_d: float, method: str,
           rectification: dict | None, params: DisparityParams, ctx=None, **extra) -> dict:
    """A Disparity record, or a not-found one when d lies outside the plausible range."""
    rng = disparity_range_px(rectification, params)
    if not np.isfinite(d) or d <= 0:
        rec = not_found(seg, f"disparity out of range ({d:.2f} px <= 0)", method)
    elif rng is not None and not (rng[0] <= d <= rng[1]):
        rec = not_found(seg, f"disparity out of range ({d:.2f} px not in {rng[0]:.1f}-{rng[1]:.1f} px "
                             f"= working range {params.working_range_cm} cm)", method)
    else:
        rec = {
            "id": seg["id"], "found": True, "reason": None, "u_left_px": float(u), "v_left_px": float(v),
            "disparity_px": float(d), "sigma_disparity_px": float(max(sigma_d, params.min_sigma_disparity_px)),
            "method": method, "split": seg.get("split"), "depth_offset_cm": 0.0,
        }
        rec.update(extra)
    if not rec["found"] and ctx is not None:
        ctx.warn(f"{rec['id']}: {rec['reason']}")
    return rec


def seg_reason(seg: dict) -> str | None:
    """Why a Segmentation cannot give a disparity (it was not found), or None."""
    if not isinstance(seg, dict) or "found" not in seg:
        from stereograph.api import NodeError

        raise NodeError("disparity input is not a Segmentation record.",
                        hint="wire `segmentation` to a segmenter's `segmentation` output.")
    if not seg["found"]:
        return seg.get("reason") or "segmentation found no object"
    return None


# ------------------------------------------------------------------------------ sphere geometry
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
    others = np.delete(w, i)
    lam1, lam2 = w[i], float(np.mean(others))
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
