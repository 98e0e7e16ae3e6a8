"""Issue 14: the candidates a segmenter turned down are kept (small outlines with a one-word
reason) and outlined in orange in the segment and locator overlays."""

from __future__ import annotations

import numpy as np
import pytest

from nodes.calibrators.truth import truth_calibration
from nodes.contracts.overlay import REJECTED_BGR
from nodes.contracts.segmenter._detect import MAX_REJECTED, MAX_REJECTED_POINTS
from nodes.disparity.ellipse import EllipseParams, ellipse
from nodes.locators.triangulate import TriangulateParams, triangulate
from nodes.rectifiers.opencv import rectify_calibration
from nodes.rectifiers.remap import RemapParams, remap
from nodes.segmenters.edge_morph import EdgeMorphParams, edge_morph
from nodes.sources.synthetic import SyntheticParams, synthetic

ORANGE = [20, 120, 245]


@pytest.fixture(scope="module")
def distractor():
    src = synthetic(
        SyntheticParams(n_scenes=0, n_views=0, seed=3, n_hard_each=2, hard_cases=["distractor"])
    )
    rect = rectify_calibration(truth_calibration(src["truth"]))
    pairs = [
        remap(RemapParams(), rectification=rect, pair=p)["rectified"] for p in src["pairs"].values()
    ]
    return pairs, rect


def _chroma(bgr):
    f = np.asarray(bgr, float)
    return f / max(f.sum(), 1.0)


def _check_shape(seg):
    for side in ("left", "right"):
        px, why = seg[f"rejected_{side}_px"], seg[f"rejected_{side}_why"]
        assert len(px) == len(why) <= MAX_REJECTED
        for c, w in zip(px, why):
            assert c.ndim == 2 and c.shape[1] == 2 and 3 <= len(c) <= MAX_REJECTED_POINTS
            assert w in ("size", "round", "colour", "smaller", "ambiguous")


@pytest.mark.slow
def test_a_distractor_of_another_colour_is_kept_as_rejected_and_drawn_in_orange(distractor):
    pairs, rect = distractor
    params = EdgeMorphParams(object={"radius_cm": 2.0, "color_bgr": ORANGE})
    for pair in pairs:
        out = edge_morph(params, pair=pair, rectification=rect)
        seg = out["segmentation"]
        assert seg["found"], seg["reason"]
        _check_shape(seg)
        img = np.asarray(pair["left"])
        centre = np.asarray(seg["left"]["centroid_px"])
        r_ball = np.sqrt(seg["left"]["area_px"] / np.pi)
        colour = [
            c for c, w in zip(seg["rejected_left_px"], seg["rejected_left_why"]) if w == "colour"
        ]
        assert colour, seg["rejected_left_why"]
        c = colour[0]
        m = np.round(c.mean(axis=0)).astype(int)
        # The outline is another object: away from the ball, around pixels that are not orange.
        assert np.hypot(*(m - centre)) > 2 * r_ball
        assert (
            np.abs(_chroma(img[m[1], m[0]]) - _chroma(ORANGE)).sum() > params.object.color_tolerance
        )
        # Outlined in orange in the segmenter's overlay (left half; the label band is above it).
        over = out["overlay"]
        band = over.shape[0] - img.shape[0]
        u, v = int(c[0, 0]), int(c[0, 1]) + band
        patch = over[max(0, v - 1) : v + 2, max(0, u - 1) : u + 2].reshape(-1, 3).astype(int)
        assert (np.abs(patch - REJECTED_BGR).sum(axis=1) < 60).any()
        # ... and passed on to the locator's overlay through the Disparity.
        d = ellipse(EllipseParams(), segmentation=seg, rectification=rect)["disparity"]
        assert len(d["rejected_left_px"]) == len(seg["rejected_left_px"])
        lo = triangulate(TriangulateParams(), disparity=d, rectification=rect, pair=pair)["overlay"]
        v = int(c[0, 1]) + lo.shape[0] - img.shape[0]
        patch = lo[max(0, v - 1) : v + 2, max(0, u - 1) : u + 2].reshape(-1, 3).astype(int)
        assert (np.abs(patch - REJECTED_BGR).sum(axis=1) < 60).any()


def test_without_colour_both_balls_are_rejected_as_ambiguous(distractor):
    pairs, rect = distractor
    params = EdgeMorphParams(object={"radius_cm": 2.0}, overlay=False)
    for pair in pairs:
        seg = edge_morph(params, pair=pair, rectification=rect)["segmentation"]
        assert not seg["found"] and "ambiguous" in seg["reason"]
        _check_shape(seg)
        assert seg["rejected_left_why"].count("ambiguous") == 2
