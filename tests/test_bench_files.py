"""Calibration files in and out (OpenCV FileStorage, ROS camera_info), and the loader nodes."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from nodes.calibrators._calib_io import read_ros_pair
from nodes.calibrators.chessboard import ChessboardParams, chessboard
from nodes.calibrators.load import read_calibration_file
from nodes.contracts.calibration_export import export_texts
from nodes.sources.calib_files import CalibFilesParams, calib_files
from stereograph.core.api import NodeError
from stereograph.core.outputs import write_value
from stereograph.core.runner import run_pipeline

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "opencv-stereo-chessboard"


def _calibration():
    """A plausible calibration with distortion and a slightly rotated right camera (cm)."""
    R, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))
    return {
        "K1": np.array([[515.3, 0, 321.7], [0, 514.9, 238.2], [0, 0, 1.0]]),
        "D1": np.array([-0.12, 0.05, 0.001, -0.0005, 0.01]),
        "K2": np.array([[516.1, 0, 318.4], [0, 515.8, 241.0], [0, 0, 1.0]]),
        "D2": np.array([-0.11, 0.04, -0.0007, 0.0004, 0.0]),
        "R": R,
        "T_cm": np.array([-8.01, 0.05, 0.12]),
        "image_size": [640, 480],
        "rms_px": 0.21,
        "per_view_rms_px": {},
        "rejected_views": [],
        "method": "test",
    }


def _write_exports(cal, folder: Path) -> dict:
    paths = {}
    for name, value in export_texts(cal).items():
        paths[name] = write_value(folder / name, value)[0]
    return paths


def _assert_same(a, b, tol=1e-9):
    for k in ("K1", "D1", "K2", "D2", "R", "T_cm"):
        assert np.abs(np.asarray(a[k], float) - np.asarray(b[k], float)).max() < tol, k
    assert list(a["image_size"]) == list(b["image_size"])


def test_opencv_export_reads_back_with_filestorage(tmp_path):
    cal = _calibration()
    p = _write_exports(cal, tmp_path)["opencv"]
    assert p.name == "opencv.yml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    got = {
        k: fs.getNode(k).mat()
        for k in ("M1", "D1", "M2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q")
    }
    assert fs.getNode("unit").string() == "cm" and int(fs.getNode("image_width").real()) == 640
    fs.release()
    assert np.abs(got["M1"] - cal["K1"]).max() < 1e-9 and np.abs(got["M2"] - cal["K2"]).max() < 1e-9
    assert (
        np.abs(got["D1"].ravel() - cal["D1"]).max() < 1e-9
        and np.abs(got["D2"].ravel() - cal["D2"]).max() < 1e-9
    )
    assert (
        np.abs(got["R"] - cal["R"]).max() < 1e-9
        and np.abs(got["T"].ravel() - cal["T_cm"]).max() < 1e-9
    )
    # P2's Tx is -f' B in the file's unit (cm), as stereoRectify gives it
    assert got["P2"][0, 3] / got["P2"][0, 0] == pytest.approx(
        -np.linalg.norm(cal["T_cm"]), rel=1e-3
    )
    _assert_same(read_calibration_file(p), cal)


def test_ros_camera_info_round_trip_in_metres(tmp_path):
    cal = _calibration()
    paths = _write_exports(cal, tmp_path)
    left = yaml.safe_load(paths["camera_info_left"].read_text())
    assert set(left) >= {
        "image_width",
        "image_height",
        "camera_name",
        "camera_matrix",
        "distortion_model",
        "distortion_coefficients",
        "rectification_matrix",
        "projection_matrix",
    }
    assert left["distortion_model"] == "plumb_bob"
    right = yaml.safe_load(paths["camera_info_right"].read_text())
    P2 = np.array(right["projection_matrix"]["data"]).reshape(3, 4)
    # metres
    assert P2[0, 3] / P2[0, 0] == pytest.approx(-np.linalg.norm(cal["T_cm"]) / 100, rel=1e-3)
    _assert_same(read_ros_pair(paths["camera_info_left"], paths["camera_info_right"]), cal)


def test_a_ros_pair_calibrated_without_a_square_size_needs_cm_per_unit(tmp_path):
    # (it loaded as centimetres, silently: a 3.3-square baseline became 3.3 cm)
    cal = dict(_calibration(), T_cm=np.array([-3.3, 0.02, 0.05]), length_unit="squares")
    paths = _write_exports(cal, tmp_path)
    assert (
        paths["camera_info_left"]
        .read_text()
        .startswith("# projection_matrix lengths are in squares/100")
    )
    with pytest.raises(NodeError, match="board squares.*give cm_per_unit"):
        read_calibration_file(paths["camera_info_left"], paths["camera_info_right"])
    got = read_calibration_file(
        paths["camera_info_left"], paths["camera_info_right"], cm_per_unit=2.5
    )
    assert np.abs(got["T_cm"] - 2.5 * cal["T_cm"]).max() < 1e-9  # squares x 2.5 cm
    # metres: the default, or cm_per_unit 100
    plain = _write_exports(_calibration(), tmp_path / "plain")
    for cm in (None, 100.0):
        _assert_same(
            read_calibration_file(
                plain["camera_info_left"], plain["camera_info_right"], cm_per_unit=cm
            ),
            _calibration(),
        )


def _stereo_calib_files(cal, folder: Path) -> tuple[Path, Path]:
    """intrinsics.yml + extrinsics.yml as OpenCV's stereo_calib sample writes them: no size, no
    unit."""
    intr, extr = folder / "intrinsics.yml", folder / "extrinsics.yml"
    for p, names in (
        (intr, (("M1", "K1"), ("D1", "D1"), ("M2", "K2"), ("D2", "D2"))),
        (extr, (("R", "R"), ("T", "T_cm"))),
    ):
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
        for name, key in names:
            fs.write(name, np.asarray(cal[key], float))
        fs.release()
    return intr, extr


def test_stereo_calib_sample_files_need_unit_and_size(tmp_path):
    # What OpenCV's stereo_calib sample writes: intrinsics.yml and extrinsics.yml, no size, no unit.
    cal = _calibration()
    intr, extr = _stereo_calib_files(cal, tmp_path)
    with pytest.raises(NodeError, match="lacks R, T") as e:
        read_calibration_file(intr)
    assert str(intr) in e.value.message
    with pytest.raises(NodeError, match="unit of T") as e:
        read_calibration_file(intr, extr)
    assert str(intr) in e.value.message and "cm_per_unit" in e.value.hint
    with pytest.raises(NodeError, match="image size"):
        read_calibration_file(intr, extr, cm_per_unit=0.1)
    got = read_calibration_file(intr, extr, cm_per_unit=0.1, image_size=(640, 480))  # a file in mm
    assert np.allclose(got["T_cm"], cal["T_cm"] * 0.1) and np.allclose(got["K2"], cal["K2"])


def test_an_image_size_that_does_not_fit_the_principal_points_is_refused(tmp_path):
    # (a 640x480 calibration loaded with image_size [1280, 960] was taken: principal point (322,
    # 238) in 1280x960 images, a quarter of the way across, with no word)
    intr, extr = _stereo_calib_files(_calibration(), tmp_path)
    with pytest.raises(
        NodeError,
        match=r"image_size given, 1280x960 px, does not fit it: the principal points, "
        r"left \(321.7, 238.2\) px; right \(318.4, 241.0\) px, lie 25% .* "
        r"images of about 643x476 px",
    ) as e:
        read_calibration_file(intr, extr, cm_per_unit=1.0, image_size=(1280, 960))
    assert str(intr) in e.value.message and "max_principal_offset" in e.value.hint
    # a 16:9 size for a 4:3 calibration
    with pytest.raises(NodeError, match=r"640x360 px, does not fit it"):
        read_calibration_file(intr, extr, cm_per_unit=1.0, image_size=(640, 360))
    assert read_calibration_file(intr, extr, cm_per_unit=1.0, image_size=(640, 480))[
        "image_size"
    ] == [640, 480]
    # a truly off-centre principal point (a cropped sensor) loads once the limit is raised
    got = read_calibration_file(
        intr, extr, cm_per_unit=1.0, image_size=(1280, 960), max_principal_offset=0.3
    )
    assert got["image_size"] == [1280, 960]


def _pipeline(tmp_path: Path, nodes: str) -> Path:
    p = tmp_path / "p.yaml"
    p.write_text("name: loaders\nnodes:\n" + nodes)
    return p


def test_loaders_in_a_pipeline_and_wrong_files(tmp_path):
    cal = _calibration()
    write_value(tmp_path / "calibration", cal)
    _write_exports(cal, tmp_path)
    rig = {
        "image_size": [640, 480],
        "fx_px": 515.3,
        "baseline_cm": float(np.linalg.norm(cal["T_cm"])),
    }
    write_value(
        tmp_path / "model",
        {"type": "none", "coefficients": {}, "valid_range": {}, "frame": "left_camera", "rig": rig},
    )
    write_value(
        tmp_path / "other_model",
        {
            "type": "none",
            "coefficients": {},
            "valid_range": {},
            "frame": "left_camera",
            "rig": {**rig, "baseline_cm": 12.0},
        },
    )
    write_value(
        tmp_path / "hand_eye", {"T_base_from_left": np.eye(4), "method": "given", "rig": rig}
    )
    p = _pipeline(
        tmp_path,
        """
  cal: {type: calibrator.load, params: {path: calibration.json}}
  ocv: {type: calibrator.load, params: {path: opencv.yml}}
  ros: {type: calibrator.load,
        params: {path: camera_info_left.yaml, right_path: camera_info_right.yaml}}
  model: {type: compensator.load, params: {path: model.json},
          inputs: {calibration: cal.calibration}}
  he: {type: calibrator.load_hand_eye, params: {path: hand_eye.json},
       inputs: {calibration: ocv.calibration}}
