"""calibrator.charuco on synthetic ChArUco views (source.synthetic board_type=charuco)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nodes.calibrators.charuco import CharucoParams, charuco, detect_charuco
from nodes.contracts.board import charuco_board
from nodes.sources._boards import board_corners_3d, random_board_poses, render_board_view
from nodes.sources._lens import project_points
from nodes.sources._rig import make_rig
from nodes.sources.synthetic import SyntheticParams, synthetic
from stereograph.core.api import NodeError

CHARUCO = {"dictionary": "DICT_4X4_50", "marker_fraction": 0.7}


@pytest.fixture(scope="module")
def views():
    out = synthetic(SyntheticParams(n_scenes=0, n_views=12, board_type="charuco", seed=0))["views"]
    return out


def _partial_view(views):
    """A board pushed half out of the left image's right edge (still partly in both images)."""
    rig = make_rig()
    pose = random_board_poses(rig, 1, np.random.default_rng(99))[0]
    K, D = rig["truth"]["K1"], rig["truth"]["D1"]
    pts = board_corners_3d(9, 6, 2.5)
    while (project_points(K, D, pts @ pose[:3, :3].T + pose[:3, 3])[:, 0] > 640).mean() < 0.3:
        pose[0, 3] += 0.5  # cm to the right, until a third of the corners have left the left image
    left, right, corners = render_board_view(rig, pose, seed=5, charuco=CHARUCO)
    return {"id": "partial", "left": left, "right": right}, corners


@pytest.mark.slow
def test_charuco_views_rendered(views):
    assert views["board"] == {
        "cols": 9,
        "rows": 6,
        "square_cm": 2.5,
        "type": "charuco",
        "dictionary": "DICT_4X4_50",
        "marker_fraction": 0.7,
    }
    rig = make_rig()
    pose = random_board_poses(rig, 1, np.random.default_rng(3))[0]
    left, _, corners = render_board_view(rig, pose, seed=1, charuco=CHARUCO)
    board = charuco_board(9, 6, 2.5)
    ids, px = detect_charuco(left, cv2.aruco.CharucoDetector(board))
    assert len(ids) == 54
    err = np.linalg.norm(px - corners["left_px"][ids], axis=1)
    assert err.max() < 0.3, err.max()


@pytest.mark.slow
def test_charuco_recovers_rig(views):
    partial, corners = _partial_view(views)
    w = views["image_size"][0]
    assert (corners["left_px"][:, 0] > w).sum() > 5  # really partly out of frame
    v = dict(views, views=views["views"] + [partial])
    cal = charuco(CharucoParams(), views=v)["calibration"]
    t = views["truth"]
    fx = [cal[k][0, 0] / t[k][0, 0] - 1 for k in ("K1", "K2")]
    fy = [cal[k][1, 1] / t[k][1, 1] - 1 for k in ("K1", "K2")]
    base = np.linalg.norm(cal["T_cm"]) / np.linalg.norm(t["T_cm"]) - 1
    rot = np.degrees(np.linalg.norm(cv2.Rodrigues(cal["R"] @ t["R"].T)[0]))
    print(
        f"fx err {np.round(np.array(fx) * 100, 3)} %, fy err {np.round(np.array(fy) * 100, 3)} %, "
        f"baseline err {base * 100:.3f} %, rotation err {rot:.4f} deg, rms {cal['rms_px']:.3f} px"
    )
    assert max(map(abs, fx + fy)) < 0.005
    assert abs(base) < 0.005
    assert rot < 0.1
    # the partial view contributes: used, with fewer corners than a full board
    assert "partial" in cal["per_view_rms_px"] and "partial" not in cal["rejected_views"]
    assert 8 <= len(cal["corner_ids"]["partial"]) < 54
    assert cal["method"] == "charuco/joint"


@pytest.mark.slow
def test_charuco_too_few_corners(views):
    blank = np.full((480, 640, 3), 128, np.uint8)
    v = dict(
        views,
        views=[{"id": f"b{i}", "left": blank, "right": blank} for i in range(3)]
        + views["views"][:1],
    )
    with pytest.raises(NodeError, match=r"only 1 of 4 views.*b0: 0 corners"):
        charuco(CharucoParams(), views=v)


def test_charuco_refuses_chessboard_views():
    v = {
        "views": [
            {"id": "a", "left": np.zeros((48, 64), np.uint8), "right": np.zeros((48, 64), np.uint8)}
        ],
        "image_size": [64, 48],
        "board": {"cols": 9, "rows": 6, "square_cm": 2.5},
    }
    with pytest.raises(NodeError, match="not a ChArUco board"):
        charuco(CharucoParams(), views=v)


def test_charuco_bad_dictionary():
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        SyntheticParams(board_type="charuco", aruco_dict="DICT_9X9")
