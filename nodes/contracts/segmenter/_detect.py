"""Per-image detection: coarse-first search on a downscaled copy, the epipolar search band and
the full-resolution refinement of the chosen region.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from nodes.contracts.views import RectifiedView

from ._candidates import candidates, select_candidate
from ._params import MaskFunction, SegmenterParams
from ._shadow import suppress_shadow, without_shadows
from ._size import auto_downscale
from ._subpixel import region_properties


def disparity_bounds(rectification: dict, params: SegmenterParams) -> tuple[float, float, float]:
    """(d_min, d_max, dcx) px: the disparities f B / z over the working range with 25 % slack, and
    the principal points' offset cx_left - cx_right that a measured u_left - u_right also holds."""
    fb = float(rectification["f_px"]) * abs(float(rectification["baseline_cm"]))
    cx = float(rectification.get("cx_px", 0.0))
    z0, z1 = sorted(params.working_range_cm)
    return fb / (1.25 * z1), fb / (0.75 * z0), cx - float(rectification.get("cx_right_px", cx))


def search_band(
    region: dict, rectification: dict | None, params: SegmenterParams, image_size: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """Window (u0, v0, u1, v1) of the right rectified image where the left ``region`` can appear.

    Rectified views share rows, so the right region lies on the left region's rows (+ the row
    tolerance and a size difference), shifted left by a disparity between f B / z_far and
    f B / z_near (+ the principal points' offset) over the working range with 25 % slack.
    The object's known radius R narrows that further: a sphere whose silhouette has the
    minor semi-axis b (px) is at z ~ f R / b, so d ~ B b / R; the band keeps d within a
    factor 1.4 of that (occlusion or a wrong radius only cost the whole-image fallback).
    Searching only there (the epipolar band) is cheaper than the whole image and cannot pick
    a look-alike elsewhere. None without a calibration (f_px, baseline_cm).
    """
    if (
        rectification is None
        or not rectification.get("f_px")
        or not rectification.get("baseline_cm")
    ):
        return None
    # d = f B / z + (cx_left - cx_right)
    d_min, d_max, dcx = disparity_bounds(rectification, params)
    ell = region.get("ellipse")
    b_px = float(ell["axes_px"][1]) if ell else math.sqrt(max(region["area_px"], 1.0) / math.pi)
    if b_px > 1.0:
        d_size = abs(float(rectification["baseline_cm"])) * b_px / params.object.radius_cm
        lo, hi = max(d_min, d_size / 1.4), min(d_max, d_size * 1.4)
        if lo <= hi:  # else the size says "outside the working range": keep the range's band
            d_min, d_max = lo, hi
    d_min, d_max = d_min + dcx, d_max + dcx
    x0, y0, x1, y1 = region["bbox"]
    r = 0.5 * max(x1 - x0 + 1, y1 - y0 + 1)
    # Margins: the right outline may be larger (area ratio limit) and the detection's filters
    # differ within a few coarse pixels of the window's edge.
    pad_v = params.max_row_offset_px + 0.5 * r + 32
    pad_u = 0.5 * r + 32
    w, h = image_size
    u0, u1 = max(0, int(x0 - d_max - pad_u)), min(w, int(math.ceil(x1 - d_min + pad_u)) + 1)
    v0, v1 = max(0, int(y0 - pad_v)), min(h, int(math.ceil(y1 + pad_v)) + 1)
    if u1 - u0 < 2 * r or v1 - v0 < 2 * r:
        return None
    return u0, v0, u1, v1


def _detect(
    view: RectifiedView,
    mask_fn: MaskFunction,
    params: SegmenterParams,
    r_range_px: tuple[float, float],
    s: int,
    window: tuple[int, int, int, int] | None,
    min_radius_px: float = 0.0,
    rejected: dict | None = None,
) -> tuple[dict | None, str | None, tuple[float, float, int, int]]:
    """Coarse detection: the chosen candidate (coarse coordinates), the reason, and
    (sx, sy, u_off, v_off) mapping coarse to full-resolution pixels. ``min_radius_px``
    (coarse px) raises the smallest plausible radius at this level. ``rejected``, optional:
    filled with the outlines of the candidates that lost (:func:`rejected_outlines`)."""
    h, w = view.shape[:2]
    if window is None:
        wu0, wv0, wu1, wv1 = 0, 0, w, h
    else:
        # Align the window to the pyramid's grid so that its coarse pixels are the image's.
        wu0, wv0 = window[0] // s * s, window[1] // s * s
        wu1, wv1 = min(w, -(-window[2] // s) * s), min(h, -(-window[3] // s) * s)
    small = view.coarse(s, wu0, wv0, wu1, wv1)
    sx, sy = (wu1 - wu0) / small.shape[1], (wv1 - wv0) / small.shape[0]
    r_small = (max(r_range_px[0] / s, min_radius_px), r_range_px[1] / s)
    m = mask_fn(small, params, r_small, s, False)
    m = without_shadows(small, m, params, r_small)
    cands = candidates(m, min_area_px=max(4.0, 0.5 * math.pi * r_small[0] ** 2))
    if window is not None:
        # A region cut by the window's edge (inside the image) is not the object, which lies
        # inside the window by construction.
        sh, sw = m.shape
        cands = [
            c
            for c in cands
            if not (
                (c["bbox"][0] <= 0 < wu0)
                or (c["bbox"][1] <= 0 < wv0)
                or (c["bbox"][2] >= sw - 1 and wu1 < w)
                or (c["bbox"][3] >= sh - 1 and wv1 < h)
            )
        ]
    best, reason = select_candidate(cands, small, r_small, params)
    if rejected is not None:
        rejected.clear()
        rejected.update(rejected_outlines(cands, best, (sx, sy, wu0, wv0)))
    return best, reason, (sx, sy, wu0, wv0)


# Rejected outlines kept per image for the overlays: few and small, so that they cost nothing
# next to the detection and stay small in the Segmentation.
MAX_REJECTED = 8  # outlines per image
MAX_REJECTED_POINTS = 64  # points per outline
_REJECTED_ORDER = {"ambiguous": 0, "colour": 1, "smaller": 2, "round": 3, "size": 4}


def rejected_outlines(
    cands: list[dict], best: dict | None, to_full: tuple[float, float, int, int]
) -> dict:
    """``{"px": [Nx2 int32], "why": [str]}``: the outlines (full-resolution rectified px, at most
    ``MAX_REJECTED`` of ``MAX_REJECTED_POINTS`` points) of the candidates other than ``best``, the
    most telling first (ambiguous, wrong colour, smaller, not round, wrong size; then larger
    first)."""
    sx, sy, ou, ov = to_full
    lost = [c for c in cands if c is not best]
    lost.sort(key=lambda c: (_REJECTED_ORDER.get(c.get("rejected", "smaller"), 5), -c["area_px"]))
    px, why = [], []
    for c in lost[:MAX_REJECTED]:
        pts = c["contour"].reshape(-1, 2)
        pts = pts[:: -(-len(pts) // MAX_REJECTED_POINTS)]
        # A coarse pixel centre i sits at full-resolution (i + 0.5) s - 0.5.
        full = (pts + 0.5) * (sx, sy) - 0.5 + (ou, ov)
        px.append(np.round(full).astype(np.int32))
        why.append(c.get("rejected", "smaller"))
    return {"px": px, "why": why}


# A whole ball's outline is all true edge and fills its ellipse (area within the sub-pixel
# outline's ~0.5 % precision); below these the outline holds foreign edges: refit (_partial_pass).
_MIN_TRUE_EDGE = 0.9  # share of outline points on the robust ellipse
_MIN_FILL = 0.97  # region area / ellipse area
_MAX_EDGE_RMS_PX = 0.5  # a sub-pixel outline of one ellipse scatters by a few tenths of a px
# (A refit of a whole outline gives the same ball, so these triggers err on the liberal side:
# they cost time, not accuracy.)
_MIN_RADIUS_COARSE_PX = 4.0  # smallest ball radius a coarse-first pass trusts (px at its level)


def _drop_inside(rejected: dict, mask: np.ndarray) -> None:
    """Remove from ``rejected`` the outlines whose mean point lies in ``mask`` (the found
    region)."""
    h, w = mask.shape
    keep = []
    for i, c in enumerate(rejected["px"]):
        u, v = (int(round(x)) for x in c.mean(axis=0))
        if not (0 <= u < w and 0 <= v < h and mask[v, u]):
            keep.append(i)
    rejected["px"] = [rejected["px"][i] for i in keep]
    rejected["why"] = [rejected["why"][i] for i in keep]


def segment_image(
    img_bgr: np.ndarray | RectifiedView,
    mask_fn: MaskFunction,
    params: SegmenterParams,
    r_range_px: tuple[float, float],
    window: tuple[int, int, int, int] | None = None,
    K: np.ndarray | None = None,
    rejected: dict | None = None,
    only_window: bool = False,
) -> tuple[np.ndarray, dict | None, str | None]:
    """Find the object in one rectified image.

    ``img_bgr`` is the rectified image or a :class:`RectifiedView` (a raw image rectified on
    request: only the coarse level and the object's window are remapped). ``window``
    (u0, v0, u1, v1), optional: detect only there (see :func:`search_band`); if nothing is
    found there, the whole image is searched (so reasons are the whole image's). ``K`` (the
    view's rectified camera matrix), optional: when no whole ball is found, look for a partly
    visible or touching one (:mod:`._partial_pass`; the region then has a ``partial`` entry).
    ``rejected`` (a dict), optional: filled with the outlines and one-word reasons of the
    candidates that lost in the detection pass that decided (``{"px": [...], "why": [...]}``,
    see :func:`rejected_outlines`). ``only_window``: never fall back to the whole image (one of
    several objects, each in its own window).

    Returns
    -------
    mask : bool HxW (the chosen region; all False if none)
    region : dict or None
    reason : str or None (why nothing was found)
    """
    view = img_bgr if isinstance(img_bgr, RectifiedView) else RectifiedView(img_bgr)
    h, w = view.shape[:2]
    s = auto_downscale(r_range_px[0], params.detect_downscale)
    best = None
    for level, where, r_floor in _detection_passes(params, r_range_px, s, window, only_window):
        best, why, (sx, sy, ou, ov) = _detect(
            view, mask_fn, params, r_range_px, level, where, r_floor, rejected
        )
        if r_floor == 0.0:
            reason = why
        if best is not None:
            s = level
            break
    full_mask = np.zeros((h, w), bool)
    if best is None:
        if K is not None and params.partial.enabled and not (reason or "").startswith("ambiguous"):
            return _partial_view(view, mask_fn, params, r_range_px, s, K, window, rejected, reason)
        return full_mask, None, reason
    u0, v0, u1, v1 = _window_around(best, s, (sx, sy, ou, ov), (w, h), params)
    roi = view.window(u0, v0, u1, v1)
    rm = mask_fn(roi, params, r_range_px, 1, True)
    if params.shadow.enabled:
        rm = suppress_shadow(roi, rm, params.shadow, params.object)
    chosen, inside = _full_resolution_outline(rm, best, (sx, sy, ou, ov), (u0, v0))
    if chosen is None:
        return full_mask, None, "region vanished at full resolution"
    region_mask = np.zeros(rm.shape, np.uint8)
    cv2.drawContours(region_mask, [chosen], -1, 255, cv2.FILLED)
    region = region_properties(
        roi,
        region_mask,
        (u0, v0),
        (w, h),
        params,
        contour=chosen,
        search_extra_px=0.0 if inside else float(s),
    )
    region["roundness"] = float(best["roundness"])
    full_mask[v0:v1, u0:u1] = region_mask > 0
    if K is not None and params.partial.enabled and _not_all_ball(region):
        # Part of the outline is not the ball's (the frame, an occluder, a touching object).
        from ._partial_pass import refit_region

        pmask, pregion, pwhy = refit_region(view, params, r_range_px, K, full_mask, region)
        if pregion is None:
            return np.zeros((h, w), bool), None, f"partial view: {pwhy}"
        return pmask, pregion, None
    return full_mask, region, None


def _partial_view(view, mask_fn, params, r_range_px, s, K, window, rejected, reason):
    """No whole ball found: :func:`segment_image`'s answer from the partial-view pass (a ball
    cut by the border, hidden in part or touching something), or why there is none."""
    from ._partial_pass import partial_region  # the fallback imports this module

    pmask, pregion, pwhy = partial_region(view, mask_fn, params, r_range_px, s, K, window)
    if pregion is not None:
        # the partial pass found the ball in a region the coarse pass had turned down
        if rejected:
            _drop_inside(rejected, pmask)
        return pmask, pregion, None
    h, w = view.shape[:2]
    return np.zeros((h, w), bool), None, f"{reason}; partial view: {pwhy}"


def _window_around(
    best: dict, s: int, level: tuple[float, float, int, int], size: tuple[int, int], params
) -> tuple[int, int, int, int]:
    """The full-resolution region of interest ``(u0, v0, u1, v1)`` around the coarse candidate
    ``best`` (``level``: its scale and offset, as :func:`_detect` gives them), padded for the
    outline's refinement."""
    sx, sy, ou, ov = level
    w, h = size
    x0, y0, x1, y1 = best["bbox"]
    r_est = 0.5 * max(x1 - x0 + 1, y1 - y0 + 1) * s
    pad = int(math.ceil(0.35 * r_est + 2 * s + params.edge_search_px + 4))
    u0, v0 = max(0, ou + int(x0 * sx) - pad), max(0, ov + int(y0 * sy) - pad)
    u1, v1 = min(w, ou + int((x1 + 1) * sx) + pad), min(h, ov + int((y1 + 1) * sy) + pad)
    return u0, v0, u1, v1


def _detection_passes(
    params: SegmenterParams,
    r_range_px: tuple[float, float],
    s: int,
    window: tuple[int, int, int, int] | None,
    only_window: bool,
) -> list[tuple[int, tuple[int, int, int, int] | None, float]]:
    """The detection passes, in order: ``(level, where, smallest plausible radius there)``.

    The optional first pass at twice the downscale ``s`` is ~4x cheaper; it only accepts balls of
    >= 4 px there (smaller ones, or none, fall through to the regular level, whose reasons are
    reported).
    """
    passes = []
    if (
        params.coarse_first
        and params.detect_downscale is None
        and 2 * s <= 8
        and r_range_px[1] / (2 * s) >= 2 * _MIN_RADIUS_COARSE_PX
    ):
        passes.append((2 * s, window, _MIN_RADIUS_COARSE_PX))
    if window is not None:
        passes.append((s, window, 0.0))
    if not (only_window and window is not None):
        passes.append((s, None, 0.0))
    return passes


def _full_resolution_outline(
    rm: np.ndarray,
    best: dict,
    level: tuple[float, float, int, int],
    corner: tuple[int, int],
) -> tuple[np.ndarray | None, bool]:
    """``(outline in the window, found in it)``: the window mask ``rm``'s contour around the coarse
    candidate ``best`` (``level``: its scale and offset in the image, as :func:`_detect` gives
    them; ``corner``: the window's in the image), or, when the window cut that outline open,
    ``best``'s own, scaled up; None if it vanishes."""
    sx, sy, ou, ov = level
    u0, v0 = corner
    du, dv = ou - u0, ov - v0
    cnts, _ = cv2.findContours(rm, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    # Keep the contour around the coarse candidate's centre.
    centre = (
        float(best["centroid_px"][0] * sx + ou - u0),
        float(best["centroid_px"][1] * sy + ov - v0),
    )
    inside = [c for c in cnts if cv2.pointPolygonTest(c, centre, False) >= 0]
    a_best = best["area_px"] * sx * sy
    inside = [c for c in inside if 0.5 * a_best <= cv2.contourArea(c) <= 2.0 * a_best]
    if inside:
        return max(inside, key=cv2.contourArea), True
    # The window cut the outline open (a long shadow leaving it, say): use the coarse
    # region, scaled up; the sub-pixel refinement moves it onto the true edge.
    chosen = np.round(
        (best["contour"].astype(np.float64) + 0.5) * [sx, sy] - 0.5 + [du, dv]
    ).astype(np.int32)
    chosen = cv2.approxPolyDP(chosen, 0.5, True) if len(chosen) > 4 else chosen
    # Densify to one point per pixel along the outline.
    tmp = np.zeros(rm.shape, np.uint8)
    cv2.drawContours(tmp, [chosen], -1, 255, cv2.FILLED)
    dense, _ = cv2.findContours(tmp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return (max(dense, key=cv2.contourArea) if dense else None), False


def _not_all_ball(region: dict) -> bool:
    """Part of the region's outline may not be the ball's (the frame, an occluder, a touching
    object): it touches the border, or its ellipse fits few points, loosely, or is badly filled."""
    ell = region.get("ellipse")
    n_pts = len(region["contour_px"])
    return region["touches_border"] or (
        ell is not None
        and (
            ell["inliers"] < _MIN_TRUE_EDGE * n_pts
            or ell["rms_px"] > _MAX_EDGE_RMS_PX
            or region["area_px"] < _MIN_FILL * math.pi * ell["axes_px"][0] * ell["axes_px"][1]
        )
    )
