"""The fallback pass of a segmenter when no whole, round ball was found in a view (issue 15).

:func:`partial_region` looks again, at the regular detection level, for regions that could hold
part of a ball -- cut by the image border, partly hidden, or merged with an object it touches --
and keeps one only if the sphere's image fitted to its true outline edge (:mod:`._partial`)
is a ball: a plausible radius, a region that fills the fitted disc, the object's colour (when
given), and no second ball of similar size merged with it. Whether the visible arc constrains
the location well enough is decided per pair in ``check_pair`` (from the fit's uncertainty).

The image is padded with black (the rectified image's "no data" value) before the mask
function runs, so an outline that the image border cuts open is closed by the border and
filled like any other, whatever the segmenter; border points are then left out of the fit.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from nodes.contracts.cv_overloads import scalar_op, stop_signals_held

from ._candidates import candidates
from ._color import color_distance_map, hue_mask, object_color_score
from ._partial import fit_partial
from ._pixels import fill_holes, max_hole_area, structuring_element
from ._shadow import suppress_shadow, without_shadows
from ._subpixel import refine_contour

_MAX_TRIED = 4  # candidate regions refined at full resolution, largest first


def _pad(img: np.ndarray, sides: tuple[int, int, int, int]) -> np.ndarray:
    top, bottom, left, right = sides
    return cv2.copyMakeBorder(img, top, bottom, left, right, cv2.BORDER_CONSTANT, value=(0, 0, 0))


def partial_region(
    view,
    mask_fn,
    params,
    r_range_px,
    s: int,
    K: np.ndarray,
    window: tuple[int, int, int, int] | None = None,
) -> tuple[np.ndarray | None, dict | None, str]:
    """(full-resolution bool mask, region, reason) of a partly visible ball in ``view``, or (None,
    None, reason)."""
    h, w = view.shape[:2]
    small = view.coarse(s, 0, 0, w, h)
    sx, sy = w / small.shape[1], h / small.shape[0]
    r_small = (r_range_px[0] / s, r_range_px[1] / s)
    p = int(math.ceil(0.4 * r_small[0])) + 4
    m = mask_fn(_pad(small, (p, p, p, p)), params, r_small, s, False)[p:-p, p:-p]
    m = np.ascontiguousarray(m)
    m = without_shadows(small, m, params, r_small)
    a_min, a_max = math.pi * r_small[0] ** 2, math.pi * r_small[1] ** 2
    # A ball 40 % visible at the far end, up to one merged with an object twice its size.
    cands = [c for c in candidates(m, min_area_px=0.25 * a_min) if c["area_px"] <= 3.0 * a_max]
    if window is not None:
        u0, v0, u1, v1 = window
        cands = [
            c
            for c in cands
            if c["bbox"][0] * sx <= u1
            and c["bbox"][2] * sx >= u0
            and c["bbox"][1] * sy <= v1
            and c["bbox"][3] * sy >= v0
        ]
    if not cands:
        return None, None, "no region that could hold part of a ball"
    cands.sort(key=lambda c: -c["area_px"])
    reasons, balls = [], []
    for cand in cands[:_MAX_TRIED]:
        out = _refine(view, mask_fn, params, r_range_px, s, K, cand, sx, sy)
        if out[1] is not None:
            balls.append(out)
        else:
            reasons.append(out[2])
    if len(balls) > 1:
        # Two regions each hold a ball's image (of the object's colour when given): which one?
        r0, r1 = (b[1]["partial"]["radius_px"] for b in balls[:2])
        if min(r0, r1) >= math.sqrt(params.ambiguity_ratio) * max(r0, r1):
            return (
                None,
                None,
                (
                    "ambiguous: 2 partly visible round objects of similar size"
                    + ("" if params.object.color_bgr is not None else "; give object.color_bgr")
                ),
            )
    if balls:
        return balls[0]
    return None, None, reasons[0]


def _refine(view, mask_fn, params, r_range_px, s, K, cand, sx, sy):
    h, w = view.shape[:2]
    x0, y0, x1, y1 = cand["bbox"]
    pad = int(math.ceil(0.6 * r_range_px[1] + 2 * s + params.edge_search_px + 4))
    u0, v0 = max(0, int(x0 * sx) - pad), max(0, int(y0 * sy) - pad)
    u1, v1 = min(w, int((x1 + 1) * sx) + pad), min(h, int((y1 + 1) * sy) + pad)
    roi = view.window(u0, v0, u1, v1)
    # Black only where the window meets the image border: elsewhere the window's edge is table.
    b = int(math.ceil(0.4 * r_range_px[0])) + 4
    sides = (b if v0 == 0 else 0, b if v1 == h else 0, b if u0 == 0 else 0, b if u1 == w else 0)
    rm = mask_fn(_pad(roi, sides), params, r_range_px, 1, True)
    rm = np.ascontiguousarray(
        rm[sides[0] : rm.shape[0] - sides[1], sides[2] : rm.shape[1] - sides[3]]
    )
    if params.shadow.enabled:
        rm = suppress_shadow(roi, rm, params.shadow, params.object)
    rm = _split_by_colour(roi, rm, params, r_range_px)
    cnts, _ = cv2.findContours(rm, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    centre = (float(cand["centroid_px"][0] * sx - u0), float(cand["centroid_px"][1] * sy - v0))
    cnts = [c for c in cnts if len(c) >= 12]
    if not cnts:
        return None, None, "region vanished at full resolution"
    inside = [c for c in cnts if cv2.pointPolygonTest(c, centre, False) >= 0]
    chosen = max(inside or cnts, key=cv2.contourArea)
    region_mask = np.zeros(rm.shape, np.uint8)
    cv2.drawContours(region_mask, [chosen], -1, 255, cv2.FILLED)
    pts = (
        refine_contour(roi, region_mask, params.edge_search_px, chosen) if params.subpixel else None
    )
    if pts is None:
        pts = chosen.reshape(-1, 2).astype(np.float32)
    pts = pts.astype(np.float64) + [u0, v0]
    return judge(
        view,
        params,
        r_range_px,
        K,
        roi,
        (u0, v0, u1, v1),
        region_mask,
        pts,
        float(cand["roundness"]),
    )


def _split_by_colour(roi: np.ndarray, rm: np.ndarray, params, r_range_px) -> np.ndarray:
    """With the object's colour given, keep only the mask's pixels of that colour (+ a 1 px rim for
    the anti-aliased edge): a ball merged with an object it touches comes apart along their colour
    edge, which is then true silhouette edge for the fit instead of a lost stretch of outline."""
    obj = params.object
    if roi.ndim != 3 or (obj.color_bgr is None and obj.hue_range_deg is None):
        return rm
    if obj.color_bgr is not None:
        col = scalar_op(
            cv2.compare, color_distance_map(roi, obj.color_bgr), obj.color_tolerance, cv2.CMP_LE
        )
    else:
        col = hue_mask(roi, obj.hue_range_deg, obj.min_saturation)
    col = fill_holes(col, max_hole_area(r_range_px))
    col = cv2.morphologyEx(
        col, cv2.MORPH_OPEN, structuring_element(int(max(3.0, 0.2 * r_range_px[0])) | 1)
    )
    col = cv2.dilate(col, structuring_element(3))
    split = cv2.bitwise_and(rm, col)
    # Only when the colour leaves a ball-sized part (a dark rim or a dim view may fail the test).
    if cv2.countNonZero(split) < 0.25 * math.pi * r_range_px[0] ** 2:
        return rm
    return split


def refit_region(view, params, r_range_px, K, mask: np.ndarray, region: dict):
    """A whole-ball region whose outline is not all true edge (it touches the border, or many
    outline points are off its ellipse): the sphere's image fitted to its true edge instead.
    Same return as :func:`partial_region`."""
    h, w = view.shape[:2]
    x0, y0, x1, y1 = region["bbox"]
    m = int(math.ceil(params.edge_search_px)) + 8
    u0, v0, u1, v1 = max(0, x0 - m), max(0, y0 - m), min(w, x1 + m + 1), min(h, y1 + m + 1)
    roi = view.window(u0, v0, u1, v1)
    region_mask = mask[v0:v1, u0:u1].astype(np.uint8) * 255
    pts = np.asarray(region["contour_px"], np.float64)
    return judge(
        view,
        params,
        r_range_px,
        K,
        roi,
        (u0, v0, u1, v1),
        region_mask,
        pts,
        float(region.get("roundness", 1.0)),
    )


def _filled_ellipse(shape: tuple[int, ...], ell: dict, origin_px: tuple[int, int]) -> np.ndarray:
    """A uint8 mask of ``shape`` with the fitted ellipse ``ell`` filled (255), its centre taken
    relative to ``origin_px`` (u, v)."""
    mask = np.zeros(shape, np.uint8)
    box = (
        (ell["center_px"][0] - origin_px[0], ell["center_px"][1] - origin_px[1]),
        (2 * ell["axes_px"][0], 2 * ell["axes_px"][1]),
        ell["angle_deg"],
    )
    # (a rotated box: ellipse's second overload, sub-pixel, so held: see cv_overloads)
    with stop_signals_held():
        cv2.ellipse(mask, box, 255, cv2.FILLED)
    return mask


def judge(view, params, r_range_px, K, roi, box, region_mask, pts, roundness):
    """Fit the sphere's image to the true edge among ``pts`` and keep it only if it is the ball."""
    h, w = view.shape[:2]
    u0, v0, u1, v1 = box
    rm = region_mask
    fit = fit_partial(pts, roi, (u0, v0), (w, h), K, r_range_px)
    if not fit["ok"]:
        return None, None, fit["reason"]
    ell = fit["ellipse"]
    # The fitted disc, clipped to the window (and so to the image).
    disc = _filled_ellipse(rm.shape, ell, (u0, v0))
    n_disc = cv2.countNonZero(disc)
    both = cv2.bitwise_and(disc, region_mask)
    if n_disc == 0 or cv2.countNonZero(both) < params.partial.min_disc_coverage * n_disc:
        return (
            None,
            None,
            "the arc fitted to the region's outline is not filled by the region (not a ball)",
        )
    score = None
    if params.object.color_bgr is not None or params.object.hue_range_deg is not None:
        score = object_color_score(roi, both, params.object)
        if score is None or score > 1.0:
            return None, None, "the round part of the region has another colour than the object"
    if fit["second"] >= params.partial.ambiguous_second_arc and _second_ball(
        fit, roi, rm.shape, disc, (u0, v0), score, params
    ):
        return (
            None,
            None,
            (
                "ambiguous: 2 round objects of similar size "
                + ("and colour " if score is not None else "")
                + "merged in one region"
            ),
        )
    full = np.zeros((h, w), bool)
    full[v0:v1, u0:u1] = both > 0
    region = _partial_region(ell, fit, roundness)
    return full, region, ""


