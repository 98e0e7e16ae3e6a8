"""The reasons a segmented pair is refused must name the view that is wrong, with its own
figures."""

from __future__ import annotations

import math

import numpy as np

from nodes.contracts.segmenter._checks import check_pair
from nodes.contracts.segmenter._params import SegmenterParams

F, B = 500.0, 8.0


def _region(u: float, r_px: float) -> dict:
    ell = {
        "center_px": [u, 240.0],
        "axes_px": [r_px, r_px],
        "angle_deg": 0.0,
        "rms_px": 0.05,
        "inliers": 200,
    }
    return {
        "ellipse": ell,
        "centroid_px": [u, 240.0],
        "area_px": math.pi * r_px**2,
        "touches_border": False,
    }


def test_size_mismatch_names_the_view_whose_size_is_off():
    """A ball at 40 cm (disparity 100 px): the left silhouette has the right size, the right one is
    25 % too large. The reason quoted the left view's distance (40 cm, which fits) as the one that
    did not fit, so a person read '40.0 cm vs 40.0 cm' as refused for nothing."""
    rect = {
        "P1": np.array([[F, 0, 320, 0], [0, F, 240, 0], [0, 0, 1, 0]]),
        "P2": np.array([[F, 0, 320, -F * B], [0, F, 240, 0], [0, 0, 1, 0]]),
    }
    r_px = F * math.tan(math.asin(2.0 / 40.0))
    left, right = _region(320.0 + 50.0, r_px), _region(320.0 - 50.0, 1.25 * r_px)
    why = check_pair(left, right, SegmenterParams(object={"radius_cm": 2.0}), rect)
    assert why is not None and "size does not fit" in why, why
    assert "right" in why, why
    z_right = float(why.split("size gives ")[1].split(" cm")[0])
    assert z_right < 35.0, why  # the right view's own figure (~32 cm), not the left's 40


def test_size_mismatch_in_both_views_blames_the_radius():
    rect = {
        "P1": np.array([[F, 0, 320, 0], [0, F, 240, 0], [0, 0, 1, 0]]),
        "P2": np.array([[F, 0, 320, -F * B], [0, F, 240, 0], [0, 0, 1, 0]]),
    }
    r_px = 1.3 * F * math.tan(math.asin(2.0 / 40.0))  # a 2.6 cm ball, the YAML says 2 cm
    why = check_pair(
        _region(370.0, r_px), _region(270.0, r_px), SegmenterParams(object={"radius_cm": 2.0}), rect
    )
    assert why is not None and "object.radius_cm is wrong" in why and "left image and" in why, why


def test_a_partial_fit_that_saw_the_whole_outline_is_not_called_occluded():
    """(a small ball whose outline had a few points off its edge was refused as 'occluded or
    touching another object ..., 100 % of the outline visible': nothing hid it)"""
    rect = {
        "P1": np.array([[F, 0, 320, 0], [0, F, 240, 0], [0, 0, 1, 0]]),
        "P2": np.array([[F, 0, 320, -F * B], [0, F, 240, 0], [0, 0, 1, 0]]),
    }
    r_px = F * math.tan(math.asin(2.0 / 40.0))
    whys = []
    for visible in (1.0, 0.6):
        # the right size, but its centre known only to 3 px: sigma_z ~1.7 cm
        right = _region(270.0, r_px)
        right["partial"] = {
            "outline_visible": visible,
            "cause": "occluded or touching",
            "sigma_u_px": 3.0,
            "radius_px": r_px,
            "sigma_size_rel": 0.001,
        }
        right["sigma_centroid_px"] = 3.0
        whys.append(
            check_pair(
                _region(370.0, r_px), right, SegmenterParams(object={"radius_cm": 2.0}), rect
            )
        )
    assert (
        whys[0] is not None
        and "occluded" not in whys[0]
        and "strays from the ball's edge" in whys[0]
    ), whys[0]
    assert "too little to locate it" in whys[0], whys[0]
    assert (
        whys[1] is not None
        and "occluded or touching another object in the right image, 60 %" in whys[1]
    ), whys[1]
