"""calibrator.perturb: injects exactly the requested calibration error, nothing else."""

import numpy as np
import pytest

from nodes.calibrators.perturb import PerturbParams, perturb
from stereograph.core.api import NodeError


def test_perturb_scales_baseline_and_focal():
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    cal = {
        "K1": K,
        "K2": K.copy(),
        "D1": np.zeros(5),
        "D2": np.zeros(5),
        "R": np.eye(3),
        "T_cm": np.array([-8.0, 0.1, 0.0]),
        "image_size": [640, 480],
        "method": "chessboard/joint",
    }
    out = perturb(
        PerturbParams(baseline_scale=1.02, focal_scale=0.99, cx_shift_right_px=0.5), calibration=cal
    )
    got = out["calibration"]
    np.testing.assert_allclose(got["T_cm"], cal["T_cm"] * 1.02)
    assert got["K1"][0, 0] == pytest.approx(495.0) and got["K2"][1, 1] == pytest.approx(495.0)
    assert got["K2"][0, 2] == pytest.approx(320.5) and got["K1"][0, 2] == 320
    np.testing.assert_array_equal(cal["T_cm"], [-8.0, 0.1, 0.0])  # input untouched
    same = perturb(PerturbParams(), calibration=cal)["calibration"]
    np.testing.assert_array_equal(same["T_cm"], cal["T_cm"])
    np.testing.assert_array_equal(same["K2"], cal["K2"])
    with pytest.raises(NodeError, match="lacks 'T_cm'"):
        perturb(PerturbParams(), calibration={"K1": K, "K2": K})
