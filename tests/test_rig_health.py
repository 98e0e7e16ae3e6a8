"""rectifier.check: a calibration checked against the pictures it is applied to (issue 30).

Swapped cameras, a camera rotated 0.5 deg after calibration, another rig's calibration and another
resolution are refused or warned with the cause named, whichever file the calibration was loaded
from (a run's JSON, OpenCV YAML, a ROS camera_info pair); an untouched rig passes, on the synthetic
rig and on OpenCV's real chessboard pairs.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from nodes.rectifiers.check import CheckParams, epipolar_check
from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parents[1]
CHESS = ROOT.parent / "shared" / "data" / "opencv-stereo-chessboard"
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The synthetic rig calibrated once (its three files), and four scene pairs of it."""
    tmp = tmp_path_factory.mktemp("health")
    cal = run_pipeline(
        ROOT / "pipelines" / "calibrate.yaml",
        ["rig.n_views=10"],
        cache_dir=tmp / "c",
        out_dir=tmp / "cal",
    )
    assert cal.ok
    scenes = run_pipeline(
        ROOT / "pipelines" / "locate.yaml",
        ["rig.n_scenes=4", "rig.n_views=0"],
        cache_dir=tmp / "c",
        out_dir=tmp / "scenes",
        only="rig",
    )
    pairs = list(scenes.outputs("rig", "pairs").values())
    return cal.out_dir / "calib", pairs, tmp


def _rectification(tmp: Path, path: Path, right: Path | None = None) -> dict:
    from nodes.calibrators.load import read_calibration_file
    from nodes.rectifiers.opencv import RectifyParams, opencv

    return opencv(RectifyParams(), read_calibration_file(path, right))["rectification"]


def _rotated(img, deg: float):
    h, w = img.shape[:2]
    return cv2.warpAffine(img, cv2.getRotationMatrix2D((w / 2, h / 2), deg, 1.0), (w, h))


@pytest.mark.parametrize("fmt", ["json", "opencv", "ros"])
def test_each_fault_is_named_whatever_file_the_calibration_came_from(rig, fmt):
    folder, pairs, tmp = rig
    files = {
        "json": (folder / "calibration.json", None),
        "opencv": (folder / "opencv.yml", None),
        "ros": (folder / "camera_info_left.yaml", folder / "camera_info_right.yaml"),
    }[fmt]
    rect = _rectification(tmp, *files)
    p = CheckParams()
    assert epipolar_check(rect, pairs, p)["verdict"] == "ok"
    swapped = epipolar_check(
        rect, [{**q, "left": q["right"], "right": q["left"]} for q in pairs], p
    )
    assert swapped["verdict"] == "refuse" and "swapped" in swapped["cause"]
    moved = epipolar_check(rect, [{**q, "right": _rotated(q["right"], 0.5)} for q in pairs], p)
    assert moved["verdict"] in ("warn", "refuse") and "a camera moved" in moved["cause"], moved
    small = [
        {
            **q,
            "left": cv2.resize(q["left"], (320, 240)),
            "right": cv2.resize(q["right"], (320, 240)),
        }
        for q in pairs
    ]
    other = epipolar_check(rect, small, p)
    assert other["verdict"] == "refuse" and "another resolution" in other["cause"]


def test_another_rigs_calibration_is_refused_or_warned(rig, tmp_path):
    _, pairs, tmp = rig
    other = run_pipeline(
        ROOT / "pipelines" / "calibrate.yaml",
        ["rig.n_views=10", "rig.rotation_deg=[1.5, -2, 1]", "rig.baseline_cm=12"],
        cache_dir=tmp / "c",
        out_dir=tmp_path / "other",
    )
    if not other.ok:
        pytest.skip(f"the other rig did not calibrate: {other.reports}")
    rect = _rectification(tmp, other.out_dir / "calib" / "calibration.json")
    got = epipolar_check(rect, pairs, CheckParams())
    assert got["verdict"] in ("warn", "refuse"), got


@pytest.mark.skipif(not CHESS.is_dir(), reason="OpenCV's chessboard pairs not in ../shared/data")
def test_real_chessboard_pairs_pass_and_swapped_ones_are_refused(tmp_path):
    p = tmp_path / "real.yaml"
    p.write_text(f"""name: real
nodes:
  rig: {{type: source.calib_files, params: {{folder: '{CHESS}', square_cm: 2.5}}}}
  calib: {{type: calibrator.chessboard, inputs: {{views: rig.views}}}}
  rectify: {{type: rectifier.opencv, inputs: {{calibration: calib.calibration}}}}
  pairs: {{type: source.files, params: {{folder: '{CHESS}'}}}}
  check: {{type: rectifier.check,
          inputs: {{rectification: rectify.rectification, pairs: pairs.pairs}}}}
""")
    res = run_pipeline(p, [], cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    assert res.ok and res.outputs("check", "health")["verdict"] == "ok", res.outputs(
        "check", "health"
    )
    bad = run_pipeline(
        p,
        ["pairs.left_glob=*right*", "pairs.right_glob=*left*"],
        cache_dir=tmp_path / "c",
        out_dir=tmp_path / "o2",
    )
    assert not bad.ok and "swapped" in bad.reports["check"].error


def test_the_live_gate_checks_every_nth_pair_and_a_refusal_stops_the_loop(rig):
    from nodes.rectifiers.check import GateParams, gate
    from stereograph.core.api import NodeError, RunContext

    folder, pairs, tmp = rig
    rect = _rectification(tmp, folder / "calibration.json")
    ctx = RunContext("gate", None, tmp / "gate", tmp, resources={})
    params = GateParams(every_n=3)
    checked = []
    for k in range(6):
        out = gate(params, rect, pairs[k % len(pairs)], ctx=ctx)
        assert out["pair"] is pairs[k % len(pairs)] and out["health"]["verdict"] == "ok"
        checked.append(out["health"]["n_matches"])
    # pairs 1 and 4 checked, the others not
    assert len(set(checked[:3])) == 1 and len(set(checked[3:])) == 1
    swapped = {**pairs[0], "left": pairs[0]["right"], "right": pairs[0]["left"]}
    with pytest.raises(NodeError) as e:
        gate(params, rect, swapped, ctx=RunContext("gate", None, tmp / "gate", tmp, resources={}))
    assert e.value.lasting and "swapped" in e.value.message


ALOE = ROOT.parent / "shared" / "data" / "middlebury-aloe-opencv"


@pytest.mark.skipif(not ALOE.is_dir(), reason="the Aloe pair is not in ../shared/data")
def test_a_real_rectified_pair_with_its_given_camera_passes(tmp_path):
    """Aloe is rectified already (rectifier.given states its camera): its rows agree."""
    from nodes.rectifiers.given import GivenParams, given

    rect = given(
        GivenParams(
            f_px=3740.0,
            cx_px=640.5,
            cy_px=554.5,
            cx_right_px=910.5,
            baseline_cm=16.0,
            image_size=(1282, 1110),
        )
    )["rectification"]
    pair = {
        "id": "aloe",
        "left": cv2.imread(str(ALOE / "aloeL.jpg")),
        "right": cv2.imread(str(ALOE / "aloeR.jpg")),
    }
    got = epipolar_check(rect, [pair], CheckParams())
    assert got["verdict"] == "ok" and got["dy_systematic_px"] < 0.3, got
    swapped = epipolar_check(
        rect, [{**pair, "left": pair["right"], "right": pair["left"]}], CheckParams()
    )
    assert swapped["verdict"] == "refuse" and "swapped" in swapped["cause"], swapped
