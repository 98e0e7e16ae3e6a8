"""The per-pair driver every segmenter runs (and its overlay image); the steps live in
``_size``, ``_detect``, ``_candidates``, ``_subpixel``, ``_shadow`` and ``_checks``.

Every segmenter follows the same plan; only the *mask function* (which pixels may belong
to the object) differs between methods:

1. **Detect** on a downscaled copy of each rectified image (``detect_downscale``, by default
   chosen from the smallest expected ball radius so that it stays >= 4 px; with
   ``coarse_first`` a level twice as coarse is tried first for balls big enough there): the
   method's mask, optional shadow suppression, connected components. The right image is
   searched in the left region's epipolar band first. The image may be a raw camera image
   rectified on request (:mod:`nodes.contracts.views`).
2. **Select** the object among the components: plausible size (from the calibration's focal
   length, the object's radius and the working range), roundness, colour (when configured),
   then the largest one (the thesis's rule). Two near-equal survivors -> not found.
3. **Refine** in a region of interest at full resolution: the mask again, then a sub-pixel
   contour -- each boundary point moved along the mask normal to the maximum of the colour
   gradient (parabolic peak) -- whose polygon moments give area and centroid and whose points
   give the ellipse (``cv2.fitEllipse`` after trimming outliers).
   The candidates that lost keep their outlines (``rejected_left_px`` / ``rejected_right_px``,
   with one-word reasons in ``rejected_*_why``) for the overlays.
4. **Check** the two regions against each other (rectified: same rows, similar size/shape) and
   against the image border; an untrustworthy result is ``found: False`` with a reason.

Working in the ROI (and with cv2 in the hot path) keeps a 640x480 pair in a few milliseconds.
"""

from __future__ import annotations

import cv2
import numpy as np

from nodes.contracts.views import RectifiedView, pair_views

from ._checks import check_pair, pair_is_raw, validate_pair
from ._detect import search_band, segment_image
from ._params import MaskFunction, SegmenterParams
from ._size import expected_radius_px


def as_bgr(img: np.ndarray) -> np.ndarray:
    """A 3-channel BGR view of a gray or BGR uint8 image."""
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img


def draw_overlay(left: np.ndarray, right: np.ndarray, seg: dict) -> np.ndarray:
    """Left | right side by side (BGR uint8) with the mask outline (green), centroid (red cross),
    rejected candidates (orange, when the Segmentation lists them) and a band above naming the pair
    and the result."""
    from nodes.contracts.overlay import draw_rejected, label_pair

    out = []
    for side, img in (("left", left), ("right", right)):
        im = as_bgr(img).copy()
        draw_rejected(im, seg.get(f"rejected_{side}_px"), reasons=seg.get(f"rejected_{side}_why"))
        mask = seg.get(f"{side}_mask")
        reg = seg.get(side)
        if mask is not None and mask.any():
            cnts, _ = cv2.findContours(
                mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
            )
            cv2.drawContours(im, cnts, -1, (0, 255, 0), 1)
        if reg is not None:
            u, v = reg["centroid_px"]
            cv2.drawMarker(im, (int(round(u)), int(round(v))), (0, 0, 255), cv2.MARKER_CROSS, 12, 1)
        out.append(im)
    over = np.hstack(out)
    detail = None
    if seg["found"] and seg.get("left") is not None and seg.get("right") is not None:
        (ul, vl), (ur, vr) = seg["left"]["centroid_px"], seg["right"]["centroid_px"]
        detail = (
            f"{seg.get('method', 'segmented')}: centroid left ({ul:.1f}, {vl:.1f}) px, "
            f"right ({ur:.1f}, {vr:.1f}) px"
        )
    return label_pair(over, seg.get("id"), bool(seg["found"]), seg.get("reason"), detail)