def _partial_region(ell: dict, fit: dict, roundness: float) -> dict:
    """The region of a partly seen ball, from the sphere's image fitted to its true edge."""
    a, bax = ell["axes_px"]
    cu, cv_ = ell["center_px"]
    return {
        "area_px": float(math.pi * a * bax),
        # the full silhouette's (an ellipse's centroid is its centre)
        "centroid_px": [float(cu), float(cv_)],
        "bbox": [
            int(math.floor(cu - a)),
            int(math.floor(cv_ - a)),
            int(math.ceil(cu + a)),
            int(math.ceil(cv_ + a)),
        ],
        "ellipse": ell,
        "touches_border": False,
        "contour_px": fit["true_edge_px"].astype(np.float64),
        "centroid_method": "partial_sphere_fit",
        "sigma_centroid_px": float(fit["sigma_u_px"]),
        "roundness": roundness,
        "partial": {
            "outline_visible": float(fit["outline_visible"]),
            "cause": fit["cause"],
            "sigma_u_px": float(fit["sigma_u_px"]),
            "radius_px": float(fit["radius_px"]),
            "sigma_size_rel": float(fit["sigma_size_rel"]),
        },
    }


def _second_ball(fit: dict, roi, shape, disc, origin, score, params) -> bool:
    """Whether the second arc the fit found is another ball like this one: with a colour to
    compare, only if its own disc (less the first one's) has the object's colour too."""
    if score is None or fit.get("second_ellipse") is None:
        return True
    d2 = _filled_ellipse(shape, fit["second_ellipse"], origin)
    d2 = cv2.bitwise_and(d2, cv2.bitwise_not(disc))
    s2 = object_color_score(roi, d2, params.object) if cv2.countNonZero(d2) else None
    return s2 is not None and s2 <= 1.0
