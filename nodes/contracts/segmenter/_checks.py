"""Left/right checks of a segmented pair (rows, size, shape, partial views) and of the pair's
input (rectified or raw).
"""

from __future__ import annotations

import math

import numpy as np

from stereograph.api import NodeError

from ._params import SegmenterParams


def check_pair(
    left: dict, right: dict, params: SegmenterParams, rectification: dict | None = None
) -> str | None:
    """Reason why a left/right pair of regions cannot be trusted, or None.

    With a ``rectification`` also: the silhouettes' size must give the stereo distance for a
    ball of ``object.radius_cm`` (``max_size_mismatch``), and a partly visible ball (region with
    ``partial``) must be located within ``partial.max_sigma_z_cm`` by its fitted arcs.
    """
    if rectification is not None and rectification.get("P1") is not None:
        why = _check_size_and_partial(left, right, params, rectification)
        if why is not None:
            return why
    if left.get("partial") or right.get("partial"):
        return None  # border, size and shape were judged on the fitted sphere images above
    if left["touches_border"] or right["touches_border"]:
        side = "left" if left["touches_border"] else "right"
        return f"region touches the {side} image border (object cut off)"
    ra = max(left["area_px"], right["area_px"]) / max(min(left["area_px"], right["area_px"]), 1e-9)
    if ra > params.max_area_ratio:
        return (
            f"left/right regions differ in size (areas {left['area_px']:.0f} vs "
            f"{right['area_px']:.0f} px,"
            f" ratio {ra:.2f} > {params.max_area_ratio}): occluded or a different object"
        )
    dv = abs(left["centroid_px"][1] - right["centroid_px"][1])
    if dv > params.max_row_offset_px + 0.05 * math.sqrt(max(left["area_px"], 1.0) / math.pi):
        return (
            f"left/right regions are on different rows (dv = {dv:.1f} px): not the same "
            "object -- or, when "
            "every pair says so, images this calibration does not rectify (left and "
            "right swapped, another "
            "rig's calibration)"
        )
    el, er = left.get("ellipse"), right.get("ellipse")
    if el and er:
        ql = el["axes_px"][1] / max(el["axes_px"][0], 1e-9)
        qr = er["axes_px"][1] / max(er["axes_px"][0], 1e-9)
        if abs(ql - qr) > 0.15:
            return f"left/right regions differ in shape (axis ratios {ql:.2f} vs {qr:.2f})"
    if left["centroid_px"][0] < right["centroid_px"][0]:
        return (
            "negative disparity: the right region lies right of the left one -- when "
            "every pair says so, the "
            "left and right images are swapped"
        )
    return None


def _check_size_and_partial(
    left: dict, right: dict, params: SegmenterParams, rectification: dict
) -> str | None:
    from nodes.contracts.sphere import ellipse_to_conic, sphere_from_silhouette

    el, er = left.get("ellipse"), right.get("ellipse")
    if not el or not er:
        return None
    P1, P2 = np.asarray(rectification["P1"], float), np.asarray(rectification["P2"], float)
    try:
        cones = [
            sphere_from_silhouette(
                ellipse_to_conic(e["center_px"], e["axes_px"], e["angle_deg"]), K
            )
            for e, K in ((el, P1[:, :3]), (er, P2[:, :3]))
        ]
    except (ValueError, np.linalg.LinAlgError, ZeroDivisionError):
        return "the silhouettes are not the images of a sphere"
    fb = -float(P2[0, 3])  # P2[0, 3] = -f B (rectified right camera)
    d = (cones[0]["center_px"][0] - float(P1[0, 2])) - (cones[1]["center_px"][0] - float(P2[0, 2]))
    if d <= 0 or fb <= 0:
        return None  # the disparity estimator reports a negative disparity
    z_stereo = fb / d
    R = params.object.radius_cm
    z_size = [R / max(math.sin(c["half_angle_rad"]), 1e-9) * c["axis"][2] for c in cones]
    worst = max((0, 1), key=lambda i: abs(z_size[i] / z_stereo - 1.0))  # the view that fits worst
    if abs(z_size[worst] / z_stereo - 1.0) > params.max_size_mismatch:
        return _size_mismatch(z_size, z_stereo, worst, params)
    why = _check_same_size(left, right, z_size, params)
    if why is not None:
        return why
    if left.get("partial") or right.get("partial"):
        return _check_partial(left, right, params, z_size, z_stereo, d, fb)
    return None


