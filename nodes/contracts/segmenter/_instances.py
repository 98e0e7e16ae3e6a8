"""Every instance of one object in a rectified pair: each whole, round ball is its own result.

1. **Candidates** in each image at the detection level: the method's mask, shadow suppression,
   components of a plausible size, roundness and colour (``_candidates``' rules, without the
   choice of one).
2. **Match** left and right: same rows, a disparity inside the working range *and* the one the
   ball's image size predicts (d ~ B r_px / R). A left candidate with exactly one partner, which
   has no other, is an instance; two that could swap partners cannot be told apart and are
   refused, as is a ball-sized region of the object's colour that is not round (touching balls
   merged into one region).
3. **Refine and check** each instance in its own window (``segment_image(only_window=True)``:
   sub-pixel outline, partial views) and check the two regions (``check_pair``).
"""

from __future__ import annotations

import math

import numpy as np

from nodes.contracts.views import RectifiedView

from ._candidates import _region, candidates
from ._checks import check_pair
from ._color import object_color_score
from ._detect import disparity_bounds, segment_image
from ._params import MaskFunction, SegmenterParams
from ._shadow import without_shadows
from ._size import auto_downscale

# the disparity may differ from the size-predicted one by this factor (off-axis, noise)
SIZE_FACTOR = 1.3


def _plausible(
    view, mask_fn: MaskFunction, params: SegmenterParams, r_range_px
) -> tuple[list[dict], list[dict]]:
    """(round candidates, refused ball-coloured regions), full-resolution coordinates."""
    h, w = view.shape[:2]
    s = auto_downscale(r_range_px[0], params.detect_downscale)
    small = view.coarse(s, 0, 0, w, h)
    sx, sy = w / small.shape[1], h / small.shape[0]
    r_small = (r_range_px[0] / s, r_range_px[1] / s)
    m = mask_fn(small, params, r_small, s, False)
    m = without_shadows(small, m, params, r_small)
    a_min, a_max = math.pi * r_small[0] ** 2, math.pi * r_small[1] ** 2
    coloured = params.object.color_bgr is not None or params.object.hue_range_deg is not None
    ok, refused = [], []
    for c in candidates(m, min_area_px=max(4.0, 0.5 * a_min)):
        score = object_color_score(*_region(small, c), params.object) if coloured else None
        if score is not None and score > 1.0:
            continue
        x0, y0, x1, y1 = c["bbox"]
        full = {
            "centroid_px": [
                (c["centroid_px"][0] + 0.5) * sx - 0.5,
                (c["centroid_px"][1] + 0.5) * sy - 0.5,
            ],
            "radius_px": math.sqrt(c["area_px"] / math.pi) * s,
            "color_score": score,
            "bbox": [
                int(x0 * sx),
                int(y0 * sy),
                int(math.ceil((x1 + 1) * sx)),
                int(math.ceil((y1 + 1) * sy)),
            ],
        }
        if a_min <= c["area_px"] <= a_max and c["roundness"] >= params.min_roundness:
            ok.append(full)
        elif coloured and a_min <= c["area_px"] <= 4.0 * a_max:
            full["reason"] = (
                f"a region of the object's colour that is not round (roundness {c['roundness']:.2f}"
                f" < {params.min_roundness}): balls touching each other or something else"
            )
            refused.append(full)
    return ok, refused


def _partners(a: dict, rights: list[dict], params: SegmenterParams, rect: dict) -> list[int]:
    """Indices of the right candidates that can be ``a``'s other view."""
    d_lo, d_hi, dcx = disparity_bounds(rect, params)
    d_size = abs(float(rect["baseline_cm"])) * a["radius_px"] / params.object.radius_cm
    out = []
    for j, b in enumerate(rights):
        d = a["centroid_px"][0] - b["centroid_px"][0] - dcx
        dv = abs(a["centroid_px"][1] - b["centroid_px"][1])
        if dv > params.max_row_offset_px + 0.25 * a["radius_px"] + 2.0 or not d_lo <= d <= d_hi:
            continue
        if d_size > 0 and not 1 / SIZE_FACTOR <= d / d_size <= SIZE_FACTOR:
            continue
        out.append(j)
    return out


def _window(c: dict, shape) -> tuple[int, int, int, int]:
    pad = int(math.ceil(0.6 * c["radius_px"] + 12))
    x0, y0, x1, y1 = c["bbox"]
    return max(0, x0 - pad), max(0, y0 - pad), min(shape[1], x1 + pad), min(shape[0], y1 + pad)


