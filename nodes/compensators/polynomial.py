"""``compensator.polynomial``: depth correction as a polynomial of measured depth.

The thesis's style of compensation: the z error of the triangulated position is
fitted, over the training placements, as a low-order polynomial of the measured
z (``target: error``), or the true z directly as a polynomial of the measured z
(``target: z``). Fitting uses :meth:`numpy.polynomial.Polynomial.fit` (least
squares on a scaled domain, so high degrees stay well conditioned).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from numpy.polynomial import Polynomial

from nodes.contracts.compensator import fit_compensator
from nodes.contracts.compensator._common import (
    RayFitParams,
    Samples,
    along_ray,
    resolve_along_ray,
)
from stereograph.api import Field, NodeError

__all__ = ["fit_polynomial", "polynomial", "predict_polynomial"]

INPUTS = ("z_cm",)


def fit_polynomial(
    samples: Samples, degree: int = 2, target: str = "error", xy: str = "auto"
) -> dict[str, Any]:
    """Least-squares polynomial of measured z, cm.

    Parameters
    ----------
    samples : Samples
        Training placements with truth.
    degree : int
        Polynomial degree (0 = constant offset, 1 = offset + scale, ...).
    target : {"error", "z"}
        ``"error"``: fit ``z_true - z_measured``; ``"z"``: fit ``z_true``.
    xy : {"auto", "along_ray", "keep"}
        What the correction does to x, y (see :func:`resolve_along_ray`).

    Returns
    -------
    dict
        ``{"coef": [...], "domain": [z_min, z_max], "target", "degree", "along_ray"}``: the
        coefficients of :class:`numpy.polynomial.Polynomial` on its scaled domain (window [-1, 1]).
    """
    z = samples.xyz_cm[:, 2]
    z_true = samples.truth_cm[:, 2]
    y = z_true - z if target == "error" else z_true
    if len(z) < degree + 1:
        raise NodeError(
            f"a degree-{degree} polynomial needs at least {degree + 1} placements, got {len(z)}."
        )
    if len(np.unique(z)) < degree + 1:
        raise NodeError(
            f"a degree-{degree} polynomial needs {degree + 1} distinct measured "
            f"distances, got {len(np.unique(z))}."
        )
    poly = Polynomial.fit(z, y, deg=degree)
    z_new = z + poly(z) if target == "error" else poly(z)
    return {
        "coef": [float(c) for c in poly.coef],
        "domain": [float(d) for d in poly.domain],
        "target": target,
        "degree": int(degree),
        "along_ray": resolve_along_ray(xy, samples, z_new),
    }


def predict_polynomial(coefficients: Mapping[str, Any], samples: Samples) -> np.ndarray:
    """Corrected positions, cm (N, 3), from a :func:`fit_polynomial` model."""
    poly = Polynomial(coefficients["coef"], domain=coefficients["domain"], window=[-1.0, 1.0])
    z = samples.xyz_cm[:, 2]
    value = poly(z)
    z_new = z + value if coefficients["target"] == "error" else value
    return along_ray(samples.xyz_cm, z_new, samples.frame, coefficients.get("along_ray", True))


class PolynomialParams(RayFitParams):
    """Options of ``compensator.polynomial``."""

    degree: int = Field(
        2,
        ge=0,
        le=8,
        description="Polynomial degree in measured z (unitless; 0 = constant offset).",
    )
    target: Literal["error", "z"] = Field(
        "error",
        description="Fit the z error (true - measured, cm) or the true z (cm) as the "
        "polynomial's value.",
    )


def _title(params: PolynomialParams, model: dict) -> str:
    what = "z correction" if params.target == "error" else "true z (drawn as true - measured)"
    return f"{what} = degree-{params.degree} polynomial of measured z"


@fit_compensator(
    "compensator.polynomial",
    params=PolynomialParams,
    predict=predict_polynomial,
    inputs=INPUTS,
    min_points=lambda p: p.degree + 2,
    span="z",
    axes=("z",),
    title=_title,
    version="3",
    model="Polynomial of measured z (cm).",
    figure="z error (truth - measured, cm) vs measured z: placements, fitted curve, valid range.",
)
def polynomial(params: PolynomialParams, samples: Samples) -> dict[str, Any]:
    """Fit the z error (or true z) as a polynomial of measured z on the training placements."""
    return fit_polynomial(samples, params.degree, params.target, params.xy)
