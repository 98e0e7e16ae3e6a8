"""Issue 15: partial views, touching objects, no colour given, channels (small and fast; the full
per-kind figures are printed by benchmarks/locate_hard.py)."""

from __future__ import annotations

import numpy as np
import pytest

from nodes.calibrators.truth import truth_calibration
from nodes.contracts.segmenter._partial import cone_center_px, fit_cone, fit_partial, rays
from nodes.disparity.ellipse import EllipseParams, ellipse
from nodes.locators.triangulate import TriangulateParams, triangulate
from nodes.rectifiers.opencv import rectify_calibration
from nodes.rectifiers.remap import RemapParams, remap
from nodes.segmenters.color import ColorParams, color
from nodes.segmenters.edge_morph import EdgeMorphParams, edge_morph
from nodes.sources.synthetic import SyntheticParams, synthetic

ORANGE = [20, 120, 245]


def _sphere_outline(K, centre, radius, n=400):
    c = np.asarray(centre, float)
    d = np.linalg.norm(c)
    a = c / d
    sa = radius / d
    e1 = np.cross(a, [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = np.sqrt(1 - sa * sa) * a + sa * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
    p = r @ K.T
    return p[:, :2] / p[:, 2:], K @ a / (K @ a)[2]


def test_cone_fit_on_a_third_of_the_outline_finds_the_centre_image():
    K = np.array([[515.0, 0, 320], [0, 515.0, 240], [0, 0, 1]])
    pts, centre = _sphere_outline(K, [9.0, -4.0, 40.0], 2.0)
    arc = pts[:133]  # 120 degrees of the outline
    fit = fit_cone(rays(arc, K), 515.0)
    (u, v), s_u = cone_center_px(fit["w"], K, fit["cov"])
    assert abs(u - centre[0]) < 0.01 and abs(v - centre[1]) < 0.01
    assert 0 < s_u < 0.5  # the noise floor (0.1 px) over a third of the outline
    # A shorter arc is less certain: the threshold that refuses it comes from this figure.
    fit_short = fit_cone(rays(pts[:40], K), 515.0)
    assert cone_center_px(fit_short["w"], K, fit_short["cov"])[1] > s_u


def test_fit_partial_leaves_out_border_points_and_an_occluder_edge():
    K = np.array([[515.0, 0, 320], [0, 515.0, 240], [0, 0, 1]])
    pts, centre = _sphere_outline(K, [14.0, 0.0, 40.0], 2.0)  # near u = 500
    pts = pts[pts[:, 0] < 505.0]  # cut by a border at u = 505
    border = np.stack([np.full(30, 505.0), np.linspace(pts[:, 1].min(), pts[:, 1].max(), 30)], 1)
    chord = np.stack([np.linspace(470, 490, 30), np.full(30, 250.0)], 1)  # a straight foreign edge
    img = np.full((480, 640, 3), 128, np.uint8)
    fit = fit_partial(
        np.concatenate([pts, border, chord]), img, (0, 0), (506, 480), K, (10.0, 40.0)
    )
    assert fit["ok"] and fit["cause"].startswith("border: right")
    assert np.hypot(*(np.subtract(fit["center_px"], centre[:2]))) < 0.05


@pytest.fixture(scope="module")
def hard():
    src = synthetic(
        SyntheticParams(
            n_scenes=0,
            n_views=0,
            seed=3,
            n_hard_each=2,
            hard_cases=["border_cut", "touching_box", "touching_ball", "same_color", "distractor"],
        )
    )
    rect = rectify_calibration(truth_calibration(src["truth"]))
    pairs = [
        remap(RemapParams(), rectification=rect, pair=p)["rectified"] for p in src["pairs"].values()
    ]
    return pairs, rect


def _locate(node, params, pair, rect):
    seg = node(params, pair=pair, rectification=rect)["segmentation"]
    d = ellipse(EllipseParams(), segmentation=seg, rectification=rect)["disparity"]
    return triangulate(TriangulateParams(), disparity=d, rectification=rect, pair=pair)["location"]


def _err(loc):
    return float(
        np.linalg.norm(np.subtract([loc["x_cm"], loc["y_cm"], loc["z_cm"]], loc["truth_cm"]))
    )


@pytest.mark.slow
def test_partial_and_touching_balls_are_found_and_right_with_the_colour(hard):
    pairs, rect = hard
    params = ColorParams(object={"radius_cm": 2.0, "color_bgr": ORANGE}, overlay=False)
    n_found = 0
    for p in pairs:
        loc = _locate(color, params, p, rect)
        if p["id"].startswith("same_color"):
            assert not loc["found"] or _err(loc) < 1.0, p["id"]
            continue
        if loc["found"]:
            n_found += 1
            assert _err(loc) < 1.0, (p["id"], _err(loc))
    assert n_found >= 7  # of the 8 scenes with one orange ball


def test_no_colour_never_gives_a_confident_wrong_answer(hard):
    pairs, rect = hard
    params = EdgeMorphParams(object={"radius_cm": 2.0}, overlay=False)
    n_ambiguous = 0
    for p in pairs:
        loc = _locate(edge_morph, params, p, rect)
        assert not loc["found"] or _err(loc) < 1.0, (p["id"], loc["reason"])
        n_ambiguous += "ambiguous" in (loc["reason"] or "")
    assert n_ambiguous >= 2  # two balls alike: refused with the reason, not guessed


def test_auto_channel_picks_a_plane_where_an_orange_ball_stands_out_on_grey():
    from nodes.contracts.segmenter._channel import best_plane, normalize_exposure

    rng = np.random.default_rng(0)
    # grey as bright as orange
    img = np.clip(rng.normal(145, 12, (120, 160, 3)), 0, 255).astype(np.uint8)
    img[40:70, 60:90] = (20, 120, 245)
    name, contrast = best_plane(img, ORANGE)
    assert name in ("blue", "red", "saturation") and contrast[name] > contrast["gray"]
    dim = (img * 0.3).astype(np.uint8)
    assert np.percentile(normalize_exposure(dim[..., 2]), 99) >= 250  # stretched back


@pytest.mark.slow
def test_dim_scene_is_found_with_the_auto_channel_not_with_gray():
    from nodes.disparity.centroid import CentroidParams, centroid

    src = synthetic(SyntheticParams(n_scenes=3, n_views=0, seed=5, ambient=0.2))
    rect = rectify_calibration(truth_calibration(src["truth"]))
    rng = np.random.default_rng(0)
    found = {}
    for ch in ("gray", "auto"):
        params = EdgeMorphParams(
            object={"radius_cm": 2.0, "color_bgr": ORANGE}, channel=ch, overlay=False
        )
        found[ch] = 0
        for p in src["pairs"].values():
            q = dict(p)
            for k in ("left", "right"):
                q[k] = np.clip(p[k] * 0.3 + rng.normal(0, 1.0, p[k].shape), 0, 255).astype(np.uint8)
            r = remap(RemapParams(), rectification=rect, pair=q)["rectified"]
            seg = edge_morph(params, pair=r, rectification=rect)["segmentation"]
            d = centroid(CentroidParams(), segmentation=seg, rectification=rect)["disparity"]
            loc = triangulate(TriangulateParams(), disparity=d, rectification=rect, pair=r)[
                "location"
            ]
            if loc["found"]:
                assert _err(loc) < 0.5
                found[ch] += 1
    assert found["auto"] == 3 and found["gray"] < found["auto"]


@pytest.mark.parametrize("r", [4.0, 6.0, 9.0, 15.0, 30.0])
def test_the_visible_share_of_a_small_whole_outline_is_all_of_it(r):
    # A pixel outline has ~1 point per px: 72 bins of 5 degrees left half of them empty on a
    # whole ball of 6 px radius (far away, or small), which was then reported "42 % of the outline
    # visible" (found on a 2 cm ball at 100-200 cm); the bins now hold >= 2 px of outline each.
    import cv2

    from nodes.contracts.segmenter._partial import coverage

    c = 50.0
    disc = np.zeros((100, 100), np.uint8)
    cv2.circle(disc, (50, 50), int(r), 255, -1)
    cnt = (
        cv2.findContours(disc, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)[0][0]
        .reshape(-1, 2)
        .astype(float)
    )
    assert coverage(cnt, np.array([c, c]), r) >= 0.95
    upper = cnt[cnt[:, 1] < c - 0.5]  # half the outline (a lower half hidden)
    assert 0.4 <= coverage(upper, np.array([c, c]), r) <= 0.6


@pytest.mark.slow
def test_a_small_far_ball_seen_whole_is_refused_as_small_not_as_occluded(tmp_path):
    """(plain 2 cm balls at 100-200 cm, nothing in front of them, were refused as "occluded or
    touching another object"; the cause is a ~6 px silhouette: too few outline pixels)"""
    from pathlib import Path

    import stereograph

    far = {
        "rig.n_scenes": 20,
        "rig.camera_height_cm": 40,
        "rig.camera_tilt_deg": 15,
        "rig.min_distance_cm": 100,
        "rig.max_distance_cm": 200,
        "objects.working_range_cm": [80, 220],
        "disparity.working_range_cm": [80, 220],
        "locate.working_range_cm": [80, 220],
    }
    pipeline = Path(__file__).resolve().parents[1] / "pipelines" / "locate.yaml"
    res = stereograph.run(
        pipeline, far, use_cache=False, keep=["locate"], out_dir=tmp_path / "out", progress=False
    )
    reasons = [r["reason"] for r in res.outputs("locate", "location").values() if not r["found"]]
    assert reasons and all(r.startswith("the ball is small in the") for r in reasons), reasons
    assert not any("occluded" in r for r in reasons)


@pytest.mark.slow
def test_a_view_that_lost_the_balls_dark_side_is_refused_not_located():
    """(dim side light, ambient 0.05: the unlit half of the ball merges with the dark table in one
    view only; that silhouette still fits an ellipse, its size passed max_size_mismatch (15 %) and
    its area max_area_ratio, and the pair was located 0.9 cm off here -- 1.8 cm with a chessboard
    calibration)"""
    from nodes.disparity.centroid import CentroidParams, centroid

    centres = [[0.114, 10.823], [-7.699, -11.477]]  # on the table, cm
    scenes = [{"id": f"side{i}", "ball": {"center_cm": c}} for i, c in enumerate(centres)]
    params = EdgeMorphParams(object={"radius_cm": 2.0, "color_bgr": ORANGE}, overlay=False)
    reasons = {}
    for light in ({"ambient": 0.05, "light_cm": (60, -40, 40)}, {}):
        src = synthetic(SyntheticParams(n_scenes=0, n_views=0, seed=0, scenes=scenes, **light))
        rect = rectify_calibration(truth_calibration(src["truth"]))
        for p in src["pairs"].values():
            r = remap(RemapParams(), rectification=rect, pair=p)["rectified"]
            seg = edge_morph(params, pair=r, rectification=rect)["segmentation"]
            d = centroid(CentroidParams(), segmentation=seg, rectification=rect)["disparity"]
            loc = triangulate(TriangulateParams(), disparity=d, rectification=rect, pair=r)[
                "location"
            ]
            if not light:  # the same placements in the default light: found, and right
                assert loc["found"] and _err(loc) < 0.2, (p["id"], loc["reason"])
            else:
                assert not loc["found"], (p["id"], _err(loc))
                reasons[p["id"]] = loc["reason"]
    assert "the left and right silhouettes are not one ball's" in reasons["side1"], reasons
    assert "the right view sees only part of the ball" in reasons["side1"], reasons