def _rows_partners(a: dict, rights: list[dict], params: SegmenterParams, rect: dict) -> list[int]:
    """Right regions that can be a not-round left region's other view: overlapping rows, a disparity
    inside the working range (its size says nothing: the region is not one whole ball)."""
    d_lo, d_hi, _ = disparity_bounds(rect, params)
    out = []
    for j, b in enumerate(rights):
        top, bottom = max(a["bbox"][1], b["bbox"][1]), min(a["bbox"][3], b["bbox"][3])
        rows = min(a["bbox"][3] - a["bbox"][1], b["bbox"][3] - b["bbox"][1])
        if (
            bottom - top >= 0.6 * rows
            and d_lo <= a["centroid_px"][0] - b["centroid_px"][0] <= d_hi * 1.2
        ):
            out.append(j)
    return out


def _left(vl, mask_fn, params, r_range_px, a, K1) -> tuple[dict | None, str | None]:
    """The left candidate ``a`` refined in its own window: (region or None, reason)."""
    _, reg, why = segment_image(
        vl, mask_fn, params, r_range_px, window=_window(a, vl.shape), K=K1, only_window=True
    )
    return reg, why


def _pair_with(left, vr, mask_fn, params, r_range_px, rect, a, b, K2) -> dict:
    """One instance from the refined left (``left``: region, reason) and a right candidate ``b``,
    refined in its own window, then checked."""
    lreg, lwhy = left
    _, rreg, rwhy = segment_image(
        vr, mask_fn, params, r_range_px, window=_window(b, vr.shape), K=K2, only_window=True
    )
    if lreg is None or rreg is None:
        why = f"left image: {lwhy}" if lreg is None else f"right image: {rwhy}"
    else:
        why = check_pair(lreg, rreg, params, rect)
    return {
        "found": why is None,
        "reason": why,
        "left": lreg,
        "right": rreg,
        "left_px": a["centroid_px"],
        "color_score": a["color_score"],
    }


def _one_ball_view(
    view, region: dict, rect: dict, params: SegmenterParams, window
) -> RectifiedView:
    """The right view with everything in ``window`` but a disc where the left ``region``'s ball must
    appear painted over with the window's border colour: the other balls of a merged region are
    gone."""
    r_px = math.sqrt(max(region["area_px"], 1.0) / math.pi)
    if region.get("partial"):
        r_px = float(region["partial"].get("radius_px") or r_px)
    dcx = disparity_bounds(rect, params)[2]
    u = (
        region["centroid_px"][0]
        - dcx
        - abs(float(rect["baseline_cm"])) * r_px / params.object.radius_cm
    )
    v = region["centroid_px"][1]
    img = np.ascontiguousarray(view.full()).copy()
    u0, v0, u1, v1 = window
    patch = img[v0:v1, u0:u1]
    border = np.concatenate([patch[0], patch[-1], patch[:, 0], patch[:, -1]])
    yy, xx = np.mgrid[v0:v1, u0:u1]
    outside = (xx - u) ** 2 + (yy - v) ** 2 > (1.3 * r_px + 3.0) ** 2
    patch[outside] = np.median(border, axis=0).astype(img.dtype)
    return RectifiedView(img)


def _masked_retry(left, vr, mask_fn, params, r_range_px, rect, a, b, K2) -> dict | None:
    """A merged region whose two views were fitted to different balls: the right view again, with
    only the disc where the refined left's (``left``) ball must appear left in it."""
    lreg = left[0]
    if lreg is None:
        return None
    win = _window(b, vr.shape)
    _, rreg, _ = segment_image(
        _one_ball_view(vr, lreg, rect, params, win),
        mask_fn,
        params,
        r_range_px,
        window=win,
        K=K2,
        only_window=True,
    )
    if rreg is None or check_pair(lreg, rreg, params, rect) is not None:
        return None
    return {
        "found": True,
        "reason": None,
        "left": lreg,
        "right": rreg,
        "left_px": a["centroid_px"],
        "color_score": a["color_score"],
    }