""",
    )
    r = run_pipeline(p, out_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    assert r.ok, r.status
    for n in ("cal", "ocv", "ros"):
        _assert_same(r.outputs(n, "calibration"), cal)
    assert r.outputs("model", "model")["type"] == "none"
    assert np.allclose(r.outputs("he", "hand_eye")["T_base_from_left"], np.eye(4))
    # the second run recomputes nothing: the cache key is the files' content
    r2 = run_pipeline(p, out_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    assert not r2.ran
    # a model fitted on another rig, and a file of the wrong kind: clear errors naming both files
    p2 = _pipeline(
        tmp_path,
        """
  cal: {type: calibrator.load, params: {path: calibration.json}}
  model: {type: compensator.load, params: {path: other_model.json},
          inputs: {calibration: cal.calibration}}
  he: {type: calibrator.load_hand_eye, params: {path: calibration.json}}
""",
    )
    r3 = run_pipeline(p2, out_dir=tmp_path / "run3", cache_dir=tmp_path / "cache")
    err = r3.reports["model"].error
    assert (
        r3.status["model"] == "failed" and "other_model.json" in err and "calibration.json" in err
    )
    assert "baseline" in err
    assert (
        r3.status["he"] == "failed"
        and "holds a StereoCalibration, not a HandEye" in r3.reports["he"].error
    )
    # a mirrored transform (one axis flipped): orthonormal, yet every target would land mirrored (it
    # was picked)
    write_value(
        tmp_path / "mirror",
        {"T_base_from_left": np.diag([1.0, -1.0, 1.0, 1.0]), "method": "given", "rig": rig},
    )
    p3 = _pipeline(
        tmp_path,
        """
  he: {type: calibrator.load_hand_eye, params: {path: mirror.json}}
