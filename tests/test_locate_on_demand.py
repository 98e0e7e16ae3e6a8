"""Segmenters given raw camera images rectify only what they read (nodes/rectifiers/_views.py).

The on-demand path must agree with the explicit ``rectifier.remap`` path: the full-resolution
windows are the very pixels of the full remap, the coarse level is the pyramid of the rectified
image up to interpolation, and the located centroids agree to a few thousandths of a pixel.
"""

from __future__ import annotations

import textwrap

import cv2
import numpy as np
import pytest

from nodes.calibrators.truth import truth_calibration
from nodes.contracts.segmenter._pixels import masked_pixels
from nodes.contracts.views import RectifiedView, pair_views
from nodes.rectifiers.opencv import rectify_calibration
from nodes.sources.synthetic import SyntheticParams, synthetic
from stereograph.core.runner import run_pipeline

PIPELINE = """\
name: on-demand
nodes:
  rig: {type: source.synthetic, params: {n_scenes: 10, n_views: 0, seed: 3}}
  calib: {type: calibrator.truth, inputs: {truth: rig.truth}}
  rectify: {type: rectifier.opencv, inputs: {calibration: calib.calibration}}
  remap: {type: rectifier.remap, inputs: {rectification: rectify.rectification, pair: rig.pairs}}
  seg_remapped:
    type: segmenter.edge_morph
    params: {object: {radius_cm: 2.0, color_bgr: [20, 120, 245]}}
    inputs: {pair: remap.rectified, rectification: rectify.rectification}
  seg_raw:
    type: segmenter.edge_morph
    params: {object: {radius_cm: 2.0, color_bgr: [20, 120, 245]}}
    inputs: {pair: rig.pairs, rectification: rectify.rectification}
"""


@pytest.fixture(scope="module")
def rig():
    src = synthetic(SyntheticParams(n_scenes=2, n_views=0, seed=5))
    return list(src["pairs"].values()), rectify_calibration(truth_calibration(src["truth"]))


def test_windows_are_the_full_remap_pixels_and_coarse_is_its_pyramid(rig):
    pairs, rect = rig
    p = pairs[0]
    full = cv2.remap(p["left"], rect["map_left_fixed"], rect["map_left_interp"], cv2.INTER_LINEAR)
    view, _ = pair_views(rect, p["left"], p["right"], raw=True)
    assert view.shape == full.shape and view.is_raw
    for u0, v0, u1, v1 in [(0, 0, 640, 480), (101, 37, 250, 199), (600, 400, 640, 480)]:
        assert np.array_equal(view.window(u0, v0, u1, v1), full[v0:v1, u0:u1])
    for scale in (2, 4):
        ref = full
        for _ in range(scale.bit_length() - 1):
            ref = cv2.pyrDown(ref)
        got = view.coarse(scale, 0, 0, 640, 480)
        assert got.shape == ref.shape
        inner = (slice(8, -8), slice(8, -8))
        assert np.abs(got[inner].astype(int) - ref[inner]).mean() < 2.0  # gray levels
        # A band (cropped raw pyramid, bounded by the map positions the level samples) equals
        # the same band of the whole-image coarse level, inside the image and at its corners.
        for u0, v0, u1, v1 in [
            (64, 96, 320, 224),
            (0, 0, 128, 96),
            (512, 384, 640, 480),
            (200, 8, 456, 121),
        ]:
            band = view.coarse(scale, u0, v0, u1, v1)
            assert np.array_equal(
                band, got[v0 // scale : -(-v1 // scale), u0 // scale : -(-u1 // scale)]
            )
    # An already rectified image is sliced and pyrDown'ed.
    plain = RectifiedView(full)
    assert not plain.is_raw and np.array_equal(plain.window(5, 6, 50, 60), full[6:60, 5:50])


def test_masked_pixels_is_a_fast_boolean_gather():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    mask = rng.random((40, 50)) > 0.6
    assert np.array_equal(masked_pixels(img, mask), img[mask])
    sub = img[5:30, 7:41]  # a strided window
    assert np.array_equal(masked_pixels(sub, mask[5:30, 7:41]), sub[mask[5:30, 7:41]])
    assert np.array_equal(masked_pixels(img[..., 0], mask), img[..., 0][mask])


@pytest.mark.slow
def test_raw_pairs_segment_like_remapped_pairs(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(PIPELINE)
    res = run_pipeline(f, cache_dir=tmp_path / "cache", out_dir=tmp_path / "out", use_cache=False)
    assert res.ok, res.status
    a, b = res.outputs("seg_remapped", "segmentation"), res.outputs("seg_raw", "segmentation")
    assert sum(s["found"] for s in a.values()) >= 8
    for k in a:
        assert a[k]["found"] == b[k]["found"], (k, a[k]["reason"], b[k]["reason"])
        if a[k]["found"]:
            for side in ("left", "right"):
                assert b[k][f"{side}_mask"].shape == (480, 640)
                np.testing.assert_allclose(
                    b[k][side]["centroid_px"], a[k][side]["centroid_px"], atol=0.02
                )
    # The overlay of the raw path shows the rectified images the masks refer to.
    ov_a, ov_b = res.outputs("seg_remapped", "overlay"), res.outputs("seg_raw", "overlay")
    k = next(iter(ov_a))
    # (the two views side by side, under a caption band that says which pair and what was found)
    assert (
        ov_b[k].shape == ov_a[k].shape and ov_a[k].shape[1:] == (1280, 3) and ov_a[k].shape[0] > 480
    )
    assert np.abs(ov_b[k].astype(int) - ov_a[k]).mean() < 1.0


def test_raw_pairs_without_a_rectification_are_refused_clearly(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(
        textwrap.dedent("""\
        name: no-rect
        nodes:
          rig: {type: source.synthetic, params: {n_scenes: 2, n_views: 0, seed: 1}}
          seg:
            type: segmenter.edge_morph
            inputs: {pair: rig.pairs}
        """)
    )
    res = run_pipeline(f, cache_dir=tmp_path / "cache", out_dir=tmp_path / "out", use_cache=False)
    assert not res.ok
    msg = res.reports["seg"].error
    assert "StereoPair" in msg and "rectification" in res.reports["seg"].hint


def test_band_pyramid_margin_holds_on_texture(rig):
    """On noise (no smooth area to hide a border effect) a band's cropped pyramid still equals the
    whole-image coarse level: the crop's margin covers pyrDown's reach at every level."""
    _, rect = rig
    noise = np.random.default_rng(1).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    maps = {
        "x": rect["map_left_x"],
        "y": rect["map_left_y"],
        "fixed": rect.get("map_left_fixed"),
        "interp": rect.get("map_left_interp"),
    }
    for scale in (2, 4, 8):
        whole = RectifiedView(noise, maps).coarse(scale, 0, 0, 640, 480)
        for u0, v0, u1, v1 in [
            (64, 96, 320, 224),
            (200, 8, 456, 121),
            (512, 384, 640, 480),
            (328, 240, 413, 301),
        ]:
            band = RectifiedView(noise, maps).coarse(scale, u0, v0, u1, v1)
            assert np.array_equal(
                band, whole[v0 // scale : -(-v1 // scale), u0 // scale : -(-u1 // scale)]
            )
