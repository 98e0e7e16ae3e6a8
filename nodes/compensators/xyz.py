"""``compensator.xyz``: a 3-D correction of x, y and z from image position and disparity.

The thesis corrected z only, but errors in x and y grow towards the image
border too (lens distortion left over by the calibration, a rotation of the
rectified frame, a scale error of f B that moves points along their rays). This
model fits the error of each axis as a low-order polynomial of the rectified
left image position (u, v, px) and the depth feature ``w`` (by default the
inverse disparity 1/d, which is proportional to depth, so the errors of a wrong
baseline or focal length are linear in it). Variables are scaled to [-1, 1]
over their training range and the coefficients solved by ridge-regularised
linear least squares (:func:`numpy.linalg.lstsq` on the augmented system).
"""

from __future__ import annotations

from collections.abc import Mapping
from itertools import combinations_with_replacement
from typing import Any, Literal

import numpy as np

from nodes.contracts.compensator import fit_compensator
from nodes.contracts.compensator._common import (
    FitParams,
    Samples,
)
from stereograph.api import Field, NodeError

__all__ = ["fit_xyz", "monomials", "predict_xyz", "xyz"]

INPUTS = ("u_left_px", "v_left_px", "disparity_px")


def monomials(n_vars: int, degree: int) -> list[list[int]]:
    """Exponent vectors of all monomials of total degree <= ``degree`` (constant first)."""
    out = [[0] * n_vars]
    for deg in range(1, degree + 1):
        for combo in combinations_with_replacement(range(n_vars), deg):
            e = [0] * n_vars
            for k in combo:
                e[k] += 1
            out.append(e)
    return out


def _features(samples: Samples, depth_feature: str) -> np.ndarray:
    d = samples.disparity_px
    with np.errstate(divide="ignore", invalid="ignore"):
        w = 1.0 / d if depth_feature == "inverse_disparity" else d
    return np.column_stack([samples.u_px, samples.v_px, w])


def _design(scaled: np.ndarray, exponents: list[list[int]]) -> np.ndarray:
    return np.column_stack(
        [np.prod(scaled ** np.asarray(e, dtype=float), axis=1) for e in exponents]
    )


def fit_xyz(
    samples: Samples, degree: int = 2, ridge: float = 1e-6, depth_feature: str = "inverse_disparity"
) -> dict[str, Any]:
    """Per-axis error polynomials of (u, v, w), cm.

    Parameters
    ----------
    samples : Samples
        Training placements with truth, disparity and image position.
    degree : int
        Total degree of the polynomial in (u, v, w).
    ridge : float
        Tikhonov weight relative to the mean squared column norm of the design
        matrix (unitless); the constant term is not penalised.
    depth_feature : {"inverse_disparity", "disparity"}
        Third variable: 1/d (1/px) or d (px).

    Returns
    -------
    dict
        ``{"exponents", "center", "half_range", "coef_x_cm", "coef_y_cm", "coef_z_cm",
        "depth_feature", "degree", "ridge"}``.
    """
    exponents = monomials(3, degree)
    if len(samples) < len(exponents) + 1:
        raise NodeError(
            f"a degree-{degree} polynomial of (u, v, disparity) has {len(exponents)} "
            "coefficients per axis and needs "
            f"at least {len(exponents) + 1} placements, got {len(samples)}."
        )
    feats = _features(samples, depth_feature)
    lo, hi = feats.min(axis=0), feats.max(axis=0)
    center, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    for name, h in zip(("u", "v", "disparity"), half):
        if not h > 0:
            raise NodeError(
                f"all training placements share one {name} value; a polynomial in it "
                "cannot be fitted."
            )
    design = _design((feats - center) / half, exponents)
    target = samples.truth_cm - samples.xyz_cm
    if ridge > 0:
        lam = ridge * float(np.mean(np.sum(design**2, axis=0)))
        penalty = np.sqrt(lam) * np.eye(len(exponents))[1:]
        a = np.vstack([design, penalty])
        b = np.vstack([target, np.zeros((len(exponents) - 1, 3))])
    else:
        a, b = design, target
    coef, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    if rank < len(exponents):
        raise NodeError(
            f"the training placements do not determine the {len(exponents)} coefficients "
            f"(rank {rank}); they are "
            "too few or too regularly placed in (u, v, disparity).",
        )
    return {
        "exponents": exponents,
        "center": [float(c) for c in center],
        "half_range": [float(h) for h in half],
        "coef_x_cm": [float(c) for c in coef[:, 0]],
        "coef_y_cm": [float(c) for c in coef[:, 1]],
        "coef_z_cm": [float(c) for c in coef[:, 2]],
        "depth_feature": depth_feature,
        "degree": int(degree),
        "ridge": float(ridge),
    }


def predict_xyz(coefficients: Mapping[str, Any], samples: Samples) -> np.ndarray:
    """Corrected positions, cm (N, 3), from a :func:`fit_xyz` model."""
    feats = _features(samples, coefficients["depth_feature"])
    scaled = (feats - np.asarray(coefficients["center"])) / np.asarray(coefficients["half_range"])
    design = _design(scaled, coefficients["exponents"])
    coef = np.column_stack(
        [coefficients["coef_x_cm"], coefficients["coef_y_cm"], coefficients["coef_z_cm"]]
    )
    return samples.xyz_cm + design @ coef


class XyzParams(FitParams):
    """Options of ``compensator.xyz``."""

    degree: int = Field(
        2, ge=1, le=4, description="Total polynomial degree in (u, v, depth feature) (unitless)."
    )
    ridge: float = Field(
        1e-6,
        ge=0.0,
        le=10.0,
        description="Ridge (Tikhonov) weight relative to the design matrix's mean squared column "
        "norm (unitless).",
    )
    depth_feature: Literal["inverse_disparity", "disparity"] = Field(
        "inverse_disparity",
        description="Third variable: 1/disparity (1/px, proportional to depth) or disparity (px).",
    )


def _title(params: XyzParams, model: dict) -> str:
    feature = "1/d" if params.depth_feature == "inverse_disparity" else "d"
    return (
        f"x, y, z corrections = degree-{params.degree} polynomials of image position (u, v) and "
        f"{feature}"
    )


@fit_compensator(
    "compensator.xyz",
    params=XyzParams,
    predict=predict_xyz,
    inputs=INPUTS,
    min_points=lambda p: len(monomials(3, p.degree)) + 1,
    span="disparity",
    axes=("x", "y", "z"),
    title=_title,
    version="3",
    model="x, y, z error polynomials (cm).",
    figure="x, y, z error (truth - measured, cm) vs disparity, one panel per axis: placements, "
    "model, "
    "valid range.",
)
def xyz(params: XyzParams, samples: Samples) -> dict[str, Any]:
    """Fit x, y and z corrections as polynomials of image position and disparity on the training
    placements."""
    return fit_xyz(samples, params.degree, params.ridge, params.depth_feature)
