"""Scores of a dense disparity map against a ground truth, as Middlebury defines them.

Shared by the matcher (``disparity.dense``) and the report that scores it (``report.disparity``).
Public name: :func:`bad_pixels`.
"""

from __future__ import annotations

import numpy as np


def bad_pixels(
    disp: np.ndarray, truth_px: np.ndarray, threshold_px: float = 2.0
) -> tuple[float, float]:
    """Middlebury-style scores against a ground-truth disparity map (0 = unknown there).

    Returns
    -------
    (fill, bad)
        ``fill``: the fraction of pixels with known truth that have a disparity; ``bad``: the
        fraction of those filled pixels whose disparity is more than ``threshold_px`` from the truth
        ("bad-2.0").
    """
    known = np.asarray(truth_px) > 0
    filled = known & np.isfinite(disp)
    if not filled.any():
        return 0.0, float("nan")
    bad = filled & (np.abs(np.where(filled, disp, 0.0) - truth_px) > threshold_px)
    return float(filled.sum() / known.sum()), float(bad.sum() / filled.sum())
