"""A calibration / compensation / hand-eye file from someone else: its .npz is a zip, and a few MB
of zeros decompress into tens of GB. The loader refuses it from the zip's directory, before
decompressing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nodes.contracts import calibration_file
from stereograph.core.api import NodeError


def test_npz_that_would_decompress_beyond_the_bound_is_refused(tmp_path, monkeypatch):
    (tmp_path / "cal.json").write_text(
        json.dumps({"map": {"npz": "map", "shape": [1024, 1024], "dtype": "float64"}})
    )
    # 8 MB of zeros, ~8 kB on disk
    np.savez_compressed(tmp_path / "cal.npz", map=np.zeros((1024, 1024)))
    assert (tmp_path / "cal.npz").stat().st_size < 100_000
    got = calibration_file.read_artifact(
        tmp_path / "cal.json", "calibrator.load", "StereoCalibration", "a run"
    )
    assert got["map"].shape == (1024, 1024)  # within the bound: read
    # (the real bound is 2 GB: too slow to build here)
    monkeypatch.setattr(calibration_file, "MAX_NPZ_BYTES", 4 << 20, raising=False)
    with pytest.raises(NodeError, match="would decompress into .* more than"):
        calibration_file.read_artifact(
            tmp_path / "cal.json", "calibrator.load", "StereoCalibration", "a run"
        )


def test_json_nested_beyond_the_stack_is_a_node_error(tmp_path):
    (tmp_path / "cal.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(NodeError, match="nests its values 100000 levels deep"):
        calibration_file.read_artifact(
            tmp_path / "cal.json", "calibrator.load", "StereoCalibration", "a run"
        )
