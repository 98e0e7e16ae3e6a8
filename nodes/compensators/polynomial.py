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

from nodes.compensators._common import (
    METRICS_OUTPUT,
    TRAIN_INPUT,
    RayFitParams,
    Samples,
    along_ray,
    build_model,
    model_metrics,
    node_label,
    require_span,
    resolve_along_ray,
    training_samples,
)
from nodes.compensators._figure import fit_figure, held_out
from nodes.contracts.drawing import load_figures
from stereograph.api import Field, NodeError, Out, node

__all__ = ["fit_polynomial", "polynomial", "predict_polynomial"]

INPUTS = ("z_cm",)


def fit_polynomial(samples: Samples, degree: int = 2, target: str = "error", xy: str = "auto") -> dict[str, Any]:
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
        raise NodeError(f"a degree-{degree} polynomial needs at least {degree + 1} placements, got {len(z)}.")
    if len(np.unique(z)) < degree + 1:
        raise NodeError(
            f"a degree-{degree} polynomial needs {degree + 1} distinct measured distances, got {len(np.unique(z))}."
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

    degree: int = Field(2, ge=0, le=8, description="Polynomial degree in measured z (unitless; 0 = constant offset).")
    target: Literal["error", "z"] = Field(
        "error", description="Fit the z error (true - measured, cm) or the true z (cm) as the polynomial's value."
    )


@node(
    "compensator.polynomial",
    inputs=TRAIN_INPUT,
    outputs={"model": Out("CompensationModel", save=True, description="Polynomial of measured z (cm)."),
             "figure": Out("Image", save=True, optional=True,
                           description="z error (truth - measured, cm) vs measured z:"
                                       " placements, fitted curve, valid range."),
             **METRICS_OUTPUT},
    params=PolynomialParams,
    version="3",
    prepare=load_figures,
)
def polynomial(params: PolynomialParams, train, ctx=None):
    """Fit the z error (or true z) as a polynomial of measured z on the training placements."""
    label = node_label(ctx, "compensator.polynomial")
    samples = training_samples(train, label, needs=INPUTS, min_points=params.degree + 2)
    require_span(samples.xyz_cm[:, 2], "measured distance z", label, params.min_span_fraction, "cm")

    def fit(s: Samples) -> dict[str, Any]:
        return fit_polynomial(s, params.degree, params.target, params.xy)

    model = build_model(
        "polynomial", samples, fit, predict_polynomial, INPUTS, label, params.cv_folds, params.cv_seed,
        params.model_dump(), robust=params, min_points=params.degree + 2, ctx=ctx,
    )
    what = "z correction" if params.target == "error" else "true z (drawn as true - measured)"
    figure = fit_figure(model, samples, predict_polynomial, held_out(train, INPUTS), "z_cm", ("z",),
                        f"{what} = degree-{params.degree} polynomial of measured z", enabled=params.figure)
    return {"model": model, "metrics": model_metrics(model), "figure": figure}