def _not_round(vl, vr, mask_fn, params, r_range_px, rect, l_refused, r_all, K1, K2) -> list[dict]:
    """A ball-coloured region that is not round: a ball partly hidden by another, or two touching.
    The partial-view fit (``segment_image``'s) may still locate one whole ball in it; else it is
    refused."""
    # Two touching balls of one colour are two instances, not an ambiguity: the fit takes one (a
    # wrong left/right pairing of the two fails check_pair: its disparity disagrees with the balls'
    # size).
    params = params.model_copy(
        update={"partial": params.partial.model_copy(update={"ambiguous_second_arc": 1.0})}
    )
    out = []
    for a in l_refused:
        # each right region on its rows is tried: the wrong ones fail check_pair (size against
        # stereo distance)
        js = _rows_partners(a, r_all, params, rect)
        left = _left(vl, mask_fn, params, r_range_px, a, K1) if js else (None, None)
        tried = [
            _pair_with(left, vr, mask_fn, params, r_range_px, rect, a, r_all[j], K2) for j in js
        ]
        good = [t for t in tried if t["found"]]
        # the two views' fits took different balls of the merged region: the right one again, alone
        if not good:
            good = [
                t
                for j in js
                if (
                    t := _masked_retry(left, vr, mask_fn, params, r_range_px, rect, a, r_all[j], K2)
                )
                is not None
            ]
        if len(good) == 1:
            # (it may hide another ball: the region was not one)
            out.append({**good[0], "merged": True})
            continue
        why = a["reason"] + (
            f"; partial view: {tried[0]['reason']}"
            if len(tried) == 1
            else "; partial view: more than one right region fits it"
            if good
            else f"; partial view: none of the {len(tried)} right regions on its rows fits it"
            if tried
            else "; no region of the object's colour on its rows in the right image"
        )
        out.append({"found": False, "reason": why, "left_px": a["centroid_px"]})
    return out


def find_instances(
    vl, vr, mask_fn: MaskFunction, params: SegmenterParams, r_range_px, rect: dict, K1=None, K2=None
) -> list[dict]:
    """Every instance of ``params.object`` in a rectified pair of views.

    Returns
    -------
    list of dict
        ``{"found", "reason", "left", "right", "left_px", "color_score"}`` per instance (regions as
        ``segment_image`` gives them; ``merged``: found in a region of more than one ball), refused
        ones with their reason and the left point they concern (``left_px``), in left-image reading
        order.
    """
    lefts, l_refused = _plausible(vl, mask_fn, params, r_range_px)
    rights, r_refused = _plausible(vr, mask_fn, params, r_range_px)
    options = [_partners(a, rights, params, rect) for a in lefts]
    takers = {j: [i for i, o in enumerate(options) if j in o] for j in range(len(rights))}
    used = {o[0] for o in options if len(o) == 1}
    out = _not_round(
        vl,
        vr,
        mask_fn,
        params,
        r_range_px,
        rect,
        l_refused,
        [b for j, b in enumerate(rights) if j not in used] + r_refused,
        K1,
        K2,
    )
    for i, a in enumerate(lefts):
        if not options[i]:
            out.append(
                _merged_on_the_right(
                    vl, vr, mask_fn, params, r_range_px, rect, a, r_refused, K1, K2
                )
            )
        elif len(options[i]) > 1 or len(takers[options[i][0]]) > 1:
            out.append(
                {
                    "found": False,
                    "left_px": a["centroid_px"],
                    "reason": "two balls of this object on the same image rows: which right view "
                    "belongs to "
                    "which left one cannot be told apart",
                }
            )
        else:
            out.append(
                _pair_with(
                    _left(vl, mask_fn, params, r_range_px, a, K1),
                    vr,
                    mask_fn,
                    params,
                    r_range_px,
                    rect,
                    a,
                    rights[options[i][0]],
                    K2,
                )
            )
    return sorted(out, key=lambda r: (round(r["left_px"][1] / 8), r["left_px"][0]))


def _merged_on_the_right(vl, vr, mask_fn, params, r_range_px, rect, a, r_refused, K1, K2) -> dict:
    """A ball whole on the left with no round partner on the right: merged there with a
    neighbour (the views see the pair from two sides), found in that region, or refused."""
    # whole on the left, merged with a neighbour on the right (the views see the pair from
    # two sides)
    js = _rows_partners(a, r_refused, params, rect)
    left = _left(vl, mask_fn, params, r_range_px, a, K1) if js else (None, None)
    merged = [
        t
        for j in js
        if (t := _masked_retry(left, vr, mask_fn, params, r_range_px, rect, a, r_refused[j], K2))
        is not None
    ]
    return (
        {**merged[0], "merged": True}
        if len(merged) == 1
        else {
            "found": False,
            "left_px": a["centroid_px"],
            "reason": "no ball in the right image on its rows at the distance its size says",
        }
    )


def same_ball(a: dict, b: dict) -> bool:
    """Two instances (of two objects) that are one ball: their left points within a radius."""
    areas = [x["left"]["area_px"] for x in (a, b) if x.get("left")]
    r_px = math.sqrt(max(areas) / math.pi) if areas and max(areas) else 6.0
    return bool(np.hypot(*np.subtract(a["left_px"], b["left_px"])) < r_px)
