"""Sub-pixel refinement: outline points moved to the colour-gradient peak, a robust ellipse fit
and the region's properties.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ._blur import gaussian_blur
from ._params import SegmenterParams
from ._pixels import _channels, fast_median, structuring_element


def _color_gradient(img_bgr: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Colour gradient magnitude (sqrt of the sum over channels of |grad|^2), float32."""
    f = gaussian_blur(img_bgr, sigma)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    g2 = cv2.add(cv2.multiply(gx, gx), cv2.multiply(gy, gy))
    if g2.ndim == 3:
        g2 = cv2.transform(g2, np.ones((1, 3), np.float32))
    return cv2.sqrt(g2)


def refine_contour(
    img_bgr: np.ndarray, mask: np.ndarray, search_px: float = 3.0, contour: np.ndarray | None = None
) -> np.ndarray | None:
    """Sub-pixel outline of the (single) region in ``mask``.

    Each boundary pixel is moved along the outward normal of the contour to the maximum
    of the colour-gradient magnitude within +-``search_px`` (parabolic interpolation of the
    peak). Anti-aliased edges put that maximum on the true outline; points without a clear
    peak are dropped.

    Parameters
    ----------
    img_bgr : uint8 HxWx3 (or HxW)
    mask : uint8 HxW, 0/255, one region
    search_px : float
        Half length of the search along the normal (px).
    contour : Nx1x2 int array, optional
        The region's outer contour if already known (saves a findContours).

    Returns
    -------
    float32 Nx2 array of (u, v) points in ``img_bgr`` coordinates, or None if too few points.
    """
    if contour is None:
        cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not cnts:
            return None
        contour = max(cnts, key=len)
    c = contour.reshape(-1, 2).astype(np.float32)
    if len(c) < 12:
        return None
    c, n, (cx0, cy0, cx1, cy1) = _outward_normals(c, contour)
    # The gradient is needed only along the outline: crop to it. Samples lie within
    # search_px + 1 px of the outline and the blur and Sobel reach 4 px, so a margin of
    # search_px + 6 px gives the values of the whole image's gradient.
    hh, ww = img_bgr.shape[:2]
    m = int(math.ceil(search_px)) + 6
    x0, y0 = max(0, cx0 - m), max(0, cy0 - m)
    x1, y1 = min(ww, cx1 + m + 1), min(hh, cy1 + m + 1)
    grad = _color_gradient(img_bgr[y0:y1, x0:x1])
    step = 0.25
    t = np.arange(-search_px, search_px + step / 2, step, dtype=np.float32)
    mx = (c[:, 0:1] - x0 + n[:, 0:1] * t[None, :]).astype(np.float32, copy=False)
    my = (c[:, 1:2] - y0 + n[:, 1:2] * t[None, :]).astype(np.float32, copy=False)
    prof = cv2.remap(grad, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    k = prof.argmax(axis=1)
    inner = (k > 0) & (k < len(t) - 1)
    peak = prof.max(axis=1)  # = the profile at k
    inner &= peak > 0.25 * fast_median(peak)
    k = np.minimum(np.maximum(k, 1), len(t) - 2)
    flat = prof.reshape(-1)
    at = np.arange(0, flat.size, len(t)) + k  # flat index of (row, k)
    y0, y1, y2 = flat[at - 1], flat[at], flat[at + 1]
    den = y0 - 2 * y1 + y2
    off = np.where(np.abs(den) > 1e-9, 0.5 * (y0 - y2) / np.where(den == 0, 1, den), 0.0)
    tt = t[k] + np.clip(off, -0.5, 0.5) * step
    pts = c + n * tt[:, None]
    pts = pts[inner]
    if len(pts) < 12:
        return None
    return pts.astype(np.float32)


def _outward_normals(
    c: np.ndarray, contour: np.ndarray
) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int]]:
    """``(points, unit outward normals, bounds (x0, y0, x1, y1) of the points)`` of a closed
    outline ``c`` (Nx2 float32; ``contour`` its int form); points with no normal are dropped."""
    # Normals from the contour's tangent over +-3 points (smooths the pixel staircase),
    # oriented away from the region's centre.
    cc = np.concatenate((c[-3:], c, c[:3]))  # wrap around the closed outline
    t = cc[6:] - cc[:-6]  # c[i + 3] - c[i - 3]
    n = t[:, ::-1] * np.float32([1.0, -1.0])  # (t_y, -t_x)
    # Outward when sum((c - mean) . n) > 0; that sum is 2 sum(x_i y_i+3 - x_i+3 y_i), a
    # lagged shoelace area, cheaper as two dot products.
    c64, c3 = c.astype(np.float64), cc[6:].astype(np.float64)
    if float(c64[:, 0] @ c3[:, 1] - c3[:, 0] @ c64[:, 1]) < 0:
        n = -n
    norm = np.sqrt((n * n).sum(axis=1, keepdims=True))
    good = norm[:, 0] > 1e-6
    if good.all():  # the usual case: no copies, and the outline's bounds are its bounding box
        n = n / norm
        bx, by, bw, bh = cv2.boundingRect(contour)
        cx0, cy0, cx1, cy1 = bx, by, bx + bw - 1, by + bh - 1
    else:
        c, n = c[good], n[good] / norm[good]
        cx0, cy0, cx1, cy1 = (
            int(c[:, 0].min()),
            int(c[:, 1].min()),
            int(c[:, 0].max()),
            int(c[:, 1].max()),
        )
    return c, n, (cx0, cy0, cx1, cy1)


