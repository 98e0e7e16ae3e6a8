"""The synthetic renderer is self-consistent: silhouettes, centroids, projections, determinism, hard
scenes."""

import cv2
import numpy as np
import pytest

from nodes.sources import _lens
from nodes.sources._lens import project_points, undistort_pixels
from nodes.sources._render import render_scene
from nodes.sources._rig import make_rig
from nodes.sources._scenes import SCENE_KINDS, make_scene


@pytest.fixture(scope="module")
def rig():
    return make_rig()


def _centroid(cov):
    v, u = np.mgrid[: cov.shape[0], : cov.shape[1]]
    return np.array([(cov * u).sum(), (cov * v).sum()]) / cov.sum()


@pytest.mark.slow
def test_rendered_centroid_matches_exact_silhouette(rig):
    """Coverage centroid vs the exact (distorted) silhouette's area centroid, many placements, both
    cameras."""
    gaps = []
    for i in range(10):
        scene = make_scene(rig, "plain", np.random.default_rng([5, i]))
        _, _, t = render_scene(rig, scene, seed=i, noise_sigma=0, coverage=True)
        for side in ("left", "right"):
            sil = t[f"silhouette_{side}"]
            err = _centroid(t[f"coverage_{side}"].astype(float)) - sil["centroid_px"]
            assert np.hypot(*err) < 0.05, (i, side, err)
            assert abs(t[f"coverage_{side}"].sum() / sil["area_px"] - 1) < 2e-3
            gaps.append(np.hypot(*(np.subtract(sil["centroid_px"], sil["center_px"]))))
    # The silhouette's centroid is not the image of the centre (the gap the locators must handle).
    assert max(gaps) > 0.1


@pytest.mark.slow
def test_ideal_camera_silhouette_is_tangent_cone_ellipse():
    """Without distortion the rendered outline's centroid is the tangent-cone ellipse's centre."""
    rig = make_rig(distortion_left=(0, 0, 0, 0), distortion_right=(0, 0, 0, 0))
    for i in range(4):
        scene = make_scene(rig, "plain", np.random.default_rng([9, i]))
        _, _, t = render_scene(rig, scene, seed=i, noise_sigma=0, coverage=True)
        sil = t["silhouette_left"]
        ell = sil["ellipse_px"]
        assert np.allclose(sil["centroid_px"], ell["center_px"], atol=1e-3)
        assert np.hypot(*(_centroid(t["coverage_left"].astype(float)) - ell["center_px"])) < 0.05
        a, b = ell["axes_px"]
        assert abs(np.pi * a * b / sil["area_px"] - 1) < 1e-4


@pytest.mark.slow
def test_triangulating_true_centres_returns_true_centre(rig):
    tr = rig["truth"]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([tr["R"], tr["T_cm"].reshape(3, 1)])
    for i in range(10):
        scene = make_scene(rig, "plain", np.random.default_rng([11, i]))
        _, _, t = render_scene(rig, scene, seed=i)
        nl = cv2.undistortPoints(
            np.array([[t["center_px_left"]]]), tr["K1"], tr["D1"], criteria=crit
        ).reshape(2, 1)
        nr = cv2.undistortPoints(
            np.array([[t["center_px_right"]]]), tr["K2"], tr["D2"], criteria=crit
        ).reshape(2, 1)
        X = cv2.triangulatePoints(P1, P2, nl, nr)
        X = (X[:3] / X[3]).ravel()
        assert np.linalg.norm(X - t["center_left_cm"]) < 1e-4
        # ... and the table-frame truth is the same point.
        T = tr["T_table_from_left"]
        assert np.allclose(T[:3, :3] @ X + T[:3, 3], t["center_table_cm"], atol=1e-4)


def test_camera_model_inverse_is_exact(rig):
    cam = rig["cams"][0]
    px = np.random.default_rng(0).uniform([0, 0], [639, 479], (500, 2))
    xy = undistort_pixels(cam["K"], cam["D"], px)
    back = project_points(cam["K"], cam["D"], np.column_stack([xy, np.ones(len(xy))]))
    assert np.abs(back - px).max() < 1e-9
    ref, _ = cv2.projectPoints(
        np.column_stack([xy, np.ones(len(xy))]), np.zeros(3), np.zeros(3), cam["K"], cam["D"]
    )
    assert np.abs(ref.reshape(-1, 2) - px).max() < 1e-6