""",
    )
    r4 = run_pipeline(p3, out_dir=tmp_path / "run4", cache_dir=tmp_path / "cache")
    assert (
        r4.status["he"] == "failed" and "a mirror image, not a rotation" in r4.reports["he"].error
    )


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data not present")
def test_real_chessboard_pairs_export_reads_back(tmp_path):
    views = calib_files(CalibFilesParams(folder=str(DATA)))["views"]
    out = chessboard(ChessboardParams(), views=views)
    cal = out["calibration"]
    assert cal["dy_mean_px"] < 0.5 and cal["baseline_cm"] > 0
    p = write_value(tmp_path / "opencv", out["opencv"])[0]
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    assert np.abs(fs.getNode("M1").mat() - cal["K1"]).max() < 1e-9
    assert np.abs(fs.getNode("D2").mat().ravel() - cal["D2"]).max() < 1e-9
    assert np.abs(fs.getNode("R").mat() - cal["R"]).max() < 1e-9
    assert np.abs(fs.getNode("T").mat().ravel() - cal["T_cm"]).max() < 1e-9
    # no square size given: lengths in squares, and it says so
    assert fs.getNode("unit").string() == "squares"
    fs.release()
    with pytest.raises(NodeError, match="in board squares"):
        read_calibration_file(p)
    got = read_calibration_file(p, cm_per_unit=2.5)  # once the user says how large a square is
    assert np.allclose(got["T_cm"], cal["T_cm"] * 2.5)
    # the same calibration as stereo_calib writes it (no size): the right size loads, twice it is
    # refused
    intr, extr = _stereo_calib_files(cal, tmp_path)
    assert read_calibration_file(intr, extr, cm_per_unit=2.5, image_size=(640, 480))[
        "image_size"
    ] == [640, 480]
    with pytest.raises(NodeError, match=r"image_size given, 1280x960 px, does not fit it"):
        read_calibration_file(intr, extr, cm_per_unit=2.5, image_size=(1280, 960))


def test_opencv_xml_file_loads(tmp_path):
    cal = _calibration()
    p = tmp_path / "stereo.xml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("unit", "mm")
    for name, key in (("M1", "K1"), ("D1", "D1"), ("M2", "K2"), ("D2", "D2"), ("R", "R")):
        fs.write(name, np.asarray(cal[key], float))
    fs.write("T", np.asarray(cal["T_cm"], float) * 10.0)
    fs.release()
    assert p.read_text().lstrip().startswith("<?xml")
    _assert_same(read_calibration_file(p), cal)


@pytest.mark.slow
def test_export_load_locate_gives_the_same_locations(tmp_path):
    rig = "  rig: {type: source.synthetic, params: {n_scenes: 4, n_views: 0, seed: 3}}\n"

    def _run(name, text):
        return run_pipeline(
            _pipeline(tmp_path, rig + text),
            out_dir=tmp_path / name,
            cache_dir=tmp_path / "cache",
            keep={"locate_json", "locate_ocv", "locate_ros"},
        )

    first = _run("cal", "  calib: {type: calibrator.truth, inputs: {truth: rig.truth}}\n")
    assert first.ok
    text = ""
    for tag, params in (
        ("json", "{path: cal/calib/calibration.json}"),
        ("ocv", "{path: cal/calib/opencv.yml}"),
        (
            "ros",
            "{path: cal/calib/camera_info_left.yaml, right_path: cal/calib/camera_info_right.yaml}",
        ),
    ):
        text += f"""
  cal_{tag}: {{type: calibrator.load, params: {params}}}
  rect_{tag}: {{type: rectifier.opencv, inputs: {{calibration: cal_{tag}.calibration}}}}
  seg_{tag}:
    type: segmenter.edge_morph
    params: {{object: {{radius_cm: 2.0, color_bgr: [20, 120, 245]}}, working_range_cm: [20, 80]}}
    inputs: {{pair: rig.pairs, rectification: rect_{tag}.rectification}}
  disp_{tag}: {{type: disparity.centroid, inputs: {{segmentation: seg_{tag}.segmentation,
                                                  rectification: rect_{tag}.rectification}}}}
  locate_{tag}: {{type: locator.triangulate, inputs: {{disparity: disp_{tag}.disparity,
      rectification: rect_{tag}.rectification, pair: rig.pairs}}}}
