"""``calibrator.perturb``: a deliberately imperfect copy of a stereo calibration (what-if studies).

Real rigs are never calibrated perfectly: a baseline measured a little long, a focal length
estimated from too few views. This node injects such errors into a ``StereoCalibration`` so
that a pipeline can show what they do to the located positions, and how much of it a
compensator fitted on training placements can take back (issue 5: "a 2 % baseline error
injected"). With the defaults it passes the calibration through unchanged.
"""

from __future__ import annotations

import numpy as np

from nodes.calibrators._calib_io import calibration_outputs
from nodes.contracts.calibration_export import EXPORT_OUTPUTS
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["perturb", "perturb_calibration"]


def perturb_calibration(
    calibration: dict,
    baseline_scale: float = 1.0,
    focal_scale: float = 1.0,
    cx_shift_right_px: float = 0.0,
) -> dict:
    """Return a copy of a StereoCalibration with scaled baseline / focal lengths.

    Parameters
    ----------
    calibration : dict
        A ``StereoCalibration`` (``K1``, ``K2``, ``T_cm`` ...).
    baseline_scale : float
        Multiplies the translation ``T_cm`` (believed / true baseline; 1.02 = 2 % too long).
    focal_scale : float
        Multiplies fx, fy of both cameras (unitless).
    cx_shift_right_px : float
        Added to the right camera's principal point cx, px (acts like a disparity offset).

    Returns
    -------
    dict
        The perturbed calibration, with ``perturbation`` recording the factors.
    """
    for key in ("K1", "K2", "T_cm"):
        if key not in calibration:
            raise NodeError(
                f"calibrator.perturb: the calibration lacks {key!r}.",
                hint="wire `calibration` to a calibrator's output (calibrator.chessboard ...).",
            )
    out = dict(calibration)
    out["T_cm"] = np.asarray(calibration["T_cm"], dtype=float).ravel() * baseline_scale
    for key in ("K1", "K2"):
        K = np.array(calibration[key], dtype=float, copy=True)
        K[0, 0] *= focal_scale
        K[1, 1] *= focal_scale
        if key == "K2":
            K[0, 2] += cx_shift_right_px
        out[key] = K
    out["method"] = f"{calibration.get('method', 'calibration')}+perturbed"
    out["perturbation"] = {
        "baseline_scale": float(baseline_scale),
        "focal_scale": float(focal_scale),
        "cx_shift_right_px": float(cx_shift_right_px),
    }
    return out


class PerturbParams(Params):
    baseline_scale: float = Field(
        1.0,
        gt=0.5,
        lt=2.0,
        description="Believed / true baseline (unitless; 1.02 = a 2 % baseline error).",
    )
    focal_scale: float = Field(
        1.0, gt=0.5, lt=2.0, description="Multiplier of both focal lengths (unitless)."
    )
    cx_shift_right_px: float = Field(
        0.0,
        ge=-50,
        le=50,
        description="Shift of the right principal point cx (px); acts as a disparity offset.",
    )


@node(
    "calibrator.perturb",
    inputs={"calibration": In("StereoCalibration", description="A calibration to degrade.")},
    outputs={
        "calibration": Out("StereoCalibration", description="The same, with the injected errors."),
        **EXPORT_OUTPUTS,
    },
    params=PerturbParams,
    version="1",
)
def perturb(params: PerturbParams, calibration: dict, ctx=None) -> dict:
    """Inject a known calibration error (baseline, focal length, principal point) for what-if
    studies."""
    return calibration_outputs(
        perturb_calibration(
            calibration, params.baseline_scale, params.focal_scale, params.cx_shift_right_px
        ),
        ctx,
    )
