"""Dense disparity as a product (issue 15, item 6): rectifier.given, disparity.dense, PLY output.

The real check runs pipelines/dense-aloe.yaml through the CLI on the Middlebury Aloe pair and scores
the saved map against its ground truth; the rest are small synthetic cases of the pieces.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from nodes.contracts.disparity_scores import bad_pixels
from nodes.disparity._ply import decode_ply, encode_ply
from nodes.disparity.dense import DenseParams, dense, dense_disparity, point_cloud, search_range_px
from nodes.locators.triangulate import triangulate_point
from nodes.rectifiers.given import GivenParams, given
from nodes.rectifiers.remap import RemapParams, remap
from nodes.sources._files import pair_key
from stereograph.app.cli import main as cli_main
from stereograph.core.api import NodeError
from stereograph.core.outputs import write_collection, write_value

ROOT = Path(__file__).resolve().parents[1]
ALOE = ROOT.parent / "shared" / "data" / "middlebury-aloe-opencv"
GIVEN = {"f_px": 500.0, "cx_px": 80.0, "cy_px": 60.0, "baseline_cm": 10.0, "image_size": (160, 120)}


def textured_pair(shift_px: int, seed: int = 0, size=(120, 160)):
    """A random-texture plane seen with a constant disparity of shift_px (left x = right x +
    shift)."""
    rng = np.random.default_rng(seed)
    h, w = size
    tex = cv2.GaussianBlur(rng.integers(0, 256, (h, w + shift_px), dtype=np.uint8), (3, 3), 0.8)
    left = cv2.cvtColor(np.ascontiguousarray(tex[:, :w]), cv2.COLOR_GRAY2BGR)
    right = cv2.cvtColor(np.ascontiguousarray(tex[:, shift_px : shift_px + w]), cv2.COLOR_GRAY2BGR)
    return left, right


def test_given_rectification_passes_images_through_and_triangulates_with_doffs():
    rect = given(GivenParams(**GIVEN, cx_right_px=95.0))["rectification"]
    left, right = textured_pair(12)
    out = remap(RemapParams(), rectification=rect, pair={"id": "p", "left": left, "right": right})[
        "rectified"
    ]
    assert np.array_equal(out["left"], left) and np.array_equal(out["right"], right)
    # Z = f B / (d + doffs), x, y from the left principal point, frame = left camera (R1 = I).
    p = triangulate_point(100.0, 30.0, 35.0, rect)
    z = 500.0 * 10.0 / (35.0 + 15.0)
    np.testing.assert_allclose(p, [(100 - 80) * z / 500, (30 - 60) * z / 500, z], rtol=1e-12)


def test_pair_names_with_a_trailing_capital_side_letter():
    assert pair_key("aloeL") == pair_key("aloeR") == "aloe"
    assert pair_key("left01") == pair_key("right01") == "01"  # unchanged
    assert pair_key("view1") == "view1"  # no side token: left alone


def test_dense_map_of_a_known_shift_and_its_point_cloud():
    left, right = textured_pair(24)
    rect = given(GivenParams(**GIVEN))["rectification"]
    params = DenseParams(disparity_range_px=(8, 60))
    d_min, num = search_range_px(rect, params)
    assert d_min == 8 and num % 16 == 0 and d_min + num - 1 >= 60
    disp = dense_disparity(left, right, d_min, num, params)
    ok = np.isfinite(disp)
    assert ok.mean() > 0.6  # the padded left border is matched too wherever its partner is in view
    assert (
        np.median(np.abs(disp[ok] - 24.0)) < 0.25 and np.mean(np.abs(disp[ok] - 24.0) > 1.0) < 0.02
    )
    pts, rgb = point_cloud(disp, left, rect)
    assert len(pts) == ok.sum() and rgb.dtype == np.uint8
    # a plane 208 cm away
    np.testing.assert_allclose(np.median(pts[:, 2]), 500 * 10 / 24, rtol=0.01)


def test_dense_node_outputs_and_clear_errors(tmp_path):
    left, right = textured_pair(24)
    rect = given(GivenParams(**GIVEN))["rectification"]
    pair = {"id": "p", "left": left, "right": right, "split": "test"}
    out = dense(DenseParams(working_range_cm=(100.0, 400.0)), pair=pair, rectification=rect)
    dmap, img, cloud = out["disparity_map"], out["disparity_image"], out["point_cloud"]
    # fB/400 = 12.5
    assert dmap["disparity_px"].dtype == np.float32 and dmap["search_range_px"][0] == 12
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert (img[~np.isfinite(dmap["disparity_px"])] == 0).all()
    files = write_value(tmp_path / "cloud", cloud)
    assert [f.name for f in files] == ["cloud.ply"]
    pts, _, comments = decode_ply(files[0].read_bytes())
    assert len(pts) == cloud["n_points"] > 0 and "units cm" in comments
    # A collection of file values becomes one file per item; other dicts stay JSON.
    files = write_collection(tmp_path / "coll", {"a": cloud, "b": cloud})
    assert sorted(f.name for f in files) == ["a.ply", "b.ply"]
    assert write_value(tmp_path / "plain", {"file_suffix": ".ply", "n": 1})[0].suffix == ".json"

    with pytest.raises(NodeError, match="at most 1024"):
        dense(DenseParams(working_range_cm=(1.0, 400.0)), pair=pair, rectification=rect)
    with pytest.raises(ValueError, match="must exceed p1_factor"):  # (pydantic's ValidationError)
        DenseParams(p1_factor=40.0)
    small = dict(pair, left=left[:100], right=right[:100])
    with pytest.raises(NodeError, match="rectification is for 160x120"):
        dense(DenseParams(), pair=small, rectification=rect)


def test_ply_round_trip():
    pts = np.array([[1.5, -2.0, 30.0], [0.0, 0.0, 1e3]], dtype=np.float32)
    rgb = np.array([[255, 0, 10], [1, 2, 3]], dtype=np.uint8)
    p, c, comments = decode_ply(encode_ply(pts, rgb, ["units cm"]))
    assert np.array_equal(p, pts) and np.array_equal(c, rgb) and comments == ["units cm"]


@pytest.mark.slow
@pytest.mark.skipif(not (ALOE / "aloeGT.png").exists(), reason="../shared/data not present")
def test_dense_aloe_pipeline_through_the_cli(tmp_path):
    out = tmp_path / "run"
    rc = cli_main(
        [
            "run",
            str(ROOT / "pipelines" / "dense-aloe.yaml"),
            "--out",
            str(out),
            "--cache-dir",
            str(tmp_path / "cache"),
        ]
    )
    assert rc == 0
    rec = json.loads((out / "dense" / "disparity_map.json").read_text())[0]
    disp = np.load(out / "dense" / "disparity_map.npz")[rec["disparity_px"]["npz"]]
    gt = cv2.imread(str(ALOE / "aloeGT.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    fill, bad = bad_pixels(disp, gt, 2.0)
    assert fill >= 0.72 and bad <= 0.038, (fill, bad)  # plain StereoSGBM: 3.77 % at 72.5 %
    # report.disparity's Metrics (what `stereograph compare` tabulates) hold the same scores.
    metrics = json.loads((out / "dense-score" / "metrics.json").read_text())
    assert metrics["n_pairs"] == 1 and metrics["bad_2px_fraction"] == pytest.approx(bad, abs=1e-9)
    assert metrics["fill_fraction"] == pytest.approx(fill, abs=1e-9)
    img = cv2.imread(str(out / "dense" / "disparity_image" / "aloe.png"))
    assert img.shape == (1110, 1282, 3)
    pts, rgb, _ = decode_ply((out / "dense" / "point_cloud" / "aloe.ply").read_bytes())
    assert len(pts) == np.isfinite(disp).sum()
    # Metric, left-camera frame: the scene's depths within the 1.2-2 m the pipeline searched.
    assert 115 < np.percentile(pts[:, 2], 1) and np.percentile(pts[:, 2], 99) < 205
    assert "point_cloud/aloe.ply" in " ".join(
        f for n in json.loads((out / "run.json").read_text())["nodes"] for f in n["files"]
    )


def test_point_cloud_is_metric_in_the_left_camera_frame_on_the_synthetic_rig():
    # The synthetic rig through rectifier.opencv (R1 != I): the cloud's table points must lie on the
    # true table plane (T_table_from_left maps left-camera points into the table frame, table at z =
    # 0).
    from nodes.calibrators.truth import truth_calibration
    from nodes.rectifiers.opencv import rectify_calibration
    from nodes.rectifiers.remap import remap_pair
    from nodes.sources.synthetic import synthetic

    rig = synthetic(
        synthetic.spec.params(n_scenes=1, n_views=0, min_distance_cm=30, max_distance_cm=60, seed=1)
    )
    rect = rectify_calibration(truth_calibration(rig["truth"]))
    pair = next(iter(rig["pairs"].values()))
    left, right = remap_pair(rect, pair["left"], pair["right"])
    params = DenseParams(working_range_cm=(20.0, 150.0))
    disp = dense_disparity(left, right, *search_range_px(rect, params), params)
    pts, _ = point_cloud(disp, left, rect)
    T = np.asarray(rig["truth"]["T_table_from_left"])
    z_table = (pts @ T[:3, :3].T + T[:3, 3])[:, 2]
    assert np.mean(np.abs(z_table) < 0.3) > 0.75  # 84 % measured: most of the view is table
    c = np.asarray(pair["truth"]["center_left_cm"])
    near_ball = np.linalg.norm(pts - c, axis=1) < 1.5 * pair["truth"]["radius_cm"]
    assert near_ball.sum() > 500  # the ball is in the cloud where it truly is


def test_disparity_score_names_a_missing_or_mismatched_truth(tmp_path):
    from nodes.reports.disparity import DisparityScoreParams, disparity_score

    disp = np.full((4, 6), 10.0, dtype=np.float32)
    disp[0, 0] = np.nan
    maps = {"p1": {"id": "p1", "disparity_px": disp, "compute_seconds": 0.5}}
    truth = np.full((4, 6), 10, dtype=np.uint8)
    truth[1, :] = 20  # 6 of the 23 filled pixels are 10 px off
    truth[3, 5] = 0  # unknown
    cv2.imwrite(str(tmp_path / "p1GT.png"), truth)
    out = disparity_score(DisparityScoreParams(truth=str(tmp_path / "{id}GT.png")), maps)
    assert out["metrics"]["n_pairs"] == 1 and out["metrics"]["match_s"] == 0.5
    assert out["metrics"]["fill_fraction"] == pytest.approx(22 / 23)
    assert out["metrics"]["bad_2px_fraction"] == pytest.approx(6 / 22)
    with pytest.raises(NodeError, match="no readable truth image for pair 'p1'"):
        disparity_score(DisparityScoreParams(truth=str(tmp_path / "missing.png")), maps)
    cv2.imwrite(str(tmp_path / "small.png"), truth[:2])
    with pytest.raises(NodeError, match="6x2 px"):
        disparity_score(DisparityScoreParams(truth=str(tmp_path / "small.png")), maps)


@pytest.mark.parametrize(
    "setting, expected",
    [
        ("dense.working_range_cm=[-10,200]", "must start above 0"),
        ("dense.working_range_cm=[200,120]", "first value must be below the second"),
        ("dense.disparity_range_px=[80,20]", "first value must be below the second"),
        ("dense.p2_factor=4", "p2_factor (4) must exceed p1_factor (8)"),
        ("dense.block_size_px=4", "block size must be odd"),
    ],
)
def test_dense_params_are_refused_when_the_pipeline_is_validated(setting, expected, capsys):
    # (these were found only when the node ran, after its upstream nodes: exit 1, not 2)
    code = cli_main(["validate", str(ROOT / "pipelines" / "dense-aloe.yaml"), "--set", setting])
    out = capsys.readouterr()
    msg = " ".join((out.out + out.err).split())
    assert code == 2 and expected in msg and "node 'dense'" in msg and setting in msg


@pytest.mark.skipif(not (ALOE / "aloeGT.png").exists(), reason="../shared/data not present")
@pytest.mark.parametrize(
    "names, stored",
    [
        # Middlebury 2003: quarter size, disparity x 4 in a PNG
        (("im2.png", "im6.png", "disp2.png"), "x4"),
        # Middlebury 2014: disparity in px in a PFM, inf unknown
        (("im0.png", "im1.png", "disp0.pfm"), "pfm"),
    ],
)
def test_a_middlebury_folder_is_paired_and_scored_against_its_own_truth(tmp_path, names, stored):
    """(issue 30: disp2 / disp6 as truth) no globs, no truth path, no scale: the source finds the
    truth beside the left image and the report reads its scale from the data."""
    import yaml

    scene = tmp_path / "Aloe"
    scene.mkdir()
    small = [
        cv2.resize(cv2.imread(str(ALOE / f)), (320, 277), interpolation=cv2.INTER_AREA)
        for f in ("aloeL.jpg", "aloeR.jpg")
    ]
    gt = (
        cv2.resize(
            cv2.imread(str(ALOE / "aloeGT.png"), cv2.IMREAD_GRAYSCALE),
            (320, 277),
            interpolation=cv2.INTER_NEAREST,
        ).astype(np.float32)
        / 4
    )  # px at quarter size
    cv2.imwrite(str(scene / names[0]), small[0])
    cv2.imwrite(str(scene / names[1]), small[1])
    if stored == "pfm":
        cv2.imwrite(str(scene / names[2]), np.where(gt > 0, gt, np.inf).astype(np.float32))
    else:
        cv2.imwrite(str(scene / names[2]), np.round(gt * 4).astype(np.uint8))
    doc = {
        "name": "mb",
        "nodes": {
            "pairs": {"type": "source.files", "params": {"folder": str(scene)}},
            "rectify": {
                "type": "rectifier.given",
                "params": {
                    "f_px": 935.0,
                    "cx_px": 160.0,
                    "cy_px": 138.0,
                    "cx_right_px": 227.5,
                    "baseline_cm": 16.0,
                    "image_size": [320, 277],
                },
            },
            "remap": {
                "type": "rectifier.remap",
                "inputs": {"rectification": "rectify.rectification", "pair": "pairs.pairs"},
            },
            "dense": {
                "type": "disparity.dense",
                "params": {"working_range_cm": [120.0, 200.0]},
                "inputs": {"pair": "remap.rectified", "rectification": "rectify.rectification"},
            },
            "score": {
                "type": "report.disparity",
                "inputs": {"disparity_map": "dense.disparity_map"},
            },
        },
    }
    (tmp_path / "mb.yaml").write_text(yaml.safe_dump(doc))
    out = tmp_path / "run"
    assert cli_main(["run", str(tmp_path / "mb.yaml"), "--out", str(out), "--no-cache"]) == 0
    from nodes.sources.files import FilesParams, _reads

    assert scene / names[2] in _reads(FilesParams(folder=str(scene)), tmp_path)  # in the cache key
    row = json.loads((out / "score" / "pairs.json").read_text())[0]
    assert row["pair"] == "Aloe" and row["truth"] == names[2]
    assert row["truth_scale"] == (1.0 if stored == "pfm" else 0.25)
    # 0.9 %; a wrong scale: ~100 %
    assert row["fill_fraction"] > 0.6 and row["bad_2px_fraction"] < 0.05, row
