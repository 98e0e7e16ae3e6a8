"""Labels for per-pair overlays: which pair, what was found, or the whole reason it was not.

One place for every node that draws a left | right overlay (segmenters, ``locator.triangulate``):

- :func:`label_pair` puts a text band above the picture: the pair id and the result (green) or
  the full refusal reason (red), wrapped to the image width -- never cut at the image edge;
- :func:`draw_rejected` outlines candidate regions that were considered and rejected, in orange,
  so the chosen region (green, drawn by the node) stands out from the ones that lost.

A segmenter that keeps its rejected candidates may put their outlines in its Segmentation as
``rejected_left_px`` / ``rejected_right_px`` (lists of Nx2 contours, rectified px) with one-word
reasons in ``rejected_left_why`` / ``rejected_right_why``; the segmenters' ``draw_overlay`` passes
them here, and the disparity estimators copy them into the Disparity for ``locator.triangulate``'s
overlay.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nodes.contracts.drawing import caption

FOUND_BGR = (0, 130, 0)
REFUSED_BGR = (0, 0, 200)
REJECTED_BGR = (0, 140, 255)  # orange: candidates that were not the ball


def location_text(loc: dict[str, Any]) -> str:
    """``x 1.23  y -4.56  z 45.67 cm  sigma_z 0.031 cm (left_camera)`` for a found Location."""
    sz = loc.get("sigma_z_cm")
    return (
        f"x {loc['x_cm']:.2f}  y {loc['y_cm']:.2f}  z {loc['z_cm']:.2f} cm"
        + (f"  sigma_z {sz:.3f} cm" if sz is not None else "")
        + f" ({loc.get('frame', '')} frame)"
    )


def label_pair(
    img: np.ndarray,
    pair_id: Any,
    found: bool,
    reason: str | None,
    detail: str | None = None,
    extra: list[str] | None = None,
) -> np.ndarray:
    """``img`` with a band above it: ``pair <id>: <detail>`` (green) or ``pair <id>: NOT FOUND:
    <reason>`` (red)."""
    if found:
        lines: list[Any] = [(f"pair {pair_id}: {detail or 'found'}", FOUND_BGR)]
    else:
        lines = [(f"pair {pair_id}: NOT FOUND: {reason or 'no reason given'}", REFUSED_BGR)]
    lines += list(extra or [])
    return caption(img, lines)


def draw_rejected(img: np.ndarray, contours: Any, offset_u: int = 0, reasons: Any = None) -> int:
    """Outline rejected candidate regions (Nx2 px contours) on ``img`` in orange, in place; returns
    how many.

    ``reasons``, optional: one word per contour (why it lost: size, round, colour, ...), written
    beside its outline.
    """
    import cv2

    n = 0
    reasons = list(reasons or [])
    for i, c in enumerate(contours or []):
        c = np.asarray(c, np.float64).reshape(-1, 2)
        if len(c) < 3:
            continue
        pts = np.round(c + [offset_u, 0]).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], True, REJECTED_BGR, 1, cv2.LINE_AA)
        if i < len(reasons) and reasons[i]:
            x, y = int(pts[:, 0, 0].min()), int(pts[:, 0, 1].min())
            cv2.putText(
                img,
                str(reasons[i]),
                (x, max(10, y - 3)),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.35,
                REJECTED_BGR,
                1,
                cv2.LINE_AA,
            )
        n += 1
    return n