def segment_pair(
    pair: dict,
    rectification: dict | None,
    params: SegmenterParams,
    mask_fn: MaskFunction,
    method: str,
    ctx=None,
    color_from: str | None = "params",
) -> dict:
    """Run a segmenter's mask function on both images of a rectified pair.

    When ``ctx`` says that ``pair`` is wired to camera images (a ``StereoPair``), they are
    rectified on request with ``rectification``'s maps: the coarse detection level and the
    object's full-resolution window only (see :mod:`nodes.contracts.views`); the masks and
    regions are in rectified pixels either way.

    ``color_from`` says where ``params.object``'s colour came from (``"params"``, ``"appearance"``),
    recorded in the Segmentation. Returns the node's outputs ``{"segmentation": Segmentation,
    "overlay": BGR uint8}``; a pair that cannot be trusted gives ``found: False`` with a reason,
    never an exception.
    """
    raw = pair_is_raw(ctx, rectification)
    reason = reason_shape = validate_pair(pair, rectification, raw)
    pid = str(pair.get("id", ctx.item if ctx is not None else ""))
    seg = _unfound(pair, pid, reason, method, params, color_from)
    L, R = as_bgr(np.asarray(pair["left"])), as_bgr(np.asarray(pair["right"]))
    if reason is None:
        vl, vr = pair_views(rectification, L, R, raw)
        h, w = vl.shape[:2]
        r_range = expected_radius_px(params, rectification, (w, h))
        lreg, lwhy, rreg, rwhy = _segment_views(
            seg, vl, vr, rectification, params, mask_fn, r_range
        )
        if lreg is None or rreg is None:
            reason = f"left image: {lwhy}" if lreg is None else f"right image: {rwhy}"
        else:
            reason = check_pair(lreg, rreg, params, rectification)
    else:
        h, w = L.shape[:2]
        seg.update(left_mask=np.zeros((h, w), bool), right_mask=np.zeros(R.shape[:2], bool))
    seg["found"] = reason is None
    seg["reason"] = reason
    if reason is not None and ctx is not None:
        ctx.warn(f"{pid}: {reason}")
    if params.overlay and L.shape == R.shape:
        # the overlay shows the rectified images the masks refer to
        if raw and reason_shape is None:
            L, R = vl.full(), vr.full()
        overlay = draw_overlay(L, R, seg)
    else:  # off, or left and right of different sizes: no picture (None: nothing is saved)
        overlay = None
    return {"segmentation": seg, "overlay": overlay}


def _unfound(
    pair: dict,
    pid: str,
    reason: str | None,
    method: str,
    params: SegmenterParams,
    color_from: str | None,
) -> dict:
    """A pair's Segmentation before anything is found in it (``found`` False, no masks)."""
    return {
        "id": pid,
        "found": False,
        "reason": reason,
        "left_mask": None,
        "right_mask": None,
        "left": None,
        "right": None,
        "method": method,
        "object_radius_cm": float(params.object.radius_cm),
        # (the next nodes' default)
        "working_range_cm": sorted(float(z) for z in params.working_range_cm),
        # where the object's colour came from: the YAML ("params"), learned ("appearance"), or none
        "color_from": color_from
        if (params.object.color_bgr is not None or params.object.hue_range_deg is not None)
        else None,
        "split": pair.get("split"),
        "rejected_left_px": [],
        "rejected_left_why": [],
        "rejected_right_px": [],
        "rejected_right_why": [],
    }


def _segment_views(
    seg: dict,
    vl: RectifiedView,
    vr: RectifiedView,
    rectification: dict | None,
    params: SegmenterParams,
    mask_fn: MaskFunction,
    r_range: tuple[float, float],
) -> tuple[dict | None, str | None, dict | None, str | None]:
    """Segment the left view, then the right one in the band the left region allows; fill
    ``seg``'s masks, regions and rejected outlines. Returns ``(left region, why none, right
    region, why none)``."""
    h, w = vl.shape[:2]
    K1 = K2 = None
    if rectification is not None and rectification.get("P1") is not None:
        K1, K2 = (
            np.asarray(rectification["P1"], float)[:, :3],
            np.asarray(rectification["P2"], float)[:, :3],
        )
    rej_l, rej_r = {}, {}
    lm, lreg, lwhy = segment_image(vl, mask_fn, params, r_range, K=K1, rejected=rej_l)
    band = search_band(lreg, rectification, params, (w, h)) if lreg is not None else None
    rm, rreg, rwhy = segment_image(vr, mask_fn, params, r_range, window=band, K=K2, rejected=rej_r)
    seg.update(
        left_mask=lm,
        right_mask=rm,
        left=lreg,
        right=rreg,
        rejected_left_px=rej_l.get("px", []),
        rejected_left_why=rej_l.get("why", []),
        rejected_right_px=rej_r.get("px", []),
        rejected_right_why=rej_r.get("why", []),
    )
    return lreg, lwhy, rreg, rwhy
