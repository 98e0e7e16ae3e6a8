"""``calibrator.truth``: the rig's ground-truth cameras as a StereoCalibration (a baseline)."""

from __future__ import annotations

import numpy as np

from nodes.calibrators._calib_io import calibration_outputs
from nodes.contracts.calibration_export import EXPORT_OUTPUTS
from stereograph.api import In, NodeError, Out, node


def truth_calibration(truth: dict) -> dict:
    """Turn a ``RigTruth`` into a ``StereoCalibration`` (RMS 0, no views)."""
    need = ("K1", "D1", "K2", "D2", "R", "T_cm", "image_size")
    missing = [k for k in need if k not in truth]
    if missing:
        raise NodeError(
            f"calibrator.truth: the rig truth lacks {missing}.",
            hint="wire it to a source that knows its cameras (source.synthetic's `truth`)",
        )
    cal = {k: np.asarray(truth[k], dtype=float) for k in ("K1", "D1", "K2", "D2", "R")}
    cal.update(
        {
            "T_cm": np.asarray(truth["T_cm"], dtype=float).ravel(),
            "image_size": list(truth["image_size"]),
            "rms_px": 0.0,
            "per_view_rms_px": {},
            "rejected_views": [],
            "method": "truth",
        }
    )
    if truth.get("T_table_from_left") is not None:
        cal["T_table_from_left"] = np.asarray(truth["T_table_from_left"], dtype=float)
    return cal


@node(
    "calibrator.truth",
    inputs={"truth": In("RigTruth", description="True cameras (synthetic rig).")},
    outputs={"calibration": Out("StereoCalibration"), **EXPORT_OUTPUTS},
    version="1",
)
def truth(params, truth: dict, ctx=None) -> dict:
    """Pass the rig's true cameras through as a calibration: the error-free baseline for
    locating."""
    if truth is None:
        raise NodeError(
            "calibrator.truth: this source has no ground-truth cameras.",
            hint="use calibrator.chessboard or calibrator.tsai instead",
        )
    return calibration_outputs(truth_calibration(truth), ctx)
