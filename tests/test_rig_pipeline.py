"""pipelines/calibrate.yaml through the engine: synthetic (default), real images, Tsai, and a bad
folder."""

from pathlib import Path

import pytest

from stereograph.app.cli import main
from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parents[1]
PIPE = ROOT / "pipelines" / "calibrate.yaml"
DATA = ROOT.parent / "shared" / "data" / "opencv-stereo-chessboard"


def _run(tmp_path, overrides):
    return run_pipeline(
        str(PIPE), overrides=overrides, cache_dir=tmp_path / "cache", out_dir=tmp_path / "out"
    )


@pytest.mark.slow
def test_calibrate_synthetic_default_and_tsai(tmp_path):
    res = _run(tmp_path, ["rig.n_views=10"])
    assert res.ok, res.status
    rect = res.outputs("rectify", "rectification")
    assert abs(rect["baseline_cm"] - 8.0) < 0.04 and rect["dy_mean_px"] < 0.1
    assert (tmp_path / "out" / "rectify" / "check_image.png").is_file()
    res = _run(tmp_path, ["rig.n_views=10", "calib.type=calibrator.tsai"])
    assert res.ok and res.status["rig"] == "cached"
    assert res.outputs("rectify", "rectification")["dy_mean_px"] < 0.5


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data not present")
def test_calibrate_real_images(tmp_path):
    res = _run(tmp_path, ["rig.type=source.calib_files", f"rig.folder={DATA}"])
    assert res.ok, res.status
    cal = res.outputs("calib", "calibration")
    assert len(cal["per_view_rms_px"]) == 13 and cal["rms_px"] < 0.3
    assert res.outputs("rectify", "rectification")["dy_mean_px"] <= 0.5


def test_bad_folder_exits_nonzero_naming_it(tmp_path, capsys):
    missing = tmp_path / "no_such_folder"
    rc = main(
        [
            "run",
            str(PIPE),
            "--set",
            "rig.type=source.calib_files",
            "--set",
            f"rig.folder={missing}",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert rc in (1, 2)
    io = capsys.readouterr()
    assert str(missing) in io.out + io.err


def test_validate_reports_a_bad_distance_range(capsys):
    rc = main(
        [
            "validate",
            str(PIPE),
            "--set",
            "rig.min_distance_cm=70",
            "--set",
            "rig.max_distance_cm=40",
        ]
    )
    assert rc == 2
    err = capsys.readouterr().err
    assert (
        "max_distance_cm (40.0) must exceed min_distance_cm (70.0)" in err
        and "calibrate.yaml:" in err
    )
