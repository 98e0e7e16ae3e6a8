"""The ball's colour learned from training truth (segmenter.appearance), and the ambiguity rule
for a second ball of the object's colour whose outline merged with its shadow (issue 15, item 3)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from nodes.calibrators.truth import truth_calibration
from nodes.contracts.segmenter._color import color_distance_map
from nodes.contracts.segmenter._detect import segment_image
from nodes.contracts.segmenter._params import apply_appearance
from nodes.rectifiers.opencv import rectify_calibration
from nodes.rectifiers.remap import RemapParams, remap
from nodes.segmenters.appearance import AppearanceParams, learn_appearance
from nodes.segmenters.edge_morph import EdgeMorphParams, edge_morph_mask
from nodes.sources.synthetic import SyntheticParams, synthetic
from stereograph.core.api import NodeError

ROOT = Path(__file__).resolve().parents[1]
ORANGE = (20, 120, 245)


@pytest.fixture(scope="module")
def rig():
    src = synthetic(SyntheticParams(n_scenes=8, n_views=0, seed=3))
    rect = rectify_calibration(truth_calibration(src["truth"]))
    pairs = {
        k: remap(RemapParams(), rectification=rect, pair=p)["rectified"]
        for k, p in src["pairs"].items()
    }
    return pairs, rect


def test_learns_the_balls_colour_from_the_training_placements(rig):
    pairs, rect = rig
    out = learn_appearance(pairs, rect, AppearanceParams(), raw=False)
    train = sorted(k for k, p in pairs.items() if p["split"] == "train")
    assert out["pairs"] == train and out["n_pairs"] == len(train) >= 3
    assert out["left_out"] == {}
    # the rendered ball is shaded, so its BGR is darker than the albedo; its chromaticity is the
    # albedo's
    d = color_distance_map(np.uint8([[out["color_bgr"]]]), ORANGE)[0, 0]
    assert d < 0.03, (out["color_bgr"], d)
    assert out["color_tolerance"] == pytest.approx(0.15)  # behaves as a colour given in the YAML
    every = learn_appearance(pairs, rect, AppearanceParams(split="all"), raw=False)
    assert every["n_pairs"] == len(pairs)


def test_camera_pairs_and_table_frame_truth_give_the_same_colour(rig):
    pairs, rect = rig
    src = synthetic(SyntheticParams(n_scenes=8, n_views=0, seed=3))
    ref = learn_appearance(pairs, rect, AppearanceParams(), raw=False)
    raw = learn_appearance(src["pairs"], rect, AppearanceParams(), raw=True)  # rectified on request
    assert raw["color_bgr"] == ref["color_bgr"] and raw["pairs"] == ref["pairs"]
    table_only = {
        k: {**p, "truth": {"center_table_cm": p["truth"]["center_table_cm"]}}
        for k, p in pairs.items()
    }
    T = src["truth"]["T_table_from_left"]
    assert (
        learn_appearance(table_only, rect, AppearanceParams(), raw=False, T_table_from_left=T)[
            "color_bgr"
        ]
        == ref["color_bgr"]
    )
    with pytest.raises(NodeError, match="wire `rig` for a table-frame one"):
        learn_appearance(table_only, rect, AppearanceParams(), raw=False)


def test_a_placement_whose_truth_is_wrong_is_left_out_and_listed(rig):
    pairs, rect = rig
    pairs = dict(pairs)
    pid = sorted(k for k, p in pairs.items() if p["split"] == "train")[0]
    bad = dict(pairs[pid])
    truth = dict(bad["truth"])
    # 6 cm off: the table
    truth["center_left_cm"] = list(np.add(truth["center_left_cm"], [6.0, 0.0, 0.0]))
    bad["truth"] = truth
    pairs[pid] = bad
    out = learn_appearance(pairs, rect, AppearanceParams(), raw=False)
    assert pid in out["left_out"] and "from the others'" in out["left_out"][pid]
    assert pid not in out["pairs"]
    assert color_distance_map(np.uint8([[out["color_bgr"]]]), ORANGE)[0, 0] < 0.03


def test_refuses_clearly_without_truth_or_with_too_few_placements(rig):
    pairs, rect = rig
    bare = {k: {**p, "truth": None} for k, p in pairs.items()}
    with pytest.raises(NodeError, match="none of the 8 pairs is a train placement"):
        learn_appearance(bare, rect, AppearanceParams(), raw=False)
    with pytest.raises(NodeError, match="fewer than min_pairs 50"):
        learn_appearance(pairs, rect, AppearanceParams(min_pairs=50), raw=False)


def test_a_colour_in_the_yaml_wins_and_a_bad_appearance_is_refused():
    given = EdgeMorphParams(object={"color_bgr": [1, 2, 3]})
    learned = {"color_bgr": [10, 90, 180], "color_tolerance": 0.15}
    assert apply_appearance(given, learned) == (given, "params")
    p, src = apply_appearance(EdgeMorphParams(), learned)
    assert src == "appearance" and p.object.color_bgr == (10, 90, 180)
    assert apply_appearance(EdgeMorphParams(), None)[1] is None
    with pytest.raises(NodeError, match="not an ObjectAppearance"):
        apply_appearance(EdgeMorphParams(), {"color_bgr": [300, 0, 0], "color_tolerance": 0.1})


def _two_balls(shadow: bool) -> np.ndarray:
    """Two orange balls of one size on a beige table; the right one's shadow joins its outline."""
    img = np.full((220, 320, 3), (150, 175, 190), np.uint8)
    rng = np.random.default_rng(0)
    img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    if shadow:
        cv2.ellipse(img, (232, 138), (34, 16), 20, 0, 360, (75, 88, 95), -1, cv2.LINE_AA)
    for cx in (90, 215):
        cv2.circle(img, (cx, 110), 24, ORANGE, -1, cv2.LINE_AA)
    return img


