"""``compensator.none``: the baseline that changes nothing.

It is fitted like the others (so it reports the raw training error and slots
into the same place of a pipeline) but its model is the identity.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from nodes.contracts.compensator._common import (
    METRICS_OUTPUT,
    TRAIN_INPUT,
    FitParams,
    Samples,
    build_model,
    model_metrics,
    node_label,
    training_samples,
)
from nodes.contracts.compensator._figure import fit_figure, held_out
from nodes.contracts.drawing import load_figures
from stereograph.api import Out, node

__all__ = ["fit_none", "none", "predict_none"]

INPUTS: tuple[str, ...] = ()


def fit_none(samples: Samples) -> dict[str, Any]:
    """The identity model has no coefficients."""
    return {}


def predict_none(coefficients: Mapping[str, Any], samples: Samples) -> np.ndarray:
    """Return the measured positions unchanged, cm (N, 3)."""
    return np.array(samples.xyz_cm, dtype=float, copy=True)


class NoneParams(FitParams):
    """No options: ``compensator.none`` is the identity."""


@node(
    "compensator.none",
    inputs=TRAIN_INPUT,
    outputs={
        "model": Out(
            "CompensationModel", save=True, description="Identity model + raw training error."
        ),
        "figure": Out(
            "Image",
            save=True,
            optional=True,
            description="Raw z error (truth - measured, cm) vs measured z:"
            " the baseline the others correct.",
        ),
        **METRICS_OUTPUT,
    },
    params=NoneParams,
    version="2",
    prepare=load_figures,
)
def none(params: NoneParams, train, ctx=None):
    """Baseline compensator: leaves every location as measured (reports the raw training error)."""
    label = node_label(ctx, "compensator.none")
    samples = training_samples(train, label, needs=INPUTS, min_points=0)
    if len(samples) == 0:
        # The baseline needs no training data: without truth it still passes locations through.
        model = {
            "type": "none",
            "coefficients": {},
            "valid_range": {},
            "frame": samples.frame,
            "n_train": 0,
            "train_before_cm": None,
            "train_residual_cm": None,
            "cv": {"k": params.cv_folds, "n": 0, "skipped": "no training placements"},
            "fit_time_s": 0.0,
            "options": {},
        }
    else:
        model = build_model(
            "none",
            samples,
            fit_none,
            predict_none,
            INPUTS,
            label,
            params.cv_folds,
            params.cv_seed,
            {},
        )
    figure = fit_figure(
        model,
        samples,
        predict_none,
        held_out(train, ("z_cm",)),
        "z_cm",
        ("z",),
        "identity: no correction (the raw training error, for comparison)",
        enabled=params.figure,
    )
    return {"model": model, "metrics": model_metrics(model), "figure": figure}
