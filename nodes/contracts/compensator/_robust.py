"""Leaving mis-detected training placements out of a compensation fit.

A training placement whose *measurement* is of the wrong object (a distractor ball tens of
centimetres from the one whose truth it carries) is not noise: one such placement in a
least-squares fit drags the correction of every other placement with it. Before a model's
coefficients are kept, :func:`screen_outliers` decides which placements agree with the rest:

1. **Start without the model.** The raw errors ``measured - truth`` of correct placements
   differ only by the systematic error the model is about to learn (centimetres at most);
   mis-detections sit tens of centimetres away. A placement whose 3-D error lies further from
   the median error than ``outlier_mad`` robust standard deviations (1.4826 x the median
   absolute deviation, MAD) is set aside for the first fit. This is the robust estimate that
   serves here: a robust loss (Huber, soft-L1) in the model's own regression would not be,
   because a mis-detection is a *leverage* point (its measured z, u, v, disparity are the
   distractor's, far from where its truth is), and bounded-influence losses are robust to
   outlying targets, not to outlying regressors.
2. **Judge with the model.** The model is fitted on the kept placements and its residual
   ``|predicted - truth|`` (cm) computed for *every* placement; the same median + MAD test
   on those residuals decides again, so a correct placement set aside in step 1 (at the end
   of a strongly varying error) comes back, and a mis-detection only a few centimetres off,
   invisible in step 1, is caught. This repeats until the set no longer changes (a few rounds).
3. **The kept placements are fitted by the model's plain least squares**, so a clean
   training set gives exactly the model it gave before this screening existed.

The scale used in the test never drops below the placements' own stated depth uncertainty
(``sigma_z_cm`` of the Location, the locator's propagation of the disparity noise): a model
that reproduces most placements to 1e-12 cm must not call a placement off by 0.01 cm an outlier.
With more than half the placements set aside, the median no longer describes the correct ones
and the fit refuses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NoReturn

import numpy as np

from stereograph.api import NodeError

__all__ = ["MAD_TO_SIGMA", "Screen", "robust_threshold", "screen_outliers"]

#: 1 / Phi^-1(3/4): the MAD of a normal distribution times this is its standard deviation.
MAD_TO_SIGMA = 1.4826
#: At most this many rounds of step 2; the set almost always settles in two.
MAX_ROUNDS = 6


@dataclass
class Screen:
    """Outcome of :func:`screen_outliers`.

    Attributes
    ----------
    inliers : ndarray of int
        Indices of the placements kept for the fit.
    outliers : list of dict
        ``{"item", "residual_cm", "error_cm": [x, y, z]}`` per placement left out: its distance
        from the model's prediction (cm) and its raw measured - truth error (cm).
    threshold_cm : float or None
        The residual above which a placement was left out, cm (None when screening is off).
    rounds : int
        Model fits the screening took.
    """

    inliers: np.ndarray
    outliers: list[dict[str, Any]] = field(default_factory=list)
    threshold_cm: float | None = None
    rounds: int = 0

    def describe(self) -> dict[str, Any]:
        """The screening as plain data for the model artifact."""
        return {
            "outliers": self.outliers,
            "outlier_threshold_cm": self.threshold_cm,
            "n_outliers": len(self.outliers),
        }


def robust_threshold(values: np.ndarray, k: float, min_scale: float) -> float:
    """``median + k * max(1.4826 MAD, min_scale)`` of ``values`` (non-finite values count as
    huge)."""
    v = np.where(np.isfinite(values), values, np.inf)
    med = float(np.median(v))
    scale = MAD_TO_SIGMA * float(np.median(np.abs(v - med)))
    if not np.isfinite(med) or not np.isfinite(scale):
        return float("nan")  # more than half the values are non-finite
    return med + k * max(scale, min_scale)


def _scale_floor(samples: Any) -> float:
    """Smallest residual scale to test against, cm: the median stated depth uncertainty."""
    sigma = getattr(samples, "sigma_z_cm", None)
    if sigma is not None:
        finite = np.asarray(sigma, dtype=float)
        finite = finite[np.isfinite(finite) & (finite > 0)]
        if len(finite):
            return float(np.median(finite))
    # No stated uncertainty: a millionth of the working distance, far below any real measurement.
    return 1e-6 * max(float(np.median(np.abs(samples.truth_cm[:, 2]))), 1.0)


def _check_agreement(
    samples: Any, idx: np.ndarray, z_residual: np.ndarray, max_ratio: float | None, label: str
) -> None:
    """Refuse kept placements whose depth residual is far above their stated depth uncertainty."""
    sigma = getattr(samples, "sigma_z_cm", None)
    if max_ratio is None or sigma is None or len(idx) == 0:
        return
    s = np.asarray(sigma, dtype=float)[idx]
    s = s[np.isfinite(s) & (s > 0)]
    r = z_residual[idx]
    if len(s) < len(idx) / 2 or not np.all(np.isfinite(r)):
        return  # too little stated uncertainty to judge by
    typical_sigma, typical_residual = float(np.median(s)), float(np.median(r))
    if typical_residual > max_ratio * typical_sigma:
        raise NodeError(
            f"{label}: the {len(idx)} training placements kept for the fit disagree with "
            "it by a median "
            f"{typical_residual:.3g} cm in depth, {typical_residual / typical_sigma:.0f} "
            "times their stated depth "
            f"uncertainty ({typical_sigma:.3g} cm, limit {max_ratio:g} times); the "
            "training set disagrees with itself, "
            "as when most placements measured the wrong object, so no correction is "
            "fitted from it.",
            hint="check the training placements' detections (overlays in the segmenter's "
            "folder): a distractor or a "
            "wrong colour makes a measurement of the wrong object; give the segmenter "
            "the ball's colour, or raise "
            "max_residual_sigma if the measurements' sigma_z_cm is known to understate "
            "their error.",
        )


def screen_outliers(
    samples: Any,
    fit: Callable[[Any], dict[str, Any]],
    predict: Callable[[Any, Any], np.ndarray],
    k: float,
    min_inlier_fraction: float,
    min_points: int,
    label: str,
    max_residual_sigma: float | None = None,
) -> tuple[Screen, dict[str, Any]]:
    """Find the training placements that agree with the rest, and fit the model on them.

    Parameters
    ----------
    samples : Samples
        Training placements with truth (``nodes.contracts.compensator._common.Samples``).
    fit, predict : callable
        The model's pure functions.
    k : float
        Robust standard deviations (unitless) beyond the median residual that make a placement
        an outlier.
    min_inlier_fraction : float
        Fewest placements, as a fraction of all, that must agree for the fit to go on (unitless).
    min_points : int
        Fewest placements the model can be fitted from.
    label : str
        Node label for errors.
    max_residual_sigma : float, optional
        Refuse when the kept placements' median depth residual exceeds this many times their
        median stated depth uncertainty (unitless): the median + MAD test cannot see a majority
        of mis-detections, but the fit they leave behind is far worse than the measurements are.

    Returns
    -------
    (Screen, coefficients)
        The screening and the model fitted on its inliers.

    Raises
    ------
    NodeError
        Too few placements agree with one another (a fraction below ``min_inlier_fraction``,
        or fewer than ``min_points``).
    """
    n = len(samples)
    truth = samples.truth_cm
    floor = _scale_floor(samples)
    raw = samples.xyz_cm - truth
    spread = np.linalg.norm(raw - np.median(raw, axis=0), axis=1)
    threshold = robust_threshold(spread, k, floor)
    keep = spread <= threshold
    coefficients: dict[str, Any] | None = None
    fitted_on: np.ndarray | None = None
    residual = spread
    z_residual = np.full(n, np.nan)
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):
        idx = np.flatnonzero(keep)
        if len(idx) < max(min_points, 1):
            break
        try:
            coefficients = fit(samples.subset(idx))
        except NodeError:
            if rounds > 1 or len(idx) == n:
                raise
            # The first cut left the model unfittable (a lookup bin emptied, say): judge with all.
            keep = np.ones(n, dtype=bool)
            coefficients = fit(samples)
        fitted_on = keep.copy()
        pred = predict(coefficients, samples)
        with np.errstate(invalid="ignore"):
            residual = np.linalg.norm(pred - truth, axis=1)
            z_residual = np.abs(pred[:, 2] - truth[:, 2])
        threshold = robust_threshold(residual, k, floor)
        new_keep = np.isfinite(residual) & (residual <= threshold)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    idx = np.flatnonzero(keep)
    outliers = _outlier_records(samples, np.flatnonzero(~keep), residual, raw)
    if len(idx) < max(min_points, min_inlier_fraction * n) or not np.isfinite(threshold):
        _refuse_disagreement(
            label, len(idx), n, outliers, threshold, min_points, min_inlier_fraction
        )
    if fitted_on is None or not np.array_equal(fitted_on, keep):
        coefficients = fit(samples.subset(idx))  # the last round moved the set: fit what was kept
        with np.errstate(invalid="ignore"):
            z_residual = np.abs(predict(coefficients, samples)[:, 2] - truth[:, 2])
    _check_agreement(samples, idx, z_residual, max_residual_sigma, label)
    screen = Screen(inliers=idx, outliers=outliers, threshold_cm=float(threshold), rounds=rounds)
    return screen, coefficients


def _outlier_records(
    samples: Any, out_idx: np.ndarray, residual: np.ndarray, raw: np.ndarray
) -> list[dict[str, Any]]:
    """``{item, residual_cm, error_cm}`` of each placement left out, largest residual first (an
    undefined residual first of all)."""
    outliers = [
        {
            "item": samples.ids[i],
            "residual_cm": float(residual[i]) if np.isfinite(residual[i]) else None,
            "error_cm": [float(c) for c in raw[i]],
        }
        for i in out_idx
    ]
    outliers.sort(key=lambda o: -(o["residual_cm"] if o["residual_cm"] is not None else np.inf))
    return outliers


def _refuse_disagreement(
    label: str,
    n_kept: int,
    n: int,
    outliers: list[dict],
    threshold: float,
    min_points: int,
    min_inlier_fraction: float,
) -> NoReturn:
    """Too few training placements agree with one another to fit a correction: say which
    disagree most, and what to check."""
    worst = ", ".join(
        f"{o['item']} ({o['residual_cm']:.3g} cm)"
        if o["residual_cm"] is not None
        else f"{o['item']} (undefined)"
        for o in outliers[:5]
    )
    raise NodeError(
        f"{label}: only {n_kept} of {n} training placements agree with one another; "
        f"{len(outliers)} disagree "
        "with their ground truth by far more than the rest (residual > "
        f"{threshold:.3g} cm: {worst}"
        f"{', ...' if len(outliers) > 5 else ''}). The model needs at least "
        f"{min_points} placements and at least "
        f"{min_inlier_fraction:.0%} of them in agreement, so the measurements cannot "
        "be trusted to fit "
        "a correction.",
        hint="check the training placements' detections (overlays in the segmenter's "
        "folder): a distractor "
        "or a wrong colour makes a measurement of the wrong object; give the "
        "segmenter the ball's colour, "
        "remove the mis-detected placements, or lower min_inlier_fraction (0.5 at "
        "least) if you raised it.",
    )
