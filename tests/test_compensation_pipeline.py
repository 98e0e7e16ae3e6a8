"""Compensation through the real pipeline (synthetic rig -> chessboard calibration -> ... ->
compensate), compared with `stereograph compare` on one shared cache."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereograph.app.compare import compare

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ROOT / "pipelines" / "compare-compensation.yaml"
# A small rig whose calibration carries a 2 % baseline error: a clear systematic z error.
SMALL = ["rig.n_scenes=24", "rig.n_views=8", "calib_error.baseline_scale=1.02"]


@pytest.mark.slow
def test_compare_compensation_real_pipeline(tmp_path):
    cache = tmp_path / "cache"
    first = compare(
        PIPELINE,
        ["fit.type=none,polynomial"],
        tmp_path / "a",
        overrides=SMALL,
        cache_dir=cache,
        plots=False,
    )
    assert first.ok, [v.error for v in first.variants]
    upstream = {
        "objects",
        "rig",
        "calib",
        "calib_error",
        "rectify",
        "check",
        "remap",
        "segment",
        "disparity",
        "locate",
    }
    own = {"fit", "compensate", "report"}
    assert first.variants[0].ran == upstream | own
    assert first.variants[1].ran == own  # calibration and segmentation ran once, not per variant
    none, poly = first.row(**{"fit.type": "none"}), first.row(**{"fit.type": "polynomial"})
    assert none["n_truth"] >= 6 and none["found_rate"] > 0.9  # the report node's metrics
    assert none["z_mean_cm"] > 0.4  # 2 % of 30-60 cm
    assert poly["z_rms_cm"] < 0.5 * none["z_rms_cm"]
    assert poly["x_rms_cm"] <= none["x_rms_cm"] and poly["y_rms_cm"] <= none["y_rms_cm"]
    model = json.loads((first.variants[1].out_dir / "fit" / "model.json").read_text())
    assert (
        model["type"] == "polynomial" and model["n_train"] >= 6 and "z_cm" in model["valid_range"]
    )

    second = compare(
        PIPELINE,
        ["fit.type=none,polynomial,xyz"],
        tmp_path / "b",
        overrides=SMALL,
        cache_dir=cache,
        plots=False,
    )
    assert {v.variant.settings["fit.type"]: v.ran for v in second.variants} == {
        "none": set(),
        "polynomial": set(),
        "xyz": own,
    }
