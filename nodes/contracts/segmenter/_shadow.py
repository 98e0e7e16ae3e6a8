"""Shadow suppression: drop the pixels of a mask that look like the ball's shadow on the table."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ._candidates import roundness
from ._color import DARK_LEVEL, _channel_total, _chroma_distance, dark_pixel_distance, hue_mask
from ._params import ObjectSpec, SegmenterParams, ShadowParams
from ._pixels import masked_pixels, structuring_element


def suppress_shadow(
    img_bgr: np.ndarray, mask: np.ndarray, shadow: ShadowParams, obj: ObjectSpec
) -> np.ndarray:
    """Remove shadow pixels from a mask.

    A cast shadow on the table is the table's own colour, darker: a brightness well below that
    of the surrounding background, no more saturated than the background (a low saturation
    compared with a coloured ball) and about the same normalised chromaticity. Such pixels
    inside the mask are dropped; pixels that match the object's colour (when configured) are
    always kept. A small opening then cuts the thin bridges
    that remain between ball and shadow.

    Parameters
    ----------
    img_bgr : uint8 HxWx3
    mask : uint8 HxW, 0/255
    shadow, obj : the options and the object model.

    Returns
    -------
    uint8 HxW, 0/255 : the mask without shadow pixels.
    """
    n_sel = cv2.countNonZero(mask)
    if n_sel == 0 or n_sel == mask.size:
        return mask
    # Every step below reads the mask's pixels or those within the ring's reach (4 px) of
    # them, so it runs on the mask's bounding box plus a 5 px frame (all 0 in the mask, so the
    # morphology's border handling at the crop's edge sees what the whole window has there):
    # the same pixels, the same result, on a ball's window about a third of the pixels.
    h, w = mask.shape
    x, y, bw, bh = cv2.boundingRect(mask)
    x0, y0, x1, y1 = (
        max(0, x - _FRAME_PX),
        max(0, y - _FRAME_PX),
        min(w, x + bw + _FRAME_PX),
        min(h, y + bh + _FRAME_PX),
    )
    if (x1 - x0) * (y1 - y0) < h * w:
        kept = _suppress(
            img_bgr[y0:y1, x0:x1], mask[y0:y1, x0:x1], n_sel, shadow, obj, img_bgr, mask
        )
        if kept is None:
            return mask
        out = np.zeros_like(mask)
        out[y0:y1, x0:x1] = kept
        return out
    kept = _suppress(img_bgr, mask, n_sel, shadow, obj, img_bgr, mask)
    return mask if kept is None else kept


_FRAME_PX = 5  # the shadow ring's reach (9 px element: 4 px) + 1 px of background for the opening


def _suppress(
    img_bgr: np.ndarray,
    mask: np.ndarray,
    n_sel: int,
    shadow: ShadowParams,
    obj: ObjectSpec,
    whole_img: np.ndarray,
    whole_mask: np.ndarray,
) -> np.ndarray | None:
    """:func:`suppress_shadow` on a crop holding the whole mask and its ring (``whole_*``: the
    uncropped window, for the fallback background); None = keep the mask unchanged."""
    # Local background: a ring just outside the mask (fallback: everything outside).
    ring = cv2.subtract(cv2.dilate(mask, structuring_element(9)), mask)
    bg_px = (
        masked_pixels(img_bgr, ring > 0)
        if cv2.countNonZero(ring) > 20
        else masked_pixels(whole_img, whole_mask == 0)
    )
    bg = _median_u8_rows(bg_px.reshape(-1, 3))
    bg_v = float(bg.max())
    if bg_v < 1:
        return None
    bg_s = (bg_v - float(bg.min())) / max(bg_v, 1.0) * 255.0
    # The brightness and saturation tests run on the region's pixels only (gathered once, in
    # row-major order with their flat indices) and usually leave few of them (a lit ball is
    # neither dark nor grey): only those go on to the chromaticity tests. V and S are
    # integers, so v <= t is v <= floor(t).
    s_max = math.floor(bg_s + shadow.max_saturation_gain)
    v_max = math.floor(shadow.max_brightness_ratio * bg_v)
    if s_max < 0 or v_max < 0:
        return cv2.morphologyEx(mask, cv2.MORPH_OPEN, structuring_element(3))
    sel = mask > 0
    where = np.flatnonzero(sel)
    # 1xKx3: the cv2 calls below work on it as an image
    region_px = masked_pixels(img_bgr, sel)[None]
    hsv = cv2.cvtColor(region_px, cv2.COLOR_BGR2HSV)  # V = max channel, S = (V - min) / V * 255
    cand = cv2.inRange(hsv, (0, 0, 0), (255, min(s_max, 255), min(v_max, 255)))[0] > 0
    where = where[cand]
    if len(where):
        where = where[_shadow_like(masked_pixels(region_px, cand[None])[None], bg, shadow, obj)]
    if len(where) > shadow.max_removed_fraction * n_sel:
        return None  # most of the region looks like shadow: a dark neutral object, keep it
    out = mask
    if len(where):
        out = mask.copy()
        out.reshape(-1)[where] = 0
    # Cut thin bridges left between the object and remaining shadow specks.
    out = cv2.morphologyEx(out, cv2.MORPH_OPEN, structuring_element(3))
    return out


def _shadow_like(
    px: np.ndarray, bg: np.ndarray, shadow: ShadowParams, obj: ObjectSpec
) -> np.ndarray:
    """Which of the dark, grey candidate pixels ``px`` (1xKx3) keep the background ``bg``'s
    chromaticity and are not of the object's colour: the shadow's (bool, K)."""
    f = px.astype(np.float32)
    total = _channel_total(f)
    # (V = the largest channel) chromaticity is noise in the darkest
    dark = px[0].max(axis=1) < DARK_LEVEL
    # pixels: it must not veto (shadow test) ...
    dchroma = _chroma_distance(f, total, bg).reshape(-1)
    dchroma[dark] = 0.0
    ok = dchroma <= shadow.max_chroma_shift
    if obj.color_bgr is not None:
        d_obj = _chroma_distance(f, total, obj.color_bgr).reshape(-1)
        # ... nor decide the object's colour (as
        d_obj[dark] = dark_pixel_distance(obj.color_bgr)
        # color_distance_map: not the object's, unless the object is dark itself)
        ok &= d_obj > obj.color_tolerance
    elif obj.hue_range_deg is not None:
        ok &= hue_mask(px, obj.hue_range_deg, obj.min_saturation)[0] == 0
    return ok


def _median_u8_rows(px: np.ndarray) -> np.ndarray:
    """Per-column median (float32, as ``np.median``: the mean of the two middle values for an even
    count) of an Nx3 uint8 array: one partition of the bytes, no float copy of them."""
    n = len(px)
    k = n // 2
    if n % 2:
        return np.partition(px, k, axis=0)[k].astype(np.float32)
    p = np.partition(px, (k - 1, k), axis=0)
    return (p[k - 1].astype(np.float32) + p[k]) / 2


def without_shadows(
    img_bgr: np.ndarray, mask: np.ndarray, params: SegmenterParams, r_px: tuple[float, float]
) -> np.ndarray:
    """``mask`` with its regions' shadows removed (:func:`suppress_shadow_regions`) when
    ``params.shadow`` is on; ``r_px``: the ball's smallest and largest radius in ``img_bgr``, px."""
    if not params.shadow.enabled:
        return mask
    a_rng = (math.pi * r_px[0] ** 2, math.pi * r_px[1] ** 2)
    return suppress_shadow_regions(
        img_bgr, mask, a_rng, params.shadow, params.object, params.min_roundness
    )


