"""The sphere's image from the part of its outline that is real (partial views, touching objects).

A ball cut by the image border, partly hidden, or merged with an object it touches still shows
part of its true silhouette edge. This module separates an outline into

* **border points** -- on the image border or next to the rectified image's black fill (the
  outline there is the frame's, not the ball's);
* **true silhouette edge** -- the points that lie on one sphere image;
* **foreign points** -- an occluder's or a touching object's edge,

and fits the sphere's image to the true edge only.

Sphere-aware fit (3 parameters, linear)
---------------------------------------
The silhouette of a sphere is the image of its tangent cone: unit rays x (camera frame, from
the rectified pixel via K^-1) on it satisfy a . x = cos(alpha), with a the unit direction of the
centre and alpha the cone's half-angle. With w = a / cos(alpha) this is the *linear* equation
w . x = 1, so three outline points give w exactly (RANSAC sample) and all inliers give it by
least squares, with the covariance sigma_r^2 (X^T X)^-1 -- a circle fit on the sphere of rays
that stays well conditioned on a short arc, where a free 5-parameter ellipse does not. From w:
the centre's image K w, cos(alpha) = 1 / |w|, the silhouette conic K^-T (w w^T - I) K^-1 (what
``disparity.ellipse`` and the checks consume), and the uncertainty of the centre's image
(propagated from the covariance). A residual r = w . x - 1 is an angular distance of
-r / tan(alpha) from the cone, i.e. f r / tan(alpha) px.

Whether the visible arc is long enough is decided from that uncertainty (``check_pair`` turns
the two views' centre uncertainties into sigma_z and compares it with the user's tolerance), not
from a fixed arc length.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

_RANSAC_ITERS = 60
# 5 degree bins for the visible share of the outline (fewer on a small silhouette)
_COVERAGE_BINS = 72
_COVERAGE_BIN_PX = 2.0  # least outline length per bin: the outline's points are 1-1.4 px apart


def rays(pts_px: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Unit camera-frame rays (N, 3) of rectified pixels (N, 2) through the camera matrix K."""
    h = np.concatenate([np.asarray(pts_px, float), np.ones((len(pts_px), 1))], axis=1)
    x = h @ np.linalg.inv(K).T
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _residual_px(w: np.ndarray, X: np.ndarray, f_px: float) -> np.ndarray:
    n2 = float(w @ w)
    if n2 <= 1.0:
        return np.full(len(X), np.inf)
    return np.abs(X @ w - 1.0) * f_px / math.sqrt(n2 - 1.0)


def ransac_cone(
    X: np.ndarray,
    f_px: float,
    r_range_px: tuple[float, float],
    thr_px: float,
    rng: np.random.Generator,
) -> np.ndarray | None:
    """Inlier mask of the best cone (sphere image) through the rays ``X`` (N, 3), or None.

    Samples are three points, all drawn and solved at once: the w with x_k . w = 1 for three
    rays is (x2 x x3 + x3 x x1 + x1 x x2) / (x1 . (x2 x x3)). A cone whose image radius
    (f tan alpha, px) is outside ``r_range_px`` is skipped; the score is the inlier count
    within ``thr_px``.
    """
    n = len(X)
    if n < 12:
        return None
    idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(_RANSAC_ITERS)])
    x1, x2, x3 = X[idx[:, 0]], X[idx[:, 1]], X[idx[:, 2]]
    c23 = np.cross(x2, x3)
    det = np.einsum("ij,ij->i", x1, c23)
    ok = np.abs(det) > 1e-12
    W = (c23 + np.cross(x3, x1) + np.cross(x1, x2))[ok] / det[ok, None]
    n2 = np.einsum("ij,ij->i", W, W)
    good = (n2 > 1.0) & (W[:, 2] > 0)
    W, n2 = W[good], n2[good]
    tan_a = np.sqrt(n2 - 1.0)
    r_px = f_px * tan_a
    keep = (r_px >= r_range_px[0]) & (r_px <= r_range_px[1])
    if not keep.any():
        return None
    W, tan_a = W[keep], tan_a[keep]
    inl = np.abs(X @ W.T - 1.0) * (f_px / tan_a)[None, :] <= thr_px  # (N, samples)
    best = int(np.argmax(inl.sum(axis=0)))
    return inl[:, best]


