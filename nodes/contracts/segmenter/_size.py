"""Expected image size of the ball (from the calibration and the working range) and the
detection downscale it allows.
"""

from __future__ import annotations

import math

from ._params import SegmenterParams


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