def suppress_shadow_regions(
    img_bgr: np.ndarray,
    mask: np.ndarray,
    area_range_px: tuple[float, float],
    shadow: ShadowParams,
    obj: ObjectSpec,
    min_roundness: float | None = None,
) -> np.ndarray:
    """:func:`suppress_shadow` applied region by region, in a window around each region.

    Only regions that could hold the object (area from the smallest plausible ball to four
    times the largest -- ball plus shadow) are processed; each gets its own local background.
    Working in windows keeps this cheap on whole images. With ``min_roundness``, a region that
    already has a ball's area and is at least that round is left as it is: a shadow attached
    to it is too small to change the choice, and the full-resolution pass removes it.
    """
    cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = mask.copy()
    h, w = mask.shape
    for c in cnts:
        x, y, bw, bh = cv2.boundingRect(c)
        if bw * bh < area_range_px[0]:
            continue
        area = cv2.contourArea(c)
        if not (0.5 * area_range_px[0] <= area <= 4 * area_range_px[1]):
            continue
        if (
            min_roundness is not None
            and area_range_px[0] <= area <= area_range_px[1]
            and roundness(c, cv2.moments(c), area + 0.5 * cv2.arcLength(c, True)) >= min_roundness
        ):
            continue
        m = 6
        x0, y0, x1, y1 = max(0, x - m), max(0, y - m), min(w, x + bw + m), min(h, y + bh + m)
        sub = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.drawContours(sub, [c - np.int32([x0, y0])], -1, 255, cv2.FILLED)
        sub &= mask[y0:y1, x0:x1]
        kept = suppress_shadow(img_bgr[y0:y1, x0:x1], sub, shadow, obj)
        removed = (sub > 0) & (kept == 0)
        out[y0:y1, x0:x1][removed] = 0
    return out
