"""One-pixel images and regions through the segmenters' OpenCV steps.

OpenCV 5.1's Python binding reads a 1x1 array beside a number as a Scalar (the result is 4x1):
every segmenter failed on a scene whose mask had a one-pixel region (nodes.contracts.cv_overloads).
"""

import cv2
import numpy as np
import pytest

from nodes.contracts.cv_overloads import scalar_op
from nodes.contracts.segmenter._color import color_distance_map
from nodes.contracts.segmenter._params import ObjectSpec, ShadowParams
from nodes.contracts.segmenter._pixels import fill_holes
from nodes.contracts.segmenter._shadow import suppress_shadow


def test_scalar_op_keeps_the_shape_of_a_one_pixel_image():
    one = np.full((1, 1), 3.0, np.float32)
    out = scalar_op(cv2.max, one, 5.0)
    assert out.shape == (1, 1) and out[0, 0] == 5.0
    assert scalar_op(cv2.compare, np.zeros((1, 1), np.uint8), 0, cv2.CMP_EQ).tolist() == [[255]]
    wide = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert np.array_equal(scalar_op(cv2.max, wide, 2.0), np.maximum(wide, 2.0))


def test_colour_distance_and_hole_filling_of_one_pixel():
    orange = (20, 120, 245)
    d = color_distance_map(np.uint8([[orange]]), orange)
    assert d.shape == (1, 1) and d[0, 0] < 0.01
    assert fill_holes(np.full((1, 1), 255, np.uint8)).tolist() == [[255]]
    assert fill_holes(np.zeros((1, 1), np.uint8), max_area_px=0.5).tolist() == [[0]]


def test_shadow_suppression_of_a_one_pixel_dark_region():
    img = np.full((20, 20, 3), 150, np.uint8)
    img[10, 10] = 60  # the table's grey, darker: a shadow pixel
    mask = np.zeros((20, 20), np.uint8)
    mask[10, 10] = 255
    out = suppress_shadow(img, mask, ShadowParams(), ObjectSpec(radius_cm=2.0))
    assert out.shape == mask.shape and set(np.unique(out)) <= {0, 255}


def _segmenters_of_a_pair_alone() -> list[str]:
    """Segmenter types that run on a ``pair`` alone (every other input optional)."""
    from stereograph.core import registry

    names = [n for n in registry.names() if n.startswith("segmenter.")]
    return [
        n
        for n in names
        if "pair" in registry.get(n).inputs
        and all(i.optional for k, i in registry.get(n).inputs.items() if k != "pair")
    ]


@pytest.mark.parametrize("seg_type", _segmenters_of_a_pair_alone())
def test_every_segmenter_takes_a_pair_of_any_small_size(seg_type):
    # (OpenCV 5.1's 1x1 trap broke segmenter.color and segmenter.slic on a one-pixel pair)
    from stereograph.core import registry

    spec = registry.get(seg_type)
    params = spec.params(object={"radius_cm": 2.0, "color_bgr": [20, 120, 245]})
    rng = np.random.default_rng(0)
    for h, w in [(1, 1), (1, 2), (2, 1), (1, 9), (9, 1), (2, 2), (3, 3), (5, 7), (16, 16)]:
        for left in (
            rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
            np.full((h, w, 3), 128, np.uint8),
        ):
            left[h // 2, w // 2] = (20, 120, 245)  # one pixel of the ball's colour
            seg = spec.fn(params, pair={"id": "p", "left": left, "right": left.copy()})
            seg = seg["segmentation"]
            assert seg["found"] in (True, False) and (seg["found"] or seg["reason"]), (h, w)