def test_camera_model_inverse_is_exact_over_many_blocks(rig):
    """A whole image's worth of pixels (several of undistort_normalized's blocks, the last one
    partial), with and without a starting guess: every point is inverted as exactly as one alone."""
    cam = rig["cams"][1]
    n = 2 * _lens._BLOCK + 777
    px = np.random.default_rng(1).uniform([0, 0], [639, 479], (n, 2))
    for guess in (None, np.zeros((n, 2))):
        yd = (px[:, 1] - cam["K"][1, 2]) / cam["K"][1, 1]
        xd = (px[:, 0] - cam["K"][0, 2] - cam["K"][0, 1] * yd) / cam["K"][0, 0]
        xy = _lens.undistort_normalized(np.stack([xd, yd], axis=1), cam["D"], guess=guess)
        back = project_points(cam["K"], cam["D"], np.column_stack([xy, np.ones(n)]))
        assert np.abs(back - px).max() < 1e-9
        alone = [
            _lens.undistort_normalized(
                np.stack([xd[k : k + 1], yd[k : k + 1]], axis=1),
                cam["D"],
                guess=None if guess is None else guess[k : k + 1],
            )
            for k in (0, _lens._BLOCK - 1, _lens._BLOCK, n - 1)
        ]
        assert np.array_equal(np.concatenate(alone), xy[[0, _lens._BLOCK - 1, _lens._BLOCK, n - 1]])


def test_deterministic_and_noisy(rig):
    scene = make_scene(rig, "plain", 3)
    a = render_scene(rig, scene, seed=1)
    b = render_scene(rig, scene, seed=1)
    c = render_scene(rig, scene, seed=2)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    assert a[0].shape == (480, 640, 3) and a[0].dtype == np.uint8
    # The ball really is where the truth says: its colour at the true centre's pixel.
    u, v = (int(round(x)) for x in a[2]["center_px_left"])
    b_, g_, r_ = a[0][v, u].astype(int)
    assert r_ > g_ > b_


@pytest.mark.slow
def test_hard_scene_kinds(rig):
    rng = np.random.default_rng(4)
    for kind in SCENE_KINDS:
        scene = make_scene(rig, kind, rng)
        left, right, t = render_scene(rig, scene, seed=0)
        if kind == "empty":
            assert t is None
            continue
        assert t["kind"] == kind
        if kind == "border":
            assert t["touches_border_left"] and 0.05 < t["visible_fraction_left"] < 0.999
        elif kind == "occluded":
            assert 0.05 < t["visible_fraction_left"] < 0.97
        elif kind == "hidden":
            assert t["visible_fraction_left"] < 0.01
        elif kind == "border_cut":  # issue 15: 40-90 % visible in the less visible view
            assert 0.35 < min(t["visible_fraction_left"], t["visible_fraction_right"]) < 0.95
        elif kind == "occluded_part":  # 50-95 % visible in the left view
            assert 0.45 < t["visible_fraction_left"] < 0.98
        elif kind in ("touching_box", "touching_ball", "distractor", "same_color"):
            assert t["visible_fraction_left"] > 0.95 and len(scene["objects"]) == 1
        else:
            assert t["visible_fraction_left"] > 0.99 and not t["touches_border_left"]
        if kind in ("clutter", "second_ball"):
            assert len(scene["objects"]) >= 1


def test_explicit_scene_and_bad_colour(rig):
    scene = {
        "ball": {"center_cm": [0.0, 5.0], "radius_cm": 2.5, "color": [0, 200, 0]},
        "objects": [
            {
                "type": "cylinder",
                "center_cm": [8, 8],
                "radius_cm": 1.5,
                "height_cm": 6,
                "color": "blue",
            }
        ],
    }
    _, _, t = render_scene(rig, scene)
    assert t["radius_cm"] == 2.5 and t["center_table_cm"] == [0.0, 5.0, 2.5]
    with pytest.raises(ValueError, match="unknown colour"):
        render_scene(rig, {"ball": {"center_cm": [0, 5], "color": "mauve"}})