def _size_mismatch(
    z_size: list[float], z_stereo: float, worst: int, params: SegmenterParams
) -> str:
    """Why the region's size does not fit its stereo distance: in both views (the radius is
    wrong, or it is another object), or in the ``worst`` one."""
    R = params.object.radius_cm
    side, other = ("left", "right")[worst], ("left", "right")[1 - worst]
    # both views: the radius
    if abs(z_size[1 - worst] / z_stereo - 1.0) > params.max_size_mismatch:
        return (
            f"the region's size does not fit its distance for a ball of radius {R:g} "
            "cm (size gives "
            f"{z_size[0]:.1f} cm in the left image and {z_size[1]:.1f} cm in the right, stereo "
            f"{z_stereo:.1f} cm): another object, or object.radius_cm is wrong"
        )
    return (
        f"the region's size does not fit its distance for a ball of radius {R:g} cm "
        f"in the {side} image "
        f"(size gives {z_size[worst]:.1f} cm there, {z_size[1 - worst]:.1f} cm in the "
        f"{other} image, stereo "
        f"{z_stereo:.1f} cm): the {side} view sees another object or only part of the ball"
    )


def _check_partial(
    left: dict,
    right: dict,
    params: SegmenterParams,
    z_size: list[float],
    z_stereo: float,
    d: float,
    fb: float,
) -> str | None:
    """Reason not to trust a partly seen ball (disparity ``d``, px; ``fb``: f B): its arc's size
    disagrees with the stereo distance, or too little of it is seen to locate it; else None."""
    s_d = math.hypot(left.get("sigma_centroid_px") or 0.0, right.get("sigma_centroid_px") or 0.0)
    # A fit to the wrong edge (an occluder's, a touching object's) shows as a sphere image
    # whose size disagrees with the stereo distance by more than both can be off.
    for reg, z in ((left, z_size[0]), (right, z_size[1])):
        part = reg.get("partial")
        if not part:
            continue
        tol = 3.0 * math.hypot(part["sigma_size_rel"], s_d / d) + params.partial.size_tolerance
        if abs(z / z_stereo - 1.0) > tol:
            side = "left" if reg is left else "right"
            return (
                f"{_partial_clause(part, side)}: the arc fitted to it gives {z:.1f} "
                "cm from its size but "
                f"{z_stereo:.1f} cm by stereo (> {100 * tol:.1f} %): not trusted"
            )
    s_z = z_stereo**2 * s_d / fb
    if s_z > params.partial.max_sigma_z_cm:
        part = left.get("partial") or right.get("partial")
        side = "left" if left.get("partial") else "right"
        reg = left if left.get("partial") else right
        r_px = math.sqrt(max(float(reg.get("area_px") or 0.0), 0.0) / math.pi)
        # seen (nearly) whole, and small: not hidden
        if part["outline_visible"] >= 0.8 and r_px <= 12:
            return (
                f"the ball is small in the {side} image (~{r_px:.0f} px radius at "
                f"{z_stereo:.0f} cm, "
                f"{100 * part['outline_visible']:.0f} % of its outline seen): too few "
                "outline pixels to "
                f"locate it (sigma_z {s_z:.2f} cm > partial.max_sigma_z_cm "
                f"{params.partial.max_sigma_z_cm:g}); nearer placements, a longer "
                "focal length or a larger "
                "image locate it"
            )
        return (
            f"{_partial_clause(part, side)}: too little to locate it (sigma_z {s_z:.2f} cm > "
            f"partial.max_sigma_z_cm {params.partial.max_sigma_z_cm:g})"
        )
    return None


def _check_same_size(
    left: dict, right: dict, z_size: list[float], params: SegmenterParams
) -> str | None:
    """Reason why the two silhouettes cannot be one sphere's, from their sizes alone, or None.

    Both rectified cameras see the sphere's centre at one depth, so the distances the two
    silhouettes give from their size agree whatever the ball's true radius (``object.radius_cm``
    cancels). A view that lost part of the ball -- its unlit side merged with the dark table
    or its shadow, an occluder's edge taken for the ball's -- gives a smaller or larger sphere
    image, and its centroid moves with the missing part: on a whole-looking outline this was
    found 1.8 cm off (dim side light), inside ``max_size_mismatch`` and ``max_area_ratio``.
    The tolerance is the two fits' own 3 sigma plus ``lr_size_tolerance_px`` of image radius.
    """
    sig, r_px = [], []
    for reg in (left, right):
        part, ell = reg.get("partial"), reg["ellipse"]
        r = float(part["radius_px"]) if part else float(min(ell["axes_px"]))
        r_px.append(max(r, 1e-9))
        if part:
            sig.append(float(part["sigma_size_rel"]))
        else:  # mean of the outline residuals: rms / sqrt(N), relative to the radius
            sig.append(
                float(ell.get("rms_px") or 0.0)
                / math.sqrt(max(int(ell.get("inliers") or 1), 1))
                / r_px[-1]
            )
    rel = abs(z_size[0] / z_size[1] - 1.0)
    tol = 3.0 * math.hypot(*sig) + params.lr_size_tolerance_px / min(r_px)
    if rel <= tol:
        return None
    small = "left" if z_size[0] > z_size[1] else "right"
    return (
        f"the left and right silhouettes are not one ball's: from their size the left one gives "
        f"{z_size[0]:.1f} cm and the right one {z_size[1]:.1f} cm (radius {r_px[0]:.1f} "
        f"vs {r_px[1]:.1f} px, "
        f"{100 * rel:.1f} % apart > {100 * tol:.1f} %); the {small} view sees only part "
        "of the ball (its dark "
        "side lost in a shadow or the dim table, or an occluder): not trusted"
    )