"""
    r = _run("loc", text)
    assert r.ok, {n: r.reports[n].error for n in r.status if r.reports[n].error}
    ref = r.outputs("locate_json", "location")
    assert sum(v["found"] for v in ref.values()) >= 3
    for tag in ("ocv", "ros"):
        got = r.outputs(f"locate_{tag}", "location")
        for pid, loc in ref.items():
            assert got[pid]["found"] == loc["found"]
            if loc["found"]:
                assert max(abs(got[pid][k] - loc[k]) for k in ("x_cm", "y_cm", "z_cm")) < 1e-9, (
                    tag,
                    pid,
                )


def test_opencv_json_file_loads(tmp_path):
    cal = _calibration()
    p = tmp_path / "stereo.json"  # FileStorage's JSON flavour, not a run's JSON
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_JSON)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("unit", "cm")
    for name, key in (
        ("M1", "K1"),
        ("D1", "D1"),
        ("M2", "K2"),
        ("D2", "D2"),
        ("R", "R"),
        ("T", "T_cm"),
    ):
        fs.write(name, np.asarray(cal[key], float))
    fs.release()
    _assert_same(read_calibration_file(p), cal)


def test_a_ros_pair_of_fisheye_cameras_is_refused(tmp_path):
    # (an `equidistant` camera_info loaded as plumb_bob: the fisheye k1..k4 read as k1 k2 p1 p2,
    # silently)
    paths = _write_exports(_calibration(), tmp_path)
    for side in ("camera_info_left", "camera_info_right"):
        doc = yaml.safe_load(paths[side].read_text())
        doc["distortion_model"] = "equidistant"
        doc["distortion_coefficients"] = {"rows": 1, "cols": 4, "data": [0.1, 0.01, 0.001, 0.0001]}
        paths[side].write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(NodeError, match="distortion_model 'equidistant'") as e:
        read_calibration_file(paths["camera_info_left"], paths["camera_info_right"])
    assert str(paths["camera_info_left"]) in e.value.message


def test_a_ros_pair_whose_left_file_is_the_right_cameras_is_refused(tmp_path):
    # (the right camera's file given as both: loaded with the right camera's K as the left's and R =
    # I, silently)
    paths = _write_exports(_calibration(), tmp_path)
    for left, right in (
        (paths["camera_info_right"], paths["camera_info_right"]),
        (paths["camera_info_right"], paths["camera_info_left"]),
    ):
        with pytest.raises(NodeError, match="has a baseline.*right camera's file") as e:
            read_calibration_file(left, right)
        assert str(left) in e.value.message


def test_a_run_json_in_squares_takes_cm_per_unit_like_the_other_formats(tmp_path):
    # (cm_per_unit was ignored for calibration.json: a 3.3-square baseline stayed 3.3, labelled
    # squares)
    cal = dict(_calibration(), T_cm=np.array([-3.3, 0.02, 0.05]), length_unit="squares")
    write_value(tmp_path / "calibration", cal)
    got = read_calibration_file(tmp_path / "calibration.json", cm_per_unit=2.5)
    assert np.abs(got["T_cm"] - 2.5 * cal["T_cm"]).max() < 1e-12 and got["length_unit"] == "cm"
    _assert_same(got, dict(cal, T_cm=2.5 * cal["T_cm"]))
    # already in cm: scaling it again would be wrong
    write_value(tmp_path / "in_cm", _calibration())
    with pytest.raises(NodeError, match="in cm already"):
        read_calibration_file(tmp_path / "in_cm.json", cm_per_unit=2.5)


def test_an_opencv_file_that_states_its_unit_and_size_is_not_overridden_silently(tmp_path):
    # cm_per_unit / image_size given for a file that states them won silently: the docs' line for a
    # file in mm ({cm_per_unit: 0.1, image_size: [640, 480]}) on opencv.yml gave a 0.8 cm baseline
    p = _write_exports(_calibration(), tmp_path)["opencv"]
    with pytest.raises(
        NodeError, match=r"says its lengths are in cm \(unit: cm\), but cm_per_unit 0.1 was given"
    ):
        read_calibration_file(p, cm_per_unit=0.1)
    with pytest.raises(NodeError, match=r"is for 640x480 px images, but image_size says 1280x960"):
        read_calibration_file(p, image_size=[1280, 960])
    _assert_same(read_calibration_file(p, cm_per_unit=1.0, image_size=[640, 480]), _calibration())


def test_the_default_globs_pair_names_with_the_side_after_the_number(tmp_path):
    """(docs/bench.md says 007_left.png / 007_right.png pair; the default globs 'left*' refused
    them)"""
    import cv2
    import numpy as np

    from nodes.sources._files import list_pairs
    from nodes.sources.files import FilesParams

    for i in (7, 8):
        for side in ("left", "right"):
            cv2.imwrite(str(tmp_path / f"{i:03d}_{side}.png"), np.zeros((4, 4, 3), np.uint8))
    p = FilesParams(folder=str(tmp_path))
    assert [pid for pid, _, _ in list_pairs(tmp_path, p.left_glob, p.right_glob)] == ["007", "008"]


@pytest.mark.parametrize(
    "files, ids, rule",
    [
        (["im0.png", "im1.png", "calib.txt"], ["Scene"], "im0 / im1"),
        (["im2.png", "im6.png", "disp2.png", "disp6.png"], ["Scene"], "im2 / im6"),
        (["view1.png", "view5.png", "disp1.png"], ["Scene"], "view1 / view5"),
        (
            [
                "image_0/000000.png",
                "image_1/000000.png",
                "image_0/000001.png",
                "image_1/000001.png",
            ],
            ["000000", "000001"],
            "image_0/ and image_1/",
        ),
        (["cam0/data/17.png", "cam1/data/17.png"], ["17"], "cam0/data/ and cam1/data/"),
        (["left/a.png", "right/a.png"], ["a"], "left/ and right/"),
    ],
)
def test_a_datasets_own_names_pair_with_no_settings(tmp_path, files, ids, rule):
    """(issue 30: im2.png / im6.png, im0 / im1, view1 / view5 were refused as 'no partner'; with
    globs im2.* the pair was called 'png')"""
    import cv2
    import numpy as np

    from nodes.sources._files import find_pairs

    scene = tmp_path / "Scene"
    for f in files:
        (scene / f).parent.mkdir(parents=True, exist_ok=True)
        if f.endswith(".png"):
            cv2.imwrite(str(scene / f), np.zeros((4, 4, 3), np.uint8))
        else:
            (scene / f).write_text("x")
    pairs, said = find_pairs(scene)
    assert [pid for pid, _, _ in pairs] == ids and rule in said
    left, right = (
        pairs[0][1].relative_to(scene).as_posix(),
        pairs[0][2].relative_to(scene).as_posix(),
    )
    assert (left, right) == (files[0], files[1]) or files[0].startswith("image_")


def test_a_folder_no_convention_fits_says_what_was_tried(tmp_path):
    import cv2
    import numpy as np

    from nodes.sources._files import find_pairs
    from stereograph.core.api import NodeError

    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(NodeError) as e:
        find_pairs(tmp_path)
    assert "im0/im1" in e.value.hint and "pairing: globs" in e.value.hint


def test_a_calibration_in_squares_is_refused_alike_in_the_three_formats_until_given_its_square(
    tmp_path,
):
    """(issue 30: it loaded from calibration.json without cm_per_unit, labelled squares, but was
    refused from opencv.yml and ROS: one rule now, and the same numbers once the square's size is
    given)"""
    cal = dict(_calibration(), T_cm=np.array([-3.3, 0.02, 0.05]), length_unit="squares")
    paths = _write_exports(cal, tmp_path)
    write_value(tmp_path / "calibration", cal)
    files = {
        "json": (tmp_path / "calibration.json", None),
        "opencv": (paths["opencv"], None),
        "ros": (paths["camera_info_left"], paths["camera_info_right"]),
    }
    for fmt, (path, right) in files.items():
        with pytest.raises(NodeError, match="board squares.*cm_per_unit"):
            read_calibration_file(path, right)
        got = read_calibration_file(path, right, cm_per_unit=2.5)
        assert np.abs(got["T_cm"] - 2.5 * cal["T_cm"]).max() < 1e-6, fmt
        assert got.get("length_unit", "cm") == "cm", fmt


@pytest.mark.slow
@pytest.mark.parametrize("alpha", [0.0, 1.0])
def test_the_rectifiers_exports_hold_the_runs_rectification_in_every_format(tmp_path, alpha):
    """(issue 30: opencv.yml ignored rectify.alpha -- with alpha 0 its P1/P2/Q differed from the
    run's by up to 383 -- and did not record it.) rectify/opencv.yml and the ROS pair hold the run's
    R1 R2 P1 P2 Q with rectify_alpha; each format, loaded and rectified again at that alpha, gives
    them back."""
    import cv2

    from nodes.rectifiers.opencv import rectify_calibration
    from stereograph.core.runner import run_pipeline

    root = Path(__file__).resolve().parents[1]
    res = run_pipeline(
        root / "pipelines" / "calibrate.yaml",
        ["rig.n_views=10", f"rectify.alpha={alpha}"],
        cache_dir=tmp_path / "c",
        out_dir=tmp_path / "run",
    )
    assert res.ok
    ran = res.state.get(("rectify", "rectification", None))
    out = res.out_dir
    fs = cv2.FileStorage(str(out / "rectify" / "opencv.yml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("rectify_alpha").real() == alpha
    for name in ("R1", "R2", "P1", "P2", "Q"):
        assert np.abs(fs.getNode(name).mat() - ran[name]).max() < 1e-6, name
    fs.release()
    board = read_calibration_file(out / "calib" / "calibration.json")["board"]
    # the board survives too
    assert read_calibration_file(out / "rectify" / "opencv.yml")["board"] == board
    for path, right in (
        (out / "rectify" / "opencv.yml", None),
        (out / "calib" / "calibration.json", None),
        (out / "rectify" / "camera_info_left.yaml", out / "rectify" / "camera_info_right.yaml"),
    ):
        again = rectify_calibration(read_calibration_file(path, right), alpha)
        for name in ("P1", "P2", "Q"):
            assert np.abs(again[name] - ran[name]).max() < 1e-3 * max(
                1.0, np.abs(ran[name]).max()
            ), (path, name)
