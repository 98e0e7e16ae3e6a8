"""Shadow suppression works on the mask's bounding box plus a frame
(nodes/contracts/segmenter/_shadow.py): the result must be that of the whole window, pixel for
pixel."""

from __future__ import annotations

import cv2
import numpy as np

from nodes.contracts.segmenter._params import ObjectSpec, ShadowParams
from nodes.contracts.segmenter._shadow import _suppress, suppress_shadow


def _scene(rng, h=90, w=110):
    """Textured table, an orange ball and its grey shadow; the mask covers ball + shadow."""
    img = np.clip(rng.normal(150, 25, (h, w, 3)), 0, 255).astype(np.uint8)
    cu, cv_, r = (
        int(rng.integers(20, w - 20)),
        int(rng.integers(20, h - 20)),
        int(rng.integers(6, 15)),
    )
    shadow = np.zeros((h, w), np.uint8)
    cv2.ellipse(shadow, (cu + r // 2, cv_ + r // 2), (r + 3, r // 2 + 2), 20, 0, 360, 255, -1)
    img[shadow > 0] = (img[shadow > 0] * 0.45).astype(np.uint8)
    cv2.circle(img, (cu, cv_), r, (20, 120, 245), -1)
    mask = shadow.copy()
    cv2.circle(mask, (cu, cv_), r, 255, -1)
    return img, mask


def test_cropped_suppression_equals_the_whole_window():
    rng = np.random.default_rng(7)
    shadow = ShadowParams()
    changed = 0
    for color in ((20, 120, 245), None):
        obj = ObjectSpec(radius_cm=2.0, color_bgr=color)
        for _ in range(25):
            img, mask = _scene(rng)
            whole = _suppress(img, mask, cv2.countNonZero(mask), shadow, obj, img, mask)
            whole = mask if whole is None else whole
            got = suppress_shadow(img, mask, shadow, obj)
            assert np.array_equal(got, whole)
            changed += int(np.count_nonzero(got != mask) > 0)
    assert changed > 10  # the scenes do have shadow pixels to remove
