"""Shared machinery of the segmenters: object model, candidate selection, sub-pixel
refinement, shadow suppression, left/right checks and the overlay image.

Every segmenter follows the same plan; only the *mask function* (which pixels may belong
to the object) differs between methods:

1. **Detect** on a downscaled copy of each rectified image (``detect_downscale``, by default
   chosen from the smallest expected ball radius so that it stays >= 4 px; with
   ``coarse_first`` a level twice as coarse is tried first for balls big enough there): the
   method's mask, optional shadow suppression, connected components. The right image is
   searched in the left region's epipolar band first. The image may be a raw camera image
   rectified on request (:mod:`nodes.rectifiers._views`).
2. **Select** the object among the components: plausible size (from the calibration's focal
   length, the object's radius and the working range), roundness, colour (when configured),
   then the largest one (the thesis's rule). Two near-equal survivors -> not found.
3. **Refine** in a region of interest at full resolution: the mask again, then a sub-pixel
   contour -- each boundary point moved along the mask normal to the maximum of the colour
   gradient (parabolic peak) -- whose polygon moments give area and centroid and whose points
   give the ellipse (``cv2.fitEllipse`` after trimming outliers).
4. **Check** the two regions against each other (rectified: same rows, similar size/shape) and
   against the image border; an untrustworthy result is ``found: False`` with a reason.

Working in the ROI (and with cv2 in the hot path) keeps a 640x480 pair in a few milliseconds.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Literal

import cv2
import numpy as np

from nodes.rectifiers._views import RectifiedView, pair_views
from stereograph.api import Field, In, NodeError, Out, Params, PositiveRange

# mask_fn(image_bgr, params, expected_radius_px_range_at_this_scale, scale, roi) -> uint8 0/255 mask;
# ``scale`` is the downscale factor of ``image_bgr`` (1 = full resolution): divide sizes given in
# full-resolution pixels by it. ``roi`` is True for the small full-resolution window around a
# detected object (whose border is background) and False for a whole image.
MaskFn = Callable[[np.ndarray, "SegmenterParams", tuple[float, float], int, bool], np.ndarray]


# --------------------------------------------------------------------------------------------
# Parameters shared by every segmenter
# --------------------------------------------------------------------------------------------
class ObjectSpec(Params):
    """What the object looks like (YAML: ``object: {radius_cm: 2.0, color_bgr: [30, 40, 200]}``)."""

    radius_cm: float = Field(2.0, gt=0, le=100, description="Radius of the ball (cm).")
    color_bgr: tuple[int, int, int] | None = Field(
        None, description="Expected colour of the ball, B, G, R in 0-255; None = unknown colour."
    )
    hue_range_deg: tuple[float, float] | None = Field(
        None,
        description="Accepted hue range in degrees (0-360, wraps if lo > hi), alternative to color_bgr.",
    )
    color_tolerance: float = Field(
        0.15, gt=0, le=2, description="Max L1 distance of normalised (b,g,r) chromaticity to color_bgr's (unitless)."
    )
    min_saturation: int = Field(
        60, ge=0, le=255, description="Min HSV saturation (0-255) of object pixels for hue ranges."
    )


# Every segmenter has this interface, so that swapping methods is a one-line YAML change.
SEGMENTER_INPUTS = {
    "pair": In("RectifiedPair | StereoPair",
               description="Rectified pair, or camera images rectified on request (needs `rectification`)."),
    "rectification": In("Rectification", optional=True, description="For the expected ball size."),
}
SEGMENTER_OUTPUTS = {
    "segmentation": Out("Segmentation", description="Masks and region properties."),
    "overlay": Out("Image", save=True, description="Left|right with outline and centroid (BGR)."),
}

class ShadowParams(Params):
    """Shadow suppression: drop dark, low-saturation pixels that the mask took from the table."""

    enabled: bool = Field(True, description="Remove shadow pixels attached to the object (bool).")
    max_removed_fraction: float = Field(
        0.8,
        gt=0,
        le=1,
        description="Keep a region unchanged if more than this share would go (a dark object, not a shadow; ratio).",
    )
    max_brightness_ratio: float = Field(
        0.8,
        gt=0,
        lt=1,
        description="A shadow pixel is at most this fraction of the local background brightness (ratio).",
    )
    max_saturation_gain: int = Field(
        30,
        ge=0,
        le=255,
        description="A shadow pixel is at most this much more saturated than the background (HSV S, 0-255).",
    )
    max_chroma_shift: float = Field(
        0.12,
        gt=0,
        description="Max change of normalised chromaticity (b,g,r)/sum vs the background (unitless).",
    )


class SegmenterParams(Params):
    """Parameters common to every segmenter."""

    object: ObjectSpec = Field(default_factory=ObjectSpec, description="Object model (radius in cm, colour).")
    working_range_cm: PositiveRange = Field(
        (20.0, 80.0), description="Nearest and farthest distance of the object from the cameras (cm)."
    )
    radius_px_range: PositiveRange | None = Field(
        None,
        description="Expected image radius range (px) when no Rectification is wired; None = 3 px .. half the image.",
    )
    min_roundness: float = Field(
        0.72,
        ge=0,
        le=1,
        description="Min area / (pi * r_max^2) of a candidate, 1 = disc (unitless).",
    )
    ambiguity_ratio: float = Field(
        0.85,
        gt=0,
        le=1,
        description="Second-best candidate area / best area at or above which the choice is ambiguous (ratio).",
    )
    max_area_ratio: float = Field(
        1.25, ge=1, description="Max ratio of the left and right region areas (ratio)."
    )
    max_row_offset_px: float = Field(
        2.0, ge=0, description="Max |v_left - v_right| of the two centroids in rectified images (px)."
    )
    detect_downscale: int | None = Field(
        None, ge=1, le=8, description="Downscale factor for detection; None = from the smallest expected radius."
    )
    coarse_first: bool = Field(
        True,
        description="With an automatic detect_downscale, look first at a level twice as coarse when the largest "
                    "expected ball is >= 8 px there, and fall back to the regular level when no plausible region of "
                    ">= 4 px radius is found there (bool; faster for near and mid-range balls).",
    )
    subpixel: bool = Field(True, description="Refine the contour to sub-pixel accuracy (bool).")
    edge_search_px: float = Field(
        3.0, ge=0.5, le=20, description="Half length of the normal search for the sub-pixel edge (px); "
                                        "at least half a pixel, or it samples nothing."
    )
    shadow: ShadowParams = Field(default_factory=ShadowParams, description="Shadow suppression options.")
    overlay: bool = Field(True, description="Render the overlay image (bool); off = a 1x1 placeholder.")


# --------------------------------------------------------------------------------------------
# Expected size
# --------------------------------------------------------------------------------------------
def expected_radius_px(
    params: SegmenterParams, rectification: dict | None, image_size: tuple[int, int]
) -> tuple[float, float]:
    """Range of the ball's image radius in pixels.

    Parameters
    ----------
    params : SegmenterParams
        ``object.radius_cm`` and ``working_range_cm`` are used.
    rectification : dict or None
        A ``Rectification``; ``f_px`` (px) is used. Without it ``radius_px_range`` or a broad
        default applies.
    image_size : (w, h)
        Image size in pixels.

    Returns
    -------
    (r_min_px, r_max_px) : floats
        With 30 % slack for the elongation of off-axis silhouettes and size tolerance.
    """
    w, h = image_size
    if rectification is not None and rectification.get("f_px"):
        f = float(rectification["f_px"])
        R = params.object.radius_cm
        z0, z1 = sorted(params.working_range_cm)
        # The silhouette of a sphere at distance z has angular radius asin(R/z).
        r_max = f * math.tan(math.asin(min(R / max(z0, R * 1.01), 0.99)))
        r_min = f * math.tan(math.asin(R / z1))
        return 0.7 * r_min, 1.3 * r_max
    if params.radius_px_range is not None:
        return tuple(sorted(map(float, params.radius_px_range)))  # type: ignore[return-value]
    return 3.0, 0.5 * min(w, h)


def auto_downscale(r_min_px: float, requested: int | None) -> int:
    """Detection downscale factor: largest power of two (<= 4) keeping the smallest ball >= 4 px."""
    if requested is not None:
        return int(requested)
    s = 1
    while s < 4 and r_min_px / (2 * s) >= 4.0:
        s *= 2
    return s


Channel = Literal["gray", "saturation", "color"]


def to_channel(img_bgr: np.ndarray, channel: str) -> np.ndarray:
    """The image plane a gray-level method works on.

    ``gray`` (the thesis), ``saturation`` (HSV S: a coloured ball on a neutral, textured table
    stands out while the texture and the shadow mostly vanish) or ``color`` (the BGR image
    itself; OpenCV's Canny then takes the strongest channel gradient).
    """
    if img_bgr.ndim == 2 or channel == "color":
        return img_bgr
    if channel == "saturation":
        return cv2.cvtColor(img_bgr, cv2.COLOR_BGR2HSV)[..., 1].copy()
    return cv2.cvtColor(img_bgr, cv2.COLOR_BGR2GRAY)


def structuring_element(size_px: int) -> np.ndarray:
    """Elliptical structuring element of the given diameter (px, >= 1); do not modify it (shared)."""
    return _ellipse_element(max(1, int(size_px)))


@functools.lru_cache(maxsize=64)
def _ellipse_element(size_px: int) -> np.ndarray:
    el = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px))
    el.flags.writeable = False
    return el


def fill_holes(mask: np.ndarray, max_area_px: float | None = None) -> np.ndarray:
    """Fill the holes of a uint8 0/255 mask (flood fill of the background from the border).

    Parameters
    ----------
    mask : uint8 HxW, 0/255
    max_area_px : float, optional
        Fill only holes up to this area (px). A closed outline much larger than any ball --
        the edge of a rectified image's valid area, a table edge -- then does not swallow the
        whole scene.
    """
    h, w = mask.shape
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    cv2.floodFill(padded, None, (0, 0), 128)  # 4-connected background reachable from the border
    holes = cv2.compare(padded[1:-1, 1:-1], 0, cv2.CMP_EQ)
    if max_area_px is not None and cv2.countNonZero(holes) > max_area_px:
        # Drop the holes larger than max_area_px (4-connected components). Cheaper than
        # labelling the whole image: only outlines whose area bound exceeds the limit are
        # measured exactly, by a flood fill (marked 1 = kept, 0 = dropped); a big hole may
        # surround small ones, which stay (they are separate components).
        while True:
            cnts, _ = cv2.findContours(cv2.compare(holes, 255, cv2.CMP_EQ), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_NONE)
            # Pixel count <= polygon area + boundary points + 1 (Pick's theorem).
            big = [c for c in cnts if cv2.contourArea(c) + len(c) + 1 > max_area_px]
            if not big:
                break
            for c in big:
                x, y = (int(v) for v in c[0, 0])
                if holes[y, x] != 255:
                    continue
                if cv2.floodFill(holes, None, (x, y), 1, flags=4)[0] > max_area_px:
                    cv2.floodFill(holes, None, (x, y), 0, flags=4)
        holes = cv2.compare(holes, 0, cv2.CMP_GT)
    return cv2.bitwise_or(mask, holes)


def max_hole_area(r_range_px: tuple[float, float]) -> float:
    """Largest hole worth filling: a ball of the largest expected radius plus its shadow (px)."""
    return 4.0 * math.pi * r_range_px[1] ** 2


def fast_median(a: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """``np.median`` of a 1-D array (``axis=None``, flattened) or of a 2-D array along axis 0.

    Same values as ``np.median`` (the mean of the two middle values for an even count; float64
    for integers) with a single ``np.partition`` -- ``np.median``'s own overhead dominates on
    the few hundred values per call here.
    """
    a = np.asarray(a)
    if axis is None:
        a = a.ravel()
    n = a.shape[0]
    if n == 0:
        return np.median(a, axis=0)
    k = n // 2
    if a.dtype.kind in "iub":
        a = a.astype(np.float64)
    if n % 2:
        return np.partition(a, k, axis=0)[k]
    p = np.partition(a, (k - 1, k), axis=0)
    return (p[k - 1] + p[k]) / 2


def _channels(img: np.ndarray) -> int:
    return 1 if img.ndim == 2 else img.shape[2]


def masked_pixels(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``img[mask]`` -- the pixels where ``mask`` is true, (N, C) for a colour image -- but fast.

    NumPy's boolean gather is ~25x slower per pixel when a pixel is C elements than when it
    is one, so a colour image is viewed as HxW elements of C bytes for the gather.
    """
    if img.ndim != 3 or img.shape[:2] != mask.shape:
        return img[mask]
    try:
        whole = img.view(np.dtype((np.void, img.shape[2] * img.itemsize)))[..., 0]
    except ValueError:  # pixels not contiguous in memory
        return img[mask]
    return whole[mask].view(img.dtype).reshape(-1, img.shape[2])


# --------------------------------------------------------------------------------------------
# Colour helpers
# --------------------------------------------------------------------------------------------
def chromaticity(img_bgr: np.ndarray) -> np.ndarray:
    """Normalised chromaticity (b, g, r) / (b + g + r) per pixel (float32, sums to 1).

    Invariant to the brightness of the illumination, so the lit and the shaded side of a
    matte ball have the same value.
    """
    f = np.asarray(img_bgr, np.float32)
    return f / np.maximum(f.sum(axis=-1, keepdims=True), 1.0)


def color_distance_map(img_bgr: np.ndarray, color_bgr) -> np.ndarray:
    """Per-pixel L1 distance of the normalised chromaticity to that of ``color_bgr`` (0-2, unitless).

    sum_c |x_c / S - r_c| = sum_c |x_c - r_c S| / S with S = x_b + x_g + x_r, computed with
    cv2 channel transforms (fast). Pixels darker than 25 gray levels (chromaticity undefined
    in the noise) get distance 2.
    """
    img = np.asarray(img_bgr)
    f = img.astype(np.float32)
    d = _chroma_distance(f, cv2.max(cv2.transform(f, _ONES_1x3), 1.0), color_bgr).reshape(img.shape[:2])
    gray_max = cv2.max(cv2.max(img[..., 0], img[..., 1]), img[..., 2]).reshape(img.shape[:2])
    d[gray_max < 25] = 2.0
    return d


_ONES_1x3 = np.ones((1, 3), np.float32)


def _chroma_distance(f: np.ndarray, total: np.ndarray, color_bgr) -> np.ndarray:
    """sum_c |x_c - r_c S| / S for a float32 BGR image ``f`` and its channel sum ``total`` = max(S, 1)."""
    b, g, r = (float(x) for x in color_bgr)
    k = max(b + g + r, 1.0)
    ref = np.array([[b / k] * 3, [g / k] * 3, [r / k] * 3], np.float32)  # row c: r_c * (1, 1, 1)
    scaled = cv2.transform(f, ref)  # channel c = r_c * S
    return cv2.divide(cv2.transform(cv2.absdiff(f, scaled), _ONES_1x3), total)


def hue_mask(img_bgr: np.ndarray, hue_range_deg, min_saturation: int) -> np.ndarray:
    """uint8 0/255 mask of pixels whose hue is in the range (degrees, wrapping) and saturated."""
    hsv = cv2.cvtColor(img_bgr, cv2.COLOR_BGR2HSV)
    lo, hi = (float(x) % 360.0 / 2.0 for x in hue_range_deg)  # OpenCV hue is 0..180
    hch = hsv[..., 0]
    if lo <= hi:
        m = (hch >= lo) & (hch <= hi)
    else:
        m = (hch >= lo) | (hch <= hi)
    m &= hsv[..., 1] >= min_saturation
    return m.astype(np.uint8) * 255


def object_color_score(img_bgr: np.ndarray, mask: np.ndarray, obj: ObjectSpec) -> float | None:
    """How far the region's median colour is from the object's colour (0 = same; None = no colour set).

    For ``color_bgr`` it is the median chromaticity distance divided by the tolerance; for a hue range it is
    1 - fraction of region pixels inside the range.
    """
    if obj.color_bgr is None and obj.hue_range_deg is None:
        return None
    sel = mask > 0
    if not sel.any():
        return float("inf")
    if obj.color_bgr is not None:
        dist = float(fast_median(color_distance_map(masked_pixels(img_bgr, sel)[None], obj.color_bgr)))
        return dist / obj.color_tolerance
    hm = hue_mask(img_bgr, obj.hue_range_deg, obj.min_saturation)
    return float(1.0 - (hm[sel] > 0).mean()) * 2.0  # 50 % outside the range -> score 1


# --------------------------------------------------------------------------------------------
# Shadow suppression
# --------------------------------------------------------------------------------------------
def suppress_shadow(img_bgr: np.ndarray, mask: np.ndarray, shadow: ShadowParams, obj: ObjectSpec) -> np.ndarray:
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
    sel = mask > 0
    # Local background: a ring just outside the mask (fallback: everything outside).
    ring = cv2.subtract(cv2.dilate(mask, structuring_element(9)), mask)
    bg_px = masked_pixels(img_bgr, ring > 0) if cv2.countNonZero(ring) > 20 else masked_pixels(img_bgr, ~sel)
    bg = np.asarray(fast_median(bg_px.reshape(-1, 3), axis=0), np.float32)
    bg_v = float(bg.max())
    if bg_v < 1:
        return mask
    bg_s = (bg_v - float(bg.min())) / max(bg_v, 1.0) * 255.0
    # Only the region's pixels are classified: a 1xNx3 image of them keeps the cv2 calls.
    px = masked_pixels(img_bgr, sel)[None]
    hsv = cv2.cvtColor(px, cv2.COLOR_BGR2HSV)  # V = max channel, S = (V - min) / V * 255
    v, s = hsv[..., 2], hsv[..., 1]
    f = px.astype(np.float32)
    total = cv2.max(cv2.transform(f, _ONES_1x3), 1.0)
    dchroma = _chroma_distance(f, total, bg).reshape(v.shape)
    dark = v < 25  # chromaticity is noise in the darkest pixels: it must not veto (shadow test) ...
    dchroma[dark] = 0.0
    drop = (v <= shadow.max_brightness_ratio * bg_v) & (s <= bg_s + shadow.max_saturation_gain)
    drop &= dchroma <= shadow.max_chroma_shift
    if obj.color_bgr is not None:
        d_obj = _chroma_distance(f, total, obj.color_bgr).reshape(v.shape)
        d_obj[dark] = 2.0  # ... nor make a dark pixel the object's colour (as color_distance_map)
        drop &= d_obj > obj.color_tolerance
    elif obj.hue_range_deg is not None:
        drop &= hue_mask(px, obj.hue_range_deg, obj.min_saturation) == 0
    drop = drop[0]
    if drop.sum() > shadow.max_removed_fraction * drop.size:
        return mask  # most of the region looks like shadow: a dark neutral object, keep it
    out = mask.copy()
    kept = out[sel]
    kept[drop] = 0
    out[sel] = kept
    # Cut thin bridges left between the object and remaining shadow specks.
    out = cv2.morphologyEx(out, cv2.MORPH_OPEN, structuring_element(3))
    return out


def suppress_shadow_regions(
    img_bgr: np.ndarray, mask: np.ndarray, area_range_px: tuple[float, float], shadow: ShadowParams, obj: ObjectSpec,
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
        if min_roundness is not None and area_range_px[0] <= area <= area_range_px[1] \
                and roundness(c, cv2.moments(c), area + 0.5 * cv2.arcLength(c, True)) >= min_roundness:
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


# --------------------------------------------------------------------------------------------
# Candidates and selection
# --------------------------------------------------------------------------------------------
def candidates(mask: np.ndarray, min_area_px: float) -> list[dict]:
    """Outer contours of a 0/255 mask (holes ignored) with their shape measures.

    Returns a list of dicts: ``contour`` (Nx2 int), ``area_px`` (pixel count, approximated by
    the contour area plus half its perimeter), ``bbox`` [u0,v0,u1,v1] (inclusive),
    ``centroid_px``, ``roundness`` (area / (pi r_max^2), 1 for a disc).
    """
    cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    out = []
    for c in cnts:
        if len(c) < 4:
            continue
        m = cv2.moments(c)
        if m["m00"] <= 0:
            continue
        # Contour points are the centres of boundary pixels: the region extends half a pixel
        # further, hence + perimeter / 2 for the pixel count and + 0.5 for the radius.
        area = m["m00"] + 0.5 * cv2.arcLength(c, True)
        if area < min_area_px:
            continue
        x, y, w, h = cv2.boundingRect(c)
        out.append(
            {
                "contour": c,
                "area_px": float(area),
                "bbox": [x, y, x + w - 1, y + h - 1],
                "centroid_px": [m["m10"] / m["m00"], m["m01"] / m["m00"]],
                "roundness": roundness(c, m, area),
            }
        )
    return out


def roundness(contour: np.ndarray, moments: dict, area_px: float) -> float:
    """Pixel area over the disc of the farthest outline point from the centroid (1 for a disc).

    Contour points are the centres of boundary pixels, so the radius gets + 0.5 px.
    """
    cu, cv_ = moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]
    pts = contour.reshape(-1, 2)
    r_max = float(np.sqrt(((pts[:, 0] - cu) ** 2 + (pts[:, 1] - cv_) ** 2).max())) + 0.5
    return float(area_px / (math.pi * r_max**2))


def _filled(contour: np.ndarray, bbox) -> np.ndarray:
    """uint8 0/255 mask of a filled contour inside its bbox."""
    x0, y0, x1, y1 = bbox
    sub = np.zeros((y1 - y0 + 1, x1 - x0 + 1), np.uint8)
    cv2.drawContours(sub, [contour - np.int32([x0, y0])], -1, 255, cv2.FILLED)
    return sub


def select_candidate(
    cands: list[dict],
    img_bgr: np.ndarray,
    r_range_px: tuple[float, float],
    params: SegmenterParams,
) -> tuple[dict | None, str | None]:
    """Choose the object among the candidates (coordinates of ``img_bgr``).

    Rules: plausible area (pi r^2 within the expected radius range), roundness, colour
    distance within tolerance (when a colour is configured); among the survivors the one most
    consistent with the colour, else the largest (the thesis's rule). Two survivors of
    near-equal area and no colour to tell them apart -> ambiguous.

    Returns
    -------
    (candidate or None, reason or None)
    """
    if not cands:
        return None, "no region found"
    a_min = math.pi * r_range_px[0] ** 2
    a_max = math.pi * r_range_px[1] ** 2
    rejected = []
    ok = []
    for c in cands:
        if not (a_min <= c["area_px"] <= a_max):
            rejected.append(f"area {c['area_px']:.0f} px outside {a_min:.0f}-{a_max:.0f}")
            continue
        if c["roundness"] < params.min_roundness:
            rejected.append(f"roundness {c['roundness']:.2f} < {params.min_roundness}")
            continue
        x0, y0, x1, y1 = c["bbox"]
        score = None
        if params.object.color_bgr is not None or params.object.hue_range_deg is not None:
            score = object_color_score(img_bgr[y0 : y1 + 1, x0 : x1 + 1], _filled(c["contour"], c["bbox"]),
                                       params.object)
        if score is not None and score > 1.0:
            rejected.append("colour differs from the object's")
            continue
        c["color_score"] = score
        ok.append(c)
    if not ok:
        h, w = img_bgr.shape[:2]
        biggest = max(cands, key=lambda c: c["area_px"])
        x0, y0, x1, y1 = biggest["bbox"]
        if biggest["area_px"] >= a_min and (x0 <= 0 or y0 <= 0 or x1 >= w - 1 or y1 >= h - 1):
            return None, "the only sizeable region touches the image border (object cut off?)"
        why = "; ".join(sorted(set(rejected))[:3])
        return None, f"no plausible region ({len(cands)} candidate(s): {why})"
    ok.sort(key=lambda c: -c["area_px"])
    if len(ok) > 1:
        a, b = ok[0], ok[1]
        if b["area_px"] >= params.ambiguity_ratio * a["area_px"]:
            if a.get("color_score") is not None and abs(a["color_score"] - b["color_score"]) > 0.25:
                ok.sort(key=lambda c: c["color_score"])
                return ok[0], None
            return None, (
                f"two candidate regions of near-equal size ({a['area_px']:.0f} and {b['area_px']:.0f} px)"
            )
    return ok[0], None


# --------------------------------------------------------------------------------------------
# Sub-pixel refinement
# --------------------------------------------------------------------------------------------
def _color_gradient(img_bgr: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Colour gradient magnitude (sqrt of the sum over channels of |grad|^2), float32."""
    f = cv2.GaussianBlur(img_bgr, (0, 0), sigma)
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
    c, n = c[good], n[good] / norm[good]
    # The gradient is needed only along the outline: crop to it. Samples lie within
    # search_px + 1 px of the outline and the blur and Sobel reach 4 px, so a margin of
    # search_px + 6 px gives the values of the whole image's gradient.
    hh, ww = img_bgr.shape[:2]
    m = int(math.ceil(search_px)) + 6
    x0, y0 = max(0, int(c[:, 0].min()) - m), max(0, int(c[:, 1].min()) - m)
    x1, y1 = min(ww, int(c[:, 0].max()) + m + 1), min(hh, int(c[:, 1].max()) + m + 1)
    grad = _color_gradient(img_bgr[y0:y1, x0:x1])
    step = 0.25
    t = np.arange(-search_px, search_px + step / 2, step, dtype=np.float32)
    mx = (c[:, 0:1] - x0 + n[:, 0:1] * t[None, :]).astype(np.float32, copy=False)
    my = (c[:, 1:2] - y0 + n[:, 1:2] * t[None, :]).astype(np.float32, copy=False)
    prof = cv2.remap(grad, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    k = prof.argmax(axis=1)
    inner = (k > 0) & (k < len(t) - 1)
    peak = prof[np.arange(len(k)), k]
    inner &= peak > 0.25 * fast_median(peak)
    k = np.minimum(np.maximum(k, 1), len(t) - 2)
    rows = np.arange(len(k))
    y0, y1, y2 = prof[rows, k - 1], prof[rows, k], prof[rows, k + 1]
    den = y0 - 2 * y1 + y2
    off = np.where(np.abs(den) > 1e-9, 0.5 * (y0 - y2) / np.where(den == 0, 1, den), 0.0)
    tt = t[k] + np.clip(off, -0.5, 0.5) * step
    pts = c + n * tt[:, None]
    pts = pts[inner]
    if len(pts) < 12:
        return None
    return pts.astype(np.float32)


def fit_ellipse_robust(pts: np.ndarray) -> dict | None:
    """Ellipse through sub-pixel outline points, trimming outliers (occlusion, shadow specks).

    Returns ``{"center_px": [u, v], "axes_px": [a, b], "angle_deg": float, "rms_px": float}``
    with a >= b the semi-axes (px); ``angle_deg`` is OpenCV's angle of the first axis.
    """
    if pts is None or len(pts) < 6:
        return None
    keep = np.ones(len(pts), bool)
    refit = True
    for _ in range(3):
        (cu, cv_), (w, h), ang = cv2.fitEllipse(pts[keep])
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
        mad = fast_median(np.abs(res[keep])) * 1.4826 + 1e-3
        new = np.abs(res) <= max(3.0 * mad, 0.3)
        if new.sum() < 6 or (new == keep).all():
            refit = False  # converged (or too few inliers): the last fit used ``keep``
            break
        keep = new
    if refit:
        (cu, cv_), (w, h), ang = cv2.fitEllipse(pts[keep])
    rms = float(np.sqrt(np.mean(res[keep] ** 2)))
    a, b = max(w, h) / 2, min(w, h) / 2
    if h > w:  # report the angle of the major axis
        ang = (ang + 90.0) % 180.0
    return {
        "center_px": [float(cu), float(cv_)],
        "axes_px": [float(a), float(b)],
        "angle_deg": float(ang),
        "rms_px": rms,
        "inliers": int(keep.sum()),
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
    m = cv2.moments(mask, binaryImage=True)
    area = float(m["m00"])
    cu, cv_ = m["m10"] / m["m00"], m["m01"] / m["m00"]
    if contour is None:
        cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        contour = max(cnts, key=len)
    x, y, bw, bh = cv2.boundingRect(contour)
    bbox = [x + u0, y + v0, x + bw - 1 + u0, y + bh - 1 + v0]
    touches = bbox[0] <= 0 or bbox[1] <= 0 or bbox[2] >= w - 1 or bbox[3] >= h - 1
    if not touches:
        # A rectified image has a black (exactly 0) fill outside the camera's field of view:
        # a region next to it is cut by the view's border just as by the frame's.
        ring = cv2.subtract(cv2.dilate(mask, structuring_element(5)), mask)
        black = cv2.inRange(img_bgr, (0,) * _channels(img_bgr), (0,) * _channels(img_bgr))  # every channel 0
        if cv2.countNonZero(cv2.bitwise_and(ring, black)) >= 3:
            touches = True
    pts = refine_contour(img_bgr, mask, params.edge_search_px + search_extra_px, contour) if params.subpixel else None
    sigma_c = None
    method = "pixels"
    if pts is not None:
        pm = cv2.moments(pts)
        if pm["m00"] > 0.5 * area:
            area, cu, cv_ = float(pm["m00"]), pm["m10"] / pm["m00"], pm["m01"] / pm["m00"]
            method = "subpixel_contour"
    else:
        pts = contour.reshape(-1, 2).astype(np.float32)
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


# --------------------------------------------------------------------------------------------
# Per-image and per-pair drivers
# --------------------------------------------------------------------------------------------
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
    if rectification is None or not rectification.get("f_px") or not rectification.get("baseline_cm"):
        return None
    fb = float(rectification["f_px"]) * abs(float(rectification["baseline_cm"]))
    cx = float(rectification.get("cx_px", 0.0))
    dcx = cx - float(rectification.get("cx_right_px", cx))  # d = f B / z + (cx_left - cx_right)
    z0, z1 = sorted(params.working_range_cm)
    d_min, d_max = fb / (1.25 * z1), fb / (0.75 * z0)
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
    mask_fn: MaskFn,
    params: SegmenterParams,
    r_range_px: tuple[float, float],
    s: int,
    window: tuple[int, int, int, int] | None,
    min_radius_px: float = 0.0,
) -> tuple[dict | None, str | None, tuple[float, float, int, int]]:
    """Coarse detection: the chosen candidate (coarse coordinates), the reason, and
    (sx, sy, u_off, v_off) mapping coarse to full-resolution pixels. ``min_radius_px``
    (coarse px) raises the smallest plausible radius at this level."""
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
    if params.shadow.enabled:
        a_rng = (math.pi * r_small[0] ** 2, math.pi * r_small[1] ** 2)
        m = suppress_shadow_regions(small, m, a_rng, params.shadow, params.object, params.min_roundness)
    cands = candidates(m, min_area_px=max(4.0, 0.5 * math.pi * r_small[0] ** 2))
    if window is not None:
        # A region cut by the window's edge (inside the image) is not the object, which lies
        # inside the window by construction.
        sh, sw = m.shape
        cands = [c for c in cands
                 if not ((c["bbox"][0] <= 0 < wu0) or (c["bbox"][1] <= 0 < wv0)
                         or (c["bbox"][2] >= sw - 1 and wu1 < w) or (c["bbox"][3] >= sh - 1 and wv1 < h))]
    best, reason = select_candidate(cands, small, r_small, params)
    return best, reason, (sx, sy, wu0, wv0)


_MIN_RADIUS_COARSE_PX = 4.0  # smallest ball radius a coarse-first pass trusts (px at its level)


def segment_image(
    img_bgr: np.ndarray | RectifiedView,
    mask_fn: MaskFn,
    params: SegmenterParams,
    r_range_px: tuple[float, float],
    window: tuple[int, int, int, int] | None = None,
) -> tuple[np.ndarray, dict | None, str | None]:
    """Find the object in one rectified image.

    ``img_bgr`` is the rectified image or a :class:`RectifiedView` (a raw image rectified on
    request: only the coarse level and the object's window are remapped). ``window``
    (u0, v0, u1, v1), optional: detect only there (see :func:`search_band`); if nothing is
    found there, the whole image is searched (so reasons are the whole image's).

    Returns
    -------
    mask : bool HxW (the chosen region; all False if none)
    region : dict or None
    reason : str or None (why nothing was found)
    """
    view = img_bgr if isinstance(img_bgr, RectifiedView) else RectifiedView(img_bgr)
    h, w = view.shape[:2]
    s = auto_downscale(r_range_px[0], params.detect_downscale)
    # Passes: (level, where, smallest plausible radius at that level). The optional first pass
    # at twice the downscale is ~4x cheaper; it only accepts balls of >= 4 px there (smaller
    # ones, or none, fall through to the regular level, whose reasons are reported).
    passes = []
    if params.coarse_first and params.detect_downscale is None and 2 * s <= 8 \
            and r_range_px[1] / (2 * s) >= 2 * _MIN_RADIUS_COARSE_PX:
        passes.append((2 * s, window, _MIN_RADIUS_COARSE_PX))
    if window is not None:
        passes.append((s, window, 0.0))
    passes.append((s, None, 0.0))
    best = None
    for level, where, r_floor in passes:
        best, why, (sx, sy, ou, ov) = _detect(view, mask_fn, params, r_range_px, level, where, r_floor)
        if r_floor == 0.0:
            reason = why
        if best is not None:
            s = level
            break
    full_mask = np.zeros((h, w), bool)
    if best is None:
        return full_mask, None, reason
    # Region of interest at full resolution around the chosen candidate.
    x0, y0, x1, y1 = best["bbox"]
    r_est = 0.5 * max(x1 - x0 + 1, y1 - y0 + 1) * s
    pad = int(math.ceil(0.35 * r_est + 2 * s + params.edge_search_px + 4))
    u0, v0 = max(0, ou + int(x0 * sx) - pad), max(0, ov + int(y0 * sy) - pad)
    u1, v1 = min(w, ou + int((x1 + 1) * sx) + pad), min(h, ov + int((y1 + 1) * sy) + pad)
    roi = view.window(u0, v0, u1, v1)
    rm = mask_fn(roi, params, r_range_px, 1, True)
    if params.shadow.enabled:
        rm = suppress_shadow(roi, rm, params.shadow, params.object)
    cnts, _ = cv2.findContours(rm, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    # Keep the contour around the coarse candidate's centre.
    centre = (float(best["centroid_px"][0] * sx + ou - u0), float(best["centroid_px"][1] * sy + ov - v0))
    inside = [c for c in cnts if cv2.pointPolygonTest(c, centre, False) >= 0]
    a_best = best["area_px"] * sx * sy
    inside = [c for c in inside if 0.5 * a_best <= cv2.contourArea(c) <= 2.0 * a_best]
    if inside:
        chosen = max(inside, key=cv2.contourArea)
    else:
        # The window cut the outline open (a long shadow leaving it, say): use the coarse
        # region, scaled up; the sub-pixel refinement below moves it onto the true edge.
        chosen = np.round((best["contour"].astype(np.float64) + 0.5) * [sx, sy] - 0.5 + [ou - u0, ov - v0]
                          ).astype(np.int32)
        chosen = cv2.approxPolyDP(chosen, 0.5, True) if len(chosen) > 4 else chosen
        # Densify to one point per pixel along the outline.
        tmp = np.zeros(rm.shape, np.uint8)
        cv2.drawContours(tmp, [chosen], -1, 255, cv2.FILLED)
        dense, _ = cv2.findContours(tmp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not dense:
            return full_mask, None, "region vanished at full resolution"
        chosen = max(dense, key=cv2.contourArea)
    region_mask = np.zeros(rm.shape, np.uint8)
    cv2.drawContours(region_mask, [chosen], -1, 255, cv2.FILLED)
    region = region_properties(roi, region_mask, (u0, v0), (w, h), params, contour=chosen,
                               search_extra_px=0.0 if inside else float(s))
    region["roundness"] = float(best["roundness"])
    full_mask[v0:v1, u0:u1] = region_mask > 0
    return full_mask, region, None


def check_pair(left: dict, right: dict, params: SegmenterParams) -> str | None:
    """Reason why a left/right pair of regions cannot be trusted, or None."""
    if left["touches_border"] or right["touches_border"]:
        side = "left" if left["touches_border"] else "right"
        return f"region touches the {side} image border (object cut off)"
    ra = max(left["area_px"], right["area_px"]) / max(min(left["area_px"], right["area_px"]), 1e-9)
    if ra > params.max_area_ratio:
        return (
            f"left/right regions differ in size (areas {left['area_px']:.0f} vs {right['area_px']:.0f} px,"
            f" ratio {ra:.2f} > {params.max_area_ratio}): occluded or a different object"
        )
    dv = abs(left["centroid_px"][1] - right["centroid_px"][1])
    if dv > params.max_row_offset_px + 0.05 * math.sqrt(max(left["area_px"], 1.0) / math.pi):
        return f"left/right regions are on different rows (dv = {dv:.1f} px): not the same object"
    el, er = left.get("ellipse"), right.get("ellipse")
    if el and er:
        ql = el["axes_px"][1] / max(el["axes_px"][0], 1e-9)
        qr = er["axes_px"][1] / max(er["axes_px"][0], 1e-9)
        if abs(ql - qr) > 0.15:
            return f"left/right regions differ in shape (axis ratios {ql:.2f} vs {qr:.2f})"
    if left["centroid_px"][0] < right["centroid_px"][0]:
        return "negative disparity: the right region lies right of the left one"
    return None


def validate_pair(pair: dict, rectification: dict | None, raw: bool = False) -> str | None:
    """Reason why a pair cannot be segmented (shape problems), or None.

    ``raw``: the pair holds camera images (a ``StereoPair``) to be rectified on request, so
    their size must be the calibration's source size.
    """
    if not isinstance(pair, dict) or "left" not in pair or "right" not in pair:
        raise NodeError(
            "segmenter input is not a RectifiedPair or StereoPair (a dict with 'left' and 'right' images).",
            hint="wire the segmenter's `pair` input to a rectifier.remap output or a source's pairs.",
        )
    L, R = np.asarray(pair["left"]), np.asarray(pair["right"])
    for side, im in (("left", L), ("right", R)):
        if im.dtype != np.uint8 or im.ndim not in (2, 3) or im.size == 0:
            return f"{side} image is not a uint8 image (dtype {im.dtype}, shape {im.shape})"
    if L.shape != R.shape:
        return f"mismatched image sizes: left {L.shape[1]}x{L.shape[0]} vs right {R.shape[1]}x{R.shape[0]}"
    if rectification is not None:
        size = rectification.get("source_size", rectification.get("image_size")) if raw \
            else rectification.get("image_size")
        if size is not None:
            w, h = (int(x) for x in size)
            if (L.shape[1], L.shape[0]) != (w, h):
                return f"image size {L.shape[1]}x{L.shape[0]} differs from the calibration's {w}x{h}"
    return None


def pair_is_raw(ctx, rectification: dict | None) -> bool:
    """True when the segmenter's ``pair`` input is wired to camera images (a ``StereoPair``).

    Those are rectified on request (see :mod:`nodes.rectifiers._views`), which needs the
    Rectification's maps.
    """
    wired = getattr(ctx, "input_types", None) or {}
    if wired.get("pair") != "StereoPair":
        return False
    if rectification is None or "map_left_x" not in rectification:
        raise NodeError(
            "the segmenter's `pair` input gives raw camera images (StereoPair) but no Rectification "
            "with remap maps is wired to rectify them.",
            hint="wire `rectification: <rectifier.opencv node>.rectification`, or wire `pair` to a "
                 "rectifier.remap output.",
        )
    return True


def as_bgr(img: np.ndarray) -> np.ndarray:
    """A 3-channel BGR view of a gray or BGR uint8 image."""
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img


def draw_overlay(left: np.ndarray, right: np.ndarray, seg: dict) -> np.ndarray:
    """Left | right side by side (BGR uint8) with the mask outline (green) and centroid (red cross)."""
    out = []
    for side, img in (("left", left), ("right", right)):
        im = as_bgr(img).copy()
        mask = seg.get(f"{side}_mask")
        reg = seg.get(side)
        if mask is not None and mask.any():
            cnts, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(im, cnts, -1, (0, 255, 0), 1)
        if reg is not None:
            u, v = reg["centroid_px"]
            cv2.drawMarker(im, (int(round(u)), int(round(v))), (0, 0, 255), cv2.MARKER_CROSS, 12, 1)
        out.append(im)
    over = np.hstack(out)
    if not seg["found"]:
        cv2.putText(over, f"not found: {seg['reason']}"[:90], (5, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 255), 1, cv2.LINE_AA)
    return over


def segment_pair(
    pair: dict,
    rectification: dict | None,
    params: SegmenterParams,
    mask_fn: MaskFn,
    method: str,
    ctx=None,
) -> dict:
    """Run a segmenter's mask function on both images of a rectified pair.

    When ``ctx`` says that ``pair`` is wired to camera images (a ``StereoPair``), they are
    rectified on request with ``rectification``'s maps: the coarse detection level and the
    object's full-resolution window only (see :mod:`nodes.rectifiers._views`); the masks and
    regions are in rectified pixels either way.

    Returns the node's outputs ``{"segmentation": Segmentation, "overlay": BGR uint8}``; a pair
    that cannot be trusted gives ``found: False`` with a reason, never an exception.
    """
    raw = pair_is_raw(ctx, rectification)
    reason = reason_shape = validate_pair(pair, rectification, raw)
    pid = str(pair.get("id", ctx.item if ctx is not None else ""))
    seg = {
        "id": pid,
        "found": False,
        "reason": reason,
        "left_mask": None,
        "right_mask": None,
        "left": None,
        "right": None,
        "method": method,
        "object_radius_cm": float(params.object.radius_cm),
        "split": pair.get("split"),
    }
    L, R = as_bgr(np.asarray(pair["left"])), as_bgr(np.asarray(pair["right"]))
    if reason is None:
        vl, vr = pair_views(rectification, L, R, raw)
        h, w = vl.shape[:2]
        r_range = expected_radius_px(params, rectification, (w, h))
        lm, lreg, lwhy = segment_image(vl, mask_fn, params, r_range)
        band = search_band(lreg, rectification, params, (w, h)) if lreg is not None else None
        rm, rreg, rwhy = segment_image(vr, mask_fn, params, r_range, window=band)
        seg.update(left_mask=lm, right_mask=rm, left=lreg, right=rreg)
        if lreg is None or rreg is None:
            reason = f"left image: {lwhy}" if lreg is None else f"right image: {rwhy}"
        else:
            reason = check_pair(lreg, rreg, params)
    else:
        h, w = L.shape[:2]
        seg.update(left_mask=np.zeros((h, w), bool), right_mask=np.zeros(R.shape[:2], bool))
    seg["found"] = reason is None
    seg["reason"] = reason
    if reason is not None and ctx is not None:
        ctx.warn(f"{pid}: {reason}")
    if params.overlay and L.shape == R.shape:
        if raw and reason_shape is None:  # the overlay shows the rectified images the masks refer to
            L, R = vl.full(), vr.full()
        overlay = draw_overlay(L, R, seg)
    else:
        overlay = np.zeros((1, 1, 3), np.uint8)
    return {"segmentation": seg, "overlay": overlay}

