"""``locator.triangulate``'s overlay: where the ball was located, in the rectified pair, and what it
means.

Left | right rectified images; the located image point in the left view and the matching point
``u - d`` in the right (red circles), joined by their epipolar line (yellow: matching points of a
rectified pair share a row); the segmenter's rejected candidates outlined in orange with the word
why; above them the pair id with x / y / z (cm) and sigma_z, or the whole refusal reason
(labels: ``nodes/contracts/overlay.py``). A camera pair (``StereoPair``) is remapped with the
rectification's maps first, so the marks sit on the pixels they refer to.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nodes.contracts.overlay import draw_rejected, label_pair, location_text


def _bgr(img: np.ndarray) -> np.ndarray:
    import cv2

    img = np.asarray(img)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img[..., :3].copy()


def _rectified(pair: dict, rect: dict, raw: bool) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    L, R = _bgr(pair["left"]), _bgr(pair["right"])
    if raw and "map_left_fixed" in rect:
        L = cv2.remap(L, rect["map_left_fixed"], rect["map_left_interp"], cv2.INTER_LINEAR)
        R = cv2.remap(R, rect["map_right_fixed"], rect["map_right_interp"], cv2.INTER_LINEAR)
    return L, R


def location_overlay(
    loc: dict, disparity: dict, rect: dict, pair: dict | None, raw: bool
) -> np.ndarray:
    """The labelled overlay (BGR uint8) for one Location."""
    import cv2

    if pair is not None and pair.get("left") is not None:
        L, R = _rectified(pair, rect, raw)
    else:  # no images wired: the marks on a grey canvas of the rectified size
        w, h = (int(x) for x in rect.get("image_size", (640, 480)))
        L = np.full((h, w, 3), 90, np.uint8)
        R = L.copy()
    if L.shape != R.shape:
        R = cv2.resize(R, (L.shape[1], L.shape[0]))
    w = L.shape[1]
    img = np.hstack([L, R])
    # The segmenter's rejected candidates (orange, passed on by the disparity estimator).
    draw_rejected(
        img, disparity.get("rejected_left_px"), reasons=disparity.get("rejected_left_why")
    )
    draw_rejected(
        img,
        disparity.get("rejected_right_px"),
        offset_u=w,
        reasons=disparity.get("rejected_right_why"),
    )
    u, v, d = disparity.get("u_left_px"), disparity.get("v_left_px"), disparity.get("disparity_px")
    if u is not None and v is not None and np.isfinite([u, v]).all():
        y = int(round(v))
        cv2.line(img, (0, y), (img.shape[1] - 1, y), (0, 220, 220), 1, cv2.LINE_AA)
        r = max(6, w // 80)
        cv2.circle(img, (int(round(u)), y), r, (0, 0, 255), 2, cv2.LINE_AA)
        if d is not None and np.isfinite(d):
            cv2.circle(img, (int(round(u - d)) + w, y), r, (0, 0, 255), 2, cv2.LINE_AA)
    extra: list[Any] = []
    if loc.get("truth_cm") is not None and loc.get("found"):
        err = np.asarray([loc["x_cm"], loc["y_cm"], loc["z_cm"]]) - np.asarray(
            loc["truth_cm"], float
        )
        extra.append(
            (f"error vs truth: x {err[0]:+.3f}  y {err[1]:+.3f}  z {err[2]:+.3f} cm", (90, 90, 90))
        )
    detail = f"{location_text(loc)}, disparity {d:.2f} px" if loc.get("found") else None
    return label_pair(
        img, loc.get("pair"), bool(loc.get("found")), loc.get("reason"), detail, extra
    )