def _partial_clause(part: dict, side: str) -> str:
    """What the fitted arcs saw in the ``side`` image, for a reason: cut by a border, hidden in
    part, or -- the whole outline seen, part of it off the ball's edge -- a region that strays from
    the ball."""
    cause = part.get("cause", "")
    seen = f"{100 * part['outline_visible']:.0f} % of the outline visible"
    if cause.startswith("border: "):
        return f"cut by the {cause[8:]} image border in the {side} image, {seen}"
    if part["outline_visible"] >= 0.995:  # (every direction has true edge: nothing hides the ball)
        return (
            f"the region's outline strays from the ball's edge in places in the {side} "
            "image (a touching "
            "object, a shadow or highlight on the rim; the whole ball's outline is seen)"
        )
    return f"occluded or touching another object in the {side} image, {seen}"


def validate_pair(pair: dict, rectification: dict | None, raw: bool = False) -> str | None:
    """Reason why a pair cannot be segmented (shape problems), or None.

    ``raw``: the pair holds camera images (a ``StereoPair``) to be rectified on request, so
    their size must be the calibration's source size.
    """
    if not isinstance(pair, dict) or "left" not in pair or "right" not in pair:
        raise NodeError(
            "segmenter input is not a RectifiedPair or StereoPair (a dict with 'left' "
            "and 'right' images).",
            hint="wire the segmenter's `pair` input to a rectifier.remap output or a source's "
            "pairs.",
        )
    L, R = np.asarray(pair["left"]), np.asarray(pair["right"])
    for side, im in (("left", L), ("right", R)):
        if im.dtype != np.uint8 or im.ndim not in (2, 3) or im.size == 0:
            return f"{side} image is not a uint8 image (dtype {im.dtype}, shape {im.shape})"
    # Sizes are the setup's, not one pair's: every later pair would be refused the same way (a live
    # loop would refuse every cycle), so they fail the node with the fix instead of giving "not
    # found".
    if L.shape[:2] != R.shape[:2]:
        raise NodeError(
            f"the left image is {L.shape[1]}x{L.shape[0]} px and the right one "
            f"{R.shape[1]}x{R.shape[0]}: "
            "the two cameras must give images of one size.",
            hint="set both cameras to the resolution they were calibrated at (source.camera: "
            "width_px / "
            "height_px), or give image pairs of one size",
            lasting=True,
        )
    if rectification is not None:
        size = (
            rectification.get("source_size", rectification.get("image_size"))
            if raw
            else rectification.get("image_size")
        )
        if size is not None:
            w, h = (int(x) for x in size)
            if (L.shape[1], L.shape[0]) != (w, h):
                raise NodeError(
                    f"the images are {L.shape[1]}x{L.shape[0]} px but the calibration is "
                    f"for {w}x{h}.",
                    hint="use the cameras at the resolution they were calibrated at "
                    "(source.camera: "
                    "width_px / height_px), or calibrate at this one",
                    lasting=True,
                )
    if L.shape != R.shape:
        return f"mismatched images: left {L.shape} vs right {R.shape} (one colour, one grey?)"
    return None


def pair_is_raw(ctx, rectification: dict | None) -> bool:
    """True when the segmenter's ``pair`` input is wired to camera images (a ``StereoPair``).

    Those are rectified on request (see :mod:`nodes.contracts.views`), which needs the
    Rectification's maps.
    """
    wired = getattr(ctx, "input_types", None) or {}
    if wired.get("pair") != "StereoPair":
        return False
    if rectification is None or "map_left_x" not in rectification:
        raise NodeError(
            "the segmenter's `pair` input gives raw camera images (StereoPair) but no "
            "Rectification "
            "with remap maps is wired to rectify them.",
            hint="wire `rectification: <rectifier.opencv node>.rectification`, or wire `pair` to a "
            "rectifier.remap output.",
        )
    return True