def fit_cone(X: np.ndarray, f_px: float, noise_floor_px: float = 0.1) -> dict:
    """Least-squares cone w . x = 1 through rays X (N, 3) with its covariance.

    ``noise_floor_px``: the residual spread is taken as at least this (px), so a handful of
    points that happen to agree does not claim a precision the edge cannot give.
    """
    w, *_ = np.linalg.lstsq(X, np.ones(len(X)), rcond=None)
    n2 = float(w @ w)
    tan_a = math.sqrt(max(n2 - 1.0, 1e-12))
    res_px = (X @ w - 1.0) * f_px / tan_a
    s_px = max(float(np.sqrt(np.sum(res_px**2) / max(len(X) - 3, 1))), noise_floor_px)
    s_r = s_px * tan_a / f_px
    cov = s_r**2 * np.linalg.inv(X.T @ X)
    return {"w": w, "cov": cov, "rms_px": float(np.sqrt(np.mean(res_px**2))), "sigma_px": s_px}


def cone_center_px(w: np.ndarray, K: np.ndarray, cov: np.ndarray) -> tuple[list[float], float]:
    """Image of the sphere's centre (K w) and its standard deviation along u (px)."""
    p = K @ w
    u, v = p[0] / p[2], p[1] / p[2]
    J = (K[0] * p[2] - K[2] * p[0]) / p[2] ** 2  # du/dw
    return [float(u), float(v)], float(math.sqrt(max(J @ cov @ J, 0.0)))


def cone_ellipse(w: np.ndarray, K: np.ndarray) -> dict | None:
    """Silhouette ellipse (``center_px``, ``axes_px`` major first, ``angle_deg`` of the major
    axis)."""
    Kinv = np.linalg.inv(K)
    A = Kinv.T @ (np.outer(w, w) - np.eye(3)) @ Kinv
    A = -A if A[0, 0] < 0 else A
    Q = A[:2, :2]
    try:
        centre = np.linalg.solve(Q, -A[:2, 2])
    except np.linalg.LinAlgError:
        return None
    k = -(A[2, 2] + A[:2, 2] @ centre)
    ev, evec = np.linalg.eigh(Q)
    if k <= 0 or np.any(ev <= 0):
        return None
    axes = np.sqrt(k / ev)  # ascending eigenvalues -> major axis first
    ang = math.degrees(math.atan2(evec[1, 0], evec[0, 0])) % 180.0
    return {
        "center_px": [float(centre[0]), float(centre[1])],
        "axes_px": [float(axes[0]), float(axes[1])],
        "angle_deg": float(ang),
    }