def fit_ellipse_robust(pts: np.ndarray) -> dict | None:
    """Ellipse through sub-pixel outline points, trimming outliers (occlusion, shadow specks).

    Returns ``{"center_px": [u, v], "axes_px": [a, b], "angle_deg": float, "rms_px": float}``
    with a >= b the semi-axes (px); ``angle_deg`` is OpenCV's angle of the first axis.
    """
    if pts is None or len(pts) < 6:
        return None
    keep = None  # None: all points (saves the copies of the first, usually the only, pass)
    refit = True
    for _ in range(3):
        (cu, cv_), (w, h), ang = cv2.fitEllipse(pts if keep is None else pts[keep])
        if w <= 0 or h <= 0:
            return None
        # Approximate geometric distance: scale the algebraic residual by the local radius.
        th = math.radians(ang)
        ct, st = math.cos(th), math.sin(th)
        du, dv = pts[:, 0] - cu, pts[:, 1] - cv_
        x = du * ct + dv * st
        y = -du * st + dv * ct
        rr = np.sqrt((x / (w / 2)) ** 2 + (y / (h / 2)) ** 2)
        res = (rr - 1.0) * 0.5 * (w + h) / 2
        ares = np.abs(res)
        mad = fast_median(ares if keep is None else ares[keep]) * 1.4826 + 1e-3
        new = ares <= max(3.0 * mad, 0.3)
        n_new = int(np.count_nonzero(new))
        if n_new < 6 or (n_new == len(pts) if keep is None else (new == keep).all()):
            refit = False  # converged (or too few inliers): the last fit used ``keep``
            break
        keep = new
    if refit:
        (cu, cv_), (w, h), ang = cv2.fitEllipse(pts[keep])
    if keep is None:
        rms, n_in = float(np.sqrt(np.mean(res**2))), len(pts)
    else:
        rms, n_in = float(np.sqrt(np.mean(res[keep] ** 2))), int(keep.sum())
    a, b = max(w, h) / 2, min(w, h) / 2
    if h > w:  # report the angle of the major axis
        ang = (ang + 90.0) % 180.0
    return {
        "center_px": [float(cu), float(cv_)],
        "axes_px": [float(a), float(b)],
        "angle_deg": float(ang),
        "rms_px": rms,
        "inliers": n_in,
    }


def region_properties(
    img_bgr: np.ndarray,
    mask: np.ndarray,
    offset: tuple[int, int],
    image_size: tuple[int, int],
    params: SegmenterParams,
    contour: np.ndarray | None = None,
    search_extra_px: float = 0.0,
) -> dict:
    """Region dict (see docs/artifacts.md) of the single region in ``mask`` (ROI coordinates).

    ``offset`` = (u0, v0) of the ROI in the image; ``image_size`` = (w, h) of the full image.
    With ``params.subpixel`` the centroid and area come from the polygon moments of the
    sub-pixel outline (Green's theorem), otherwise from the pixel moments.
    """
    u0, v0 = offset
    w, h = image_size
    area = float(cv2.countNonZero(mask))  # the pixel moments' m00; their centroid only when needed
    if contour is None:
        cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        contour = max(cnts, key=len)
    x, y, bw, bh = cv2.boundingRect(contour)
    bbox = [x + u0, y + v0, x + bw - 1 + u0, y + bh - 1 + v0]
    touches = bbox[0] <= 0 or bbox[1] <= 0 or bbox[2] >= w - 1 or bbox[3] >= h - 1
    if not touches:
        # A rectified image has a black (exactly 0) fill outside the camera's field of view:
        # a region next to it is cut by the view's border just as by the frame's. (Most windows
        # have no black pixel at all: then the ring around the region need not be drawn.)
        # every channel 0
        black = cv2.inRange(img_bgr, (0,) * _channels(img_bgr), (0,) * _channels(img_bgr))
        if cv2.countNonZero(black) >= 3:
            ring = cv2.subtract(cv2.dilate(mask, structuring_element(5)), mask)
            touches = cv2.countNonZero(cv2.bitwise_and(ring, black)) >= 3
    pts = (
        refine_contour(img_bgr, mask, params.edge_search_px + search_extra_px, contour)
        if params.subpixel
        else None
    )
    sigma_c = None
    method = "pixels"
    if pts is not None:
        pm = cv2.moments(pts)
        if pm["m00"] > 0.5 * area:
            area, cu, cv_ = float(pm["m00"]), pm["m10"] / pm["m00"], pm["m01"] / pm["m00"]
            method = "subpixel_contour"
    else:
        pts = contour.reshape(-1, 2).astype(np.float32)
    if method == "pixels":
        m = cv2.moments(mask, binaryImage=True)
        cu, cv_ = m["m10"] / m["m00"], m["m01"] / m["m00"]
    ell = fit_ellipse_robust(pts)
    if ell is not None:
        ell["center_px"] = [ell["center_px"][0] + u0, ell["center_px"][1] + v0]
        # Centroid noise: outline noise (rms) averaged over the points, sqrt(2/N) per coordinate.
        sigma_c = ell["rms_px"] * math.sqrt(2.0 / max(ell["inliers"], 1))
    contour = pts + np.float32([u0, v0])
    return {
        "area_px": float(area),
        "centroid_px": [float(cu + u0), float(cv_ + v0)],
        "bbox": bbox,
        "ellipse": ell,
        "touches_border": bool(touches),
        "contour_px": contour.astype(np.float64),
        "centroid_method": method,
        "sigma_centroid_px": sigma_c,
    }
