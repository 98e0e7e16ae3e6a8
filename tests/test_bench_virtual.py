"""The virtual bench, end to end: every step a pipeline whose result is a file the next one reads.

The synthetic rig's calibration views, a board lying on the table and ball scenes are saved as
image files, with a truth CSV for the training placements only. Then: calibrate (exports) ->
table frame -> locate + fit compensation (training split from the truth file) -> hand-eye -> a
separate pipeline that loads all of these and locates the remaining placements.
"""

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from nodes.sources._rig import make_rig
from nodes.sources.synthetic import SyntheticParams, _rig_kwargs
from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parents[1]
N_SCENES, N_VIEWS = 24, 10
OBJECT = "{radius_cm: 2.0, color_bgr: [20, 120, 245]}"
# the arm base, in the synthetic rig's own table frame (cm)
BASE_IN_RIG_TABLE = np.array([0.0, 0.0, 0.0])

LOCATE = """
  segment:
    type: segmenter.edge_morph
    params: {{object: {obj}, working_range_cm: [20, 80]}}
    inputs: {{pair: balls.pairs, rectification: rectify.rectification}}
  disparity:
    type: disparity.centroid
    inputs: {{segmentation: segment.segmentation, rectification: rectify.rectification}}
  locate:
    type: locator.triangulate
    params: {{frame: {frame}}}
    inputs: {{disparity: disparity.disparity, rectification: rectify.rectification,
             pair: balls.pairs{rig}}}
"""


def _load_benchmark():
    # the benchmark's own bench writer: the test runs on the very files docs/bench.md's example uses
    spec = importlib.util.spec_from_file_location(
        "virtual_bench", ROOT / "benchmarks" / "virtual_bench.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """The bench's files: calib/, table/, balls/ + truth.csv (training placements only, table
    frame)."""
    root = tmp_path_factory.mktemp("bench")
    written = _load_benchmark().write_bench(root, N_SCENES, N_VIEWS, seed=0)
    T_board = written["T_board_from_left"]
    # the arm base's pose in the board's table frame: the board frame is the rig's, shifted
    rig = make_rig(**_rig_kwargs(SyntheticParams(seed=0)))
    T_rig_from_board = np.asarray(rig["truth"]["T_table_from_left"]) @ np.linalg.inv(T_board)
    base_in_board = (np.linalg.inv(T_rig_from_board) @ [*BASE_IN_RIG_TABLE, 1.0])[:3]
    return {
        "root": root,
        "truth": written["hidden"],
        "T_board_from_left": T_board,
        "base_in_board": base_in_board,
    }


def _run(root, name, text, **kw):
    p = root / f"{name}.yaml"
    p.write_text(f"name: {name}\nnodes:\n{text}")
    r = run_pipeline(p, out_dir=root / "runs" / name, cache_dir=root / "cache", **kw)
    assert r.ok, {n: (r.status[n], r.reports[n].error) for n in r.status}
    return r


def _errors(locations: dict, truth: dict, T=None, split="test") -> np.ndarray:
    errs = []
    for pid, loc in locations.items():
        if truth[pid][0] != split or not loc["found"] or loc.get("extrapolated"):
            continue
        t = truth[pid][1] if T is None else T[:3, :3] @ truth[pid][1] + T[:3, 3]
        errs.append(np.array([loc["x_cm"], loc["y_cm"], loc["z_cm"]]) - t)
    return np.array(errs)


@pytest.mark.slow
def test_virtual_bench(bench):
    root, truth = bench["root"], bench["truth"]
    # 1. calibrate: the calibration, its OpenCV and ROS exports, and the balls located in-pipeline
    cal = _run(
        root,
        "calibrate",
        """
  views: {type: source.calib_files, params: {folder: calib, square_cm: 2.5}}
  calib: {type: calibrator.chessboard, inputs: {views: views.views}}
  rectify: {type: rectifier.opencv, inputs: {calibration: calib.calibration}}
  balls: {type: source.files, params: {folder: balls, truth: truth.csv}}
"""
        + LOCATE.format(obj=OBJECT, frame="left_camera", rig=""),
        keep={"locate"},
    )
    cal_dir = root / "runs" / "calibrate" / "calib"
    assert {
        "calibration.json",
        "opencv.yml",
        "camera_info_left.yaml",
        "camera_info_right.yaml",
    } <= {p.name for p in cal_dir.iterdir()}
    in_pipeline = cal.outputs("locate", "location")

    # 2. the table frame from the board lying on the table (calibration loaded from the OpenCV
    # export)
    _run(
        root,
        "table",
        """
  cal: {type: calibrator.load, params: {path: runs/calibrate/calib/opencv.yml}}
  board: {type: source.calib_files, params: {folder: table, square_cm: 2.5}}
  table: {type: calibrator.table_frame, inputs: {views: board.views, calibration: cal.calibration}}
""",
    )
    tf = json.loads((root / "runs" / "table" / "table" / "table_frame.json").read_text())
    T_meas, T_true = np.array(tf["T_table_from_left"]), bench["T_board_from_left"]
    assert np.abs(T_meas[:3, 3] - T_true[:3, 3]).max() < 0.05
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(T_meas[:3, :3] @ T_true[:3, :3].T)[0])) < 0.05

    # 3. locate + fit compensation on the truth file's placements (camera and table frame), and the
    # hand-eye
    loads = """
  cal: {type: calibrator.load, params: {path: runs/calibrate/calib/calibration.json}}
  tf: {type: calibrator.load_table_frame, params: {path: runs/table/table/table_frame.json},
       inputs: {calibration: cal.calibration}}
  rectify: {type: rectifier.opencv, inputs: {calibration: cal.calibration}}
  balls: {type: source.files, params: {folder: balls, truth: truth.csv}}