def coverage(pts: np.ndarray, center: np.ndarray, radius_px: float | None = None) -> float:
    """Share (0..1) of the directions around ``center`` that the points cover.

    5 degree bins, or, on a silhouette of ``radius_px`` (its minor semi-axis) too small for that,
    bins of at least ``_COVERAGE_BIN_PX`` of outline: a pixel outline has ~1 point per px, so a
    whole ball of 6 px radius (38 points) could fill only half of 72 bins and read "42 % visible".
    """
    n_bins = _COVERAGE_BINS
    if radius_px is not None:
        n_bins = int(min(_COVERAGE_BINS, max(8, 2 * math.pi * radius_px // _COVERAGE_BIN_PX)))
    ang = np.arctan2(pts[:, 1] - center[1], pts[:, 0] - center[0])
    bins = np.floor((ang + np.pi) / (2 * np.pi) * n_bins).astype(int) % n_bins
    return float(len(np.unique(bins)) / n_bins)


def border_points(
    pts: np.ndarray,
    img: np.ndarray,
    offset: tuple[int, int],
    image_size: tuple[int, int],
    margin_px: float = 2.0,
) -> np.ndarray:
    """Mask of outline points on the image border or next to the black (invalid) fill.

    ``pts`` are image coordinates; ``img`` the window they were found in, at ``offset``.
    """
    w, h = image_size
    on = (
        (pts[:, 0] < margin_px)
        | (pts[:, 1] < margin_px)
        | (pts[:, 0] > w - 1 - margin_px)
        | (pts[:, 1] > h - 1 - margin_px)
    )
    ch = 1 if img.ndim == 2 else img.shape[2]
    black = cv2.inRange(img, (0,) * ch, (0,) * ch)
    if cv2.countNonZero(black):
        near = cv2.dilate(black, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)))
        uu = np.clip(np.round(pts[:, 0] - offset[0]).astype(int), 0, black.shape[1] - 1)
        vv = np.clip(np.round(pts[:, 1] - offset[1]).astype(int), 0, black.shape[0] - 1)
        on |= near[vv, uu] > 0
    return on


def which_border(pts: np.ndarray, image_size: tuple[int, int]) -> str:
    """'left', 'right', 'top' or 'bottom': the image border nearest to the points' mean."""
    w, h = image_size
    mu, mv = pts.mean(axis=0)
    d = {"left": mu, "right": w - 1 - mu, "top": mv, "bottom": h - 1 - mv}
    return min(d, key=d.get)


def fit_partial(
    pts: np.ndarray,
    img: np.ndarray,
    offset: tuple[int, int],
    image_size: tuple[int, int],
    K: np.ndarray,
    r_range_px: tuple[float, float],
    seed: int = 0,
) -> dict:
    """Fit the sphere's image to the true silhouette edge among outline points ``pts`` (image px).

    Returns a dict: ``ok`` (bool), ``reason`` (when not ok), and when ok ``ellipse`` (with
    ``sigma_center_px``), ``center_px`` (image of the sphere's centre), ``sigma_u_px``,
    ``radius_px`` (f tan alpha), ``outline_visible`` (share of the outline that is true edge),
    ``cause`` ("border: left" / "occluded or touching"), ``second`` (share of the remaining
    outline explained by a second sphere image of similar size, 0 if none).
    """
    f_px = float(K[0, 0])
    on_border = border_points(pts, img, offset, image_size)
    cand = pts[~on_border]
    X = rays(cand, K)
    rng = np.random.default_rng(seed)
    inl = ransac_cone(X, f_px, r_range_px, 0.6, rng)
    if inl is None or inl.sum() < 12:
        return {"ok": False, "reason": "no arc of a ball's outline found"}
    fit = fit_cone(X[inl], f_px)
    # Re-select the inliers with the refined cone and the fitted spread (3 sigma, >= 0.3 px).
    res = _residual_px(fit["w"], X, f_px)
    inl = res <= max(3.0 * fit["rms_px"], 0.3)
    if inl.sum() < 12:
        return {"ok": False, "reason": "no arc of a ball's outline found"}
    fit = fit_cone(X[inl], f_px)
    w = fit["w"]
    ell = cone_ellipse(w, K)
    if ell is None:
        return {"ok": False, "reason": "the outline's arc is not the image of a sphere"}
    centre, s_u = cone_center_px(w, K, fit["cov"])
    radius_px, s_size = _size(w, fit["cov"], f_px)
    true_pts = cand[inl]
    vis = coverage(true_pts, np.asarray(ell["center_px"]), ell["axes_px"][1])
    n_border = int(on_border.sum())
    foreign = cand[~inl]
    cause = (
        f"border: {which_border(pts[on_border], image_size)}"
        if n_border > len(foreign)
        else "occluded or touching"
    )
    second, e2 = _second_arc(foreign, K, f_px, radius_px, rng)
    ell.update(rms_px=fit["rms_px"], inliers=int(inl.sum()), sigma_center_px=s_u)
    return {
        "ok": True,
        "ellipse": ell,
        "center_px": centre,
        "sigma_u_px": s_u,
        "radius_px": radius_px,
        "sigma_size_rel": s_size,
        "outline_visible": vis,
        "cause": cause,
        "second": second,
        "n_border": n_border,
        "second_ellipse": e2,
        "n_foreign": int(len(foreign)),
        "true_edge_px": true_pts,
    }


def _size(w: np.ndarray, cov: np.ndarray, f_px: float) -> tuple[float, float]:
    """``(radius of the sphere's image, px (f tan alpha); relative sd of the distance its size
    gives)`` from the fitted cone ``w`` and its covariance."""
    n = float(np.linalg.norm(w))
    radius_px = f_px * math.sqrt(max(n * n - 1.0, 0.0))
    # Relative sd of the distance the fitted size gives: |C| = R / sin(alpha) = R n / sqrt(n^2 - 1),
    # d ln|C| / dn = -1 / (n (n^2 - 1)), with sd(n) along w / n.
    u_w = w / n
    s_size = math.sqrt(max(float(u_w @ cov @ u_w), 0.0)) / (n * max(n * n - 1.0, 1e-12))
    return radius_px, s_size


def _second_arc(foreign: np.ndarray, K: np.ndarray, f_px: float, radius_px: float, rng):
    """``(share of the rest of the outline it explains, its ellipse or None)``: a second sphere
    image of similar size in the outline points the first left over (two balls merged)."""
    second, e2 = 0.0, None
    if len(foreign) >= 12:
        Xf = rays(foreign, K)
        r2 = (0.75 * radius_px, 1.33 * radius_px)
        inl2 = ransac_cone(Xf, f_px, r2, 0.6, rng)
        if inl2 is not None and inl2.sum() >= 12:
            fit2 = fit_cone(Xf[inl2], f_px)
            e2 = cone_ellipse(fit2["w"], K)
            if e2 is not None:
                second = coverage(foreign[inl2], np.asarray(e2["center_px"]), e2["axes_px"][1])
    return second, e2