def test_a_second_ball_of_the_colour_merged_with_its_shadow_makes_the_result_ambiguous():
    params = EdgeMorphParams(object={"color_bgr": list(ORANGE)}, partial={"enabled": False})
    # without the shadow both balls are round: ambiguous either way
    _, reg, why = segment_image(_two_balls(False), edge_morph_mask, params, (14.0, 40.0))
    assert reg is None and why.startswith("ambiguous"), why
    # with it the right ball's region is not round (or its median colour is pulled towards the
    # shadow's): the left ball must not come out as a confident answer
    params = params.model_copy(
        update={"shadow": params.shadow.model_copy(update={"enabled": False})}
    )
    _, reg, why = segment_image(_two_balls(True), edge_morph_mask, params, (14.0, 40.0))
    assert reg is None and why.startswith("ambiguous"), (why, reg and reg["centroid_px"])


@pytest.mark.slow
def test_locate_learn_pipeline_finds_distractor_scenes_with_no_colour_given(tmp_path):
    """CLI, from a pipeline file: the colour is learned, the distractor scenes are found right, and
    a rerun with a changed segmenter parameter reuses the cached source and remap (a streamed region
    after a gather node recomputes manifest-only items from their cached inputs)."""
    common = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(ROOT / "pipelines" / "locate-learn.yaml"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--set",
        "rig.n_scenes=4",
        "--set",
        "rig.hard_cases=[distractor]",
        "--set",
        "rig.n_hard_each=8",
    ]
    r = subprocess.run(
        common + ["--out", str(tmp_path / "a")], capture_output=True, text=True, timeout=170
    )
    assert r.returncode == 0, r.stderr[-3000:]
    app = json.loads((tmp_path / "a" / "appearance" / "appearance.json").read_text())
    assert color_distance_map(np.uint8([[app["color_bgr"]]]), ORANGE)[0, 0] < 0.03
    locs = json.loads((tmp_path / "a" / "report" / "locations.json").read_text())
    found = [v for v in locs if v["found"]]
    assert len(found) >= 0.75 * len(locs)
    # each result says where its colour came from
    assert {v["color_from"] for v in locs} == {"appearance"}
    for v in found:
        err = np.linalg.norm(np.subtract([v["x_cm"], v["y_cm"], v["z_cm"]], v["truth_cm"]))
        assert err < 1.0, (v["pair"], err)
    r = subprocess.run(
        common + ["--out", str(tmp_path / "b"), "--set", "segment.canny_high=100"],
        capture_output=True,
        text=True,
        timeout=170,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert "internal error" not in r.stderr
