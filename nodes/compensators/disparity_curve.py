"""``compensator.disparity_curve``: depth straight from disparity by curve fitting.

Triangulation gives ``z = f B / d``, which is only as good as the calibrated f
and B. The thesis (section 2.2) names curve fitting of distance against
disparity as the better way when the calibration is imperfect: fit

    z = a / (d + b) + c

on the training placements, with ``d`` the rectified disparity (px). ``a``
absorbs errors of f B (cm px), ``b`` a disparity offset (px; a principal-point
mismatch between the rectified cameras) and ``c`` a depth offset (cm). The fit
is nonlinear least squares: an algebraic linear fit
(``z d = (a + c b) + c d - b z``) for the start, then
:func:`scipy.optimize.least_squares` (trust region, analytic Jacobian) with the
disparity offset bounded so that ``d + b`` stays positive on every training placement.

``z = f B / d`` holds for the depth in the *rectified* left camera, which stereoRectify
turns by R1 against the physical camera the locations are reported in. By default
(``depth: rectified``) the curve is therefore fitted to the rectified depth: along one
viewing ray the physical z is the rectified z times a factor ``g`` of the ray's direction
only, and ``g = z_measured d / K`` with ``K`` the median of ``z_measured d`` over the
training placements (a constant; it cancels). The corrected point is ``curve(d) g`` deep.
``depth: camera`` fits the physical z directly (the thesis's plain curve).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from scipy.optimize import least_squares

from nodes.contracts.compensator import fit_compensator
from nodes.contracts.compensator._common import (
    RayFitParams,
    Samples,
    along_ray,
    resolve_along_ray,
)
from stereograph.api import Field, NodeError

__all__ = ["disparity_curve", "fit_disparity_curve", "predict_disparity_curve"]

INPUTS = ("disparity_px",)


def _curve(p: np.ndarray, d: np.ndarray) -> np.ndarray:
    return p[0] / (d + p[1]) + p[2]


def _linear_ac(d: np.ndarray, z: np.ndarray, b: float) -> np.ndarray:
    """Best (a, c) for a fixed b: z = a / (d + b) + c is linear in a and c."""
    design = np.column_stack([1.0 / (d + b), np.ones_like(d)])
    (a, c), *_ = np.linalg.lstsq(design, z, rcond=None)
    return np.array([a, b, c])


def _ray_factor(samples: Samples, k_cm_px: float | None) -> np.ndarray:
    """g = z_measured d / K: physical over rectified depth along each measured ray (1 without K)."""
    if k_cm_px is None:
        return np.ones(len(samples))
    return samples.xyz_cm[:, 2] * samples.disparity_px / k_cm_px


def fit_disparity_curve(
    samples: Samples,
    with_offset_px: bool = True,
    max_iter: int = 100,
    xy: str = "auto",
    rectified: bool = True,
) -> dict[str, Any]:
    """Least-squares fit of true z = a / (d + b) + c.

    Parameters
    ----------
    samples : Samples
        Training placements with truth and disparity.
    with_offset_px : bool
        Fit the disparity offset b (px); False fixes b = 0 (a linear fit in 1/d).
    max_iter : int
        Jacobian evaluations of the nonlinear fit at most.
    xy : {"auto", "along_ray", "keep"}
        What the correction does to x, y (see :func:`resolve_along_ray`).
    rectified : bool
        Fit the rectified depth (see the module docstring) instead of the physical z.

    Returns
    -------
    dict
        ``{"a_cm_px", "b_px", "c_cm", "k_cm_px" (None when not rectified), "along_ray",
        "iterations"}``.
    """
    d = samples.disparity_px
    k_cm_px = float(np.median(samples.xyz_cm[:, 2] * d)) if rectified else None
    if k_cm_px is not None and not k_cm_px > 0:
        raise NodeError(
            "measured depth times disparity is not positive on the training placements."
        )
    g = _ray_factor(samples, k_cm_px)
    z = samples.truth_cm[:, 2] / g
    n_coef = 3 if with_offset_px else 2
    if len(d) < n_coef + 1:
        raise NodeError(
            f"the disparity curve has {n_coef} coefficients and needs at least "
            f"{n_coef + 1} placements, "
            f"got {len(d)}."
        )
    if len(np.unique(d)) < n_coef:
        raise NodeError(
            f"the disparity curve needs {n_coef} distinct disparities, got {len(np.unique(d))}."
        )
    if np.any(d <= 0):
        raise NodeError(f"training disparities must be positive (got min {np.min(d):.3g} px).")
    p = _linear_ac(d, z, 0.0)
    iterations = 0
    if with_offset_px:
        p, iterations = _fit_with_offset(d, z, p, max_iter)
    if not np.all(np.isfinite(p)):
        raise NodeError("the disparity curve fit did not converge to finite coefficients.")
    return {
        "a_cm_px": float(p[0]),
        "b_px": float(p[1]),
        "c_cm": float(p[2]),
        "k_cm_px": k_cm_px,
        "along_ray": resolve_along_ray(xy, samples, _curve(p, d) * g),
        "iterations": int(iterations),
    }


def _fit_with_offset(d: np.ndarray, z: np.ndarray, p: np.ndarray, max_iter: int):
    """``(a, b, c)`` of z = a / (d + b) + c by nonlinear least squares from the better of ``p``
    (b = 0) and an algebraic start, never worse than its start; and the Jacobian evaluations."""
    # Algebraic start: multiply out the denominator, z d = (a + c b) + c d - b z, linear in (a +
    # cb, c, b).
    (_alpha, _c, b), *_ = np.linalg.lstsq(
        np.column_stack([np.ones_like(d), d, -z]), z * d, rcond=None
    )
    if np.all(d + b > 0.05 * np.min(d)):
        start = _linear_ac(d, z, float(b))
        if np.sum((z - _curve(start, d)) ** 2) < np.sum((z - _curve(p, d)) ** 2):
            p = start
    # b > -min(d) keeps every denominator positive (the curve's pole stays left of the data)
    b_low = -float(np.min(d)) * (1.0 - 1e-6)

    def residuals(q: np.ndarray) -> np.ndarray:
        return _curve(q, d) - z

    def jacobian(q: np.ndarray) -> np.ndarray:
        den = d + q[1]
        return np.column_stack([1.0 / den, -q[0] / den**2, np.ones_like(d)])

    fit = least_squares(
        residuals,
        p,
        jac=jacobian,
        method="trf",
        x_scale="jac",
        max_nfev=max_iter,
        bounds=([-np.inf, b_low, -np.inf], [np.inf, np.inf, np.inf]),
        ftol=1e-12,
        xtol=1e-12,
        gtol=1e-12,
    )
    # never worse than the start (least_squares returns its best point, but say so explicitly)
    if np.sum(fit.fun**2) <= np.sum((z - _curve(p, d)) ** 2):
        p = fit.x
    iterations = int(fit.njev or fit.nfev)
    return p, iterations


def predict_disparity_curve(coefficients: Mapping[str, Any], samples: Samples) -> np.ndarray:
    """Corrected positions, cm (N, 3); NaN rows where d + b <= 0 (outside the curve's domain)."""
    d = samples.disparity_px
    den = d + coefficients["b_px"]
    with np.errstate(divide="ignore", invalid="ignore"):
        z_new = np.where(den > 0, coefficients["a_cm_px"] / den + coefficients["c_cm"], np.nan)
    z_new = z_new * _ray_factor(samples, coefficients.get("k_cm_px"))
    return along_ray(samples.xyz_cm, z_new, samples.frame, coefficients.get("along_ray", True))


class DisparityCurveParams(RayFitParams):
    """Options of ``compensator.disparity_curve``."""

    depth: Literal["rectified", "camera"] = Field(
        "rectified",
        description="Fit the rectified camera's depth (where z = fB/d holds; default) or the "
        "physical z (cm).",
    )
    with_offset: bool = Field(
        True, description="Fit the disparity offset b (px) of z = a/(d+b)+c; false fixes b = 0."
    )


def _camera_frame_only(params: DisparityCurveParams, samples: Samples, label: str) -> None:
    if samples.frame != "left_camera":
        raise NodeError(
            f"{label}: the disparity curve models depth along the camera axis, but the "
            "locations are in the "
            f"'{samples.frame}' frame.",
            hint="fit on locations in the left_camera frame (locator frame: left_camera), or "
            "use compensator.xyz.",
        )


def _title(params: DisparityCurveParams, model: dict) -> str:
    c = model["coefficients"]
    return (
        f"{params.depth} depth = a / (d + b) + c: a = {c['a_cm_px']:.5g} cm px, b = "
        f"{c['b_px']:+.3g} px, "
        f"c = {c['c_cm']:+.3g} cm"
    )


@fit_compensator(
    "compensator.disparity_curve",
    params=DisparityCurveParams,
    predict=predict_disparity_curve,
    inputs=INPUTS,
    min_points=lambda p: 4 if p.with_offset else 3,
    span="disparity",
    axes=("z",),
    title=_title,
    version="3",
    check=_camera_frame_only,
    model="z = a/(d+b)+c (cm, d in px).",
    figure="Depth error (truth - measured, cm) vs disparity: placements, fitted curve, valid "
    "range.",
)
def disparity_curve(params: DisparityCurveParams, samples: Samples) -> dict[str, Any]:
    """Fit true depth against disparity, z = a/(d+b)+c, on the training placements (curve
    fitting)."""
    return fit_disparity_curve(
        samples, params.with_offset, xy=params.xy, rectified=params.depth == "rectified"
    )