"""
    b = bench["base_in_board"]
    fit = _run(
        root,
        "fit",
        loads
        + LOCATE.format(obj=OBJECT, frame="table", rig=", rig: tf.table_frame")
        + f"""
  fit: {{type: compensator.xyz, inputs: {{train: locate.location}}}}
  compensate: {{type: compensator.apply, inputs: {{model: fit.model, location: locate.location}}}}
  cam_locate:
    type: locator.triangulate
    inputs: {{disparity: disparity.disparity, rectification: rectify.rectification,
             pair: balls.pairs, rig: tf.table_frame}}
  cam_fit: {{type: compensator.xyz, inputs: {{train: cam_locate.location}}}}
  cam_compensate: {{type: compensator.apply,
                   inputs: {{model: cam_fit.model, location: cam_locate.location}}}}
  hand_eye:
    type: calibrator.hand_eye
    params: {{mode: rig,
             base_in_table: {{translation_cm: [{b[0]}, {b[1]}, {b[2]}], rpy_deg: [0, 0, 90]}}}}
    inputs: {{table_frame: tf.table_frame}}
""",
        keep={"cam_locate", "cam_compensate", "compensate"},
    )
    # the loaded calibration locates exactly as the in-pipeline one
    loaded = fit.outputs("cam_locate", "location")
    assert set(loaded) == set(in_pipeline) == set(truth)
    for pid, loc in loaded.items():
        assert loc["found"] == in_pipeline[pid]["found"]
        if loc["found"]:
            for k in ("x_cm", "y_cm", "z_cm"):
                assert abs(loc[k] - in_pipeline[pid][k]) < 1e-9
    # the training split came from the truth file: its rows are train, the rest test
    assert {pid: loc["split"] for pid, loc in loaded.items()} == {
        pid: s for pid, (s, _) in truth.items()
    }
    model = json.loads((root / "runs" / "fit" / "fit" / "model.json").read_text())
    assert model["frame"] == "table" and model["rig"]["image_size"] == [640, 480]

    # 4. a separate pipeline loads everything and locates the targets: nothing fitted again
    final = _run(
        root,
        "pick-live",
        loads
        + LOCATE.format(obj=OBJECT, frame="table", rig=", rig: tf.table_frame")
        + """
  model: {type: compensator.load, params: {path: runs/fit/fit/model.json},
          inputs: {calibration: cal.calibration}}
  he: {type: calibrator.load_hand_eye, params: {path: runs/fit/hand_eye/hand_eye.json},
       inputs: {calibration: cal.calibration}}
  compensate: {type: compensator.apply, inputs: {model: model.model, location: locate.location}}
  arm: {type: ik.arm}
  ik:
    type: ik.analytic_3dof
    params: {on_unreachable: skip}
    inputs: {arm: arm.arm, location: compensate.location, hand_eye: he.hand_eye}
""",
        keep={"compensate", "he"},
    )
    kinds = {final.reports[n].type for n in final.status}
    assert not kinds & {
        "calibrator.chessboard",
        "calibrator.table_frame",
        "compensator.xyz",
        "calibrator.hand_eye",
    }
    located, fitted = final.outputs("compensate", "location"), fit.outputs("compensate", "location")
    assert set(located) == set(fitted)
    for pid, loc in located.items():  # the loaded model corrects exactly as the fitted one did
        assert loc["found"] == fitted[pid]["found"]
        if loc["found"]:
            assert max(abs(loc[k] - fitted[pid][k]) for k in ("x_cm", "y_cm", "z_cm")) < 1e-9
    records = json.loads((root / "runs" / "pick-live" / "compensate" / "location.json").read_text())
    assert all("extrapolated" in r and "raw_z_cm" in r for r in records)

    # the test placements' error after compensation, table frame vs camera frame (true frames)
    e_table = _errors(located, truth, T_true)
    e_cam = _errors(fit.outputs("cam_compensate", "location"), truth)
    rms_table, rms_cam = (float(np.sqrt((e**2).sum(1).mean())) for e in (e_table, e_cam))
    print(
        f"\nvirtual bench: {len(e_table)} test placements, 3-D RMS after compensation: table frame "
        f"{rms_table:.4f} cm, camera frame {rms_cam:.4f} cm"
    )
    assert len(e_table) >= N_SCENES // 4
    assert abs(rms_table - rms_cam) < 0.05
    # the hand-eye from the board puts the arm base where it stands
    he = final.outputs("he", "hand_eye")
    rig_T = np.asarray(
        make_rig(**_rig_kwargs(SyntheticParams(seed=0)))["truth"]["T_table_from_left"]
    )
    base_in_left = np.linalg.inv(he["T_base_from_left"])[:3, 3]
    assert np.abs((rig_T[:3, :3] @ base_in_left + rig_T[:3, 3]) - BASE_IN_RIG_TABLE).max() < 0.1
    assert any(t.get("found") for t in final.outputs("ik", "target").values())
