"""``compensator.apply``: correct each measured location with a fitted compensation model.

Runs once per item. Dispatches on ``model["type"]`` through
:data:`nodes.compensators._table.PREDICTORS`, so any fitted model (polynomial,
disparity curve, lookup table, 3-D polynomial, or the identity) plugs in.

- ``found: false`` locations pass through unchanged.
- A measurement whose inputs (z, disparity, image position) lie outside the
  model's training range is still corrected, and marked ``extrapolated: true``;
  so is one inside that range but off the training placements' surface, or one
  whose correction is far larger than any in training (``_support.py``).
- A correction that is undefined for the measurement (the disparity curve's
  pole) turns the item into ``found: false`` with the reason, never a NaN.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from nodes.compensators._table import PREDICTORS
from nodes.contracts.compensator._common import node_label, samples_from_locations
from nodes.contracts.compensator._support import outside_support
from stereograph.api import In, NodeError, Out, Params, node

__all__ = ["apply", "apply_model"]


def apply_model(
    model: Mapping[str, Any], location: Mapping[str, Any], label: str = "compensator.apply"
) -> dict:
    """Correct one Location with a CompensationModel.

    Parameters
    ----------
    model : dict
        A ``CompensationModel`` artifact (``type``, ``coefficients``, ``valid_range``, ``frame``).
    location : dict
        A ``Location`` artifact.
    label : str
        How to name the node in errors.

    Returns
    -------
    dict
        A new Location: corrected ``x_cm``, ``y_cm``, ``z_cm`` (cm), ``extrapolated`` (bool), the
        measured ``raw_x_cm``, ``raw_y_cm``, ``raw_z_cm`` (cm) and ``compensation`` = ``{"type",
        "raw_cm": [x, y, z] as measured}``. Unchanged when not found.

    Raises
    ------
    NodeError
        Unknown model type, a frame mismatch, or a found location lacking a quantity the model
        reads.
    """
    if not location.get("found"):
        return dict(location)
    mtype = model.get("type")
    predict, needs, samples = _checked_inputs(model, location, label)
    out = dict(location)
    corrected = np.asarray(predict(model.get("coefficients", {}), samples), dtype=float)[0]
    raw = [float(v) for v in samples.xyz_cm[0]]
    if not np.all(np.isfinite(corrected)):
        out.update(
            found=False,
            reason=f"the {mtype} compensation is undefined for this measurement (inputs "
            + ", ".join(f"{k}={samples.variable(k)[0]:.4g}" for k in needs)
            + "), far outside its training range",
            x_cm=None,
            y_cm=None,
            z_cm=None,
            sigma_z_cm=None,
            extrapolated=True,
            raw_x_cm=raw[0],
            raw_y_cm=raw[1],
            raw_z_cm=raw[2],
            compensation={"type": mtype, "raw_cm": raw},
        )
        return out
    extrapolated = bool(location.get("extrapolated", False))
    outside = _outside(model, samples, raw, corrected)
    out.update(
        x_cm=float(corrected[0]),
        y_cm=float(corrected[1]),
        z_cm=float(corrected[2]),
        extrapolated=extrapolated or bool(outside),
        # what the locator measured, next to the correction
        raw_x_cm=raw[0],
        raw_y_cm=raw[1],
        raw_z_cm=raw[2],
        compensation={"type": mtype, "raw_cm": raw, "outside_range": outside},
    )
    sigma = location.get("sigma_z_cm")
    if sigma is not None and raw[2] != 0:
        # The depth noise scales with the depth correction's local scale; the ratio is a fair
        # first-order proxy.
        out["sigma_z_cm"] = float(abs(sigma * corrected[2] / raw[2]))
    return out


def _checked_inputs(
    model: Mapping[str, Any], location: Mapping[str, Any], label: str
) -> tuple[Any, tuple[str, ...], Any]:
    """``(the model's predict, the quantities it reads, the location as Samples)``; NodeError for
    an unknown model, a frame mismatch, or a quantity the location lacks."""
    mtype = model.get("type")
    if mtype not in PREDICTORS:
        raise NodeError(
            f"{label}: unknown compensation model type {mtype!r}; known: "
            f"{', '.join(sorted(PREDICTORS))}.",
            hint="wire the 'model' input to a compensator fit node (compensator.polynomial, ...).",
        )
    predict, needs = PREDICTORS[mtype]
    frame = location.get("frame", "left_camera")
    if model.get("frame", frame) != frame:
        raise NodeError(
            f"{label}: the model was fitted in the '{model.get('frame')}' frame but location "
            f"{location.get('pair')!r} is in the '{frame}' frame.",
            hint="fit and apply the compensator on locations from the same locator settings.",
        )
    item = str(location.get("pair", "?"))
    samples = samples_from_locations({item: location})
    missing = [
        k for k in ("x_cm", "y_cm", "z_cm", *needs) if not math.isfinite(samples.variable(k)[0])
    ]
    if missing:
        raise NodeError(
            f"{label}: location {item!r} is marked found but lacks finite "
            f"{', '.join(missing)}, which the "
            f"{mtype} model needs.",
            hint="the locator must report x_cm, y_cm, z_cm, disparity_px, u_left_px and "
            "v_left_px for found items.",
        )
    return predict, needs, samples


def _outside(
    model: Mapping[str, Any], samples: Any, raw: list[float], corrected: np.ndarray
) -> list[str]:
    """What puts a correction outside the model's support: each input outside its training
    range, and off the placements' surface or a correction far larger than any in training."""
    outside = []
    for name, rng in (model.get("valid_range") or {}).items():
        value = samples.variable(name)[0]
        if value < rng["min"] or value > rng["max"]:
            outside.append(name)
    # Inside the box of every input but off the placements' surface (an xyz model away from the
    # table), or a correction far larger than any in training: the model is not supported there
    # either.
    outside += outside_support(
        model.get("support"), len(model.get("valid_range") or {}), raw, corrected
    )
    return outside


class ApplyParams(Params):
    """``compensator.apply`` has no options: the model carries everything."""


@node(
    "compensator.apply",
    inputs={
        "model": In("CompensationModel", description="A fitted model (any compensator fit node)."),
        "location": In("Location", description="One measured location (runs once per item)."),
    },
    outputs={
        "location": Out(
            "Location",
            save=True,
            description="Compensated location (raw_x_cm.. as measured); extrapolated flags "
            "out-of-range input.",
        )
    },
    params=ApplyParams,
    version="1",
)
def apply(params: ApplyParams, model, location, ctx=None):
    """Correct a measured location with a fitted compensation model (flags extrapolation)."""
    out = apply_model(model, location, node_label(ctx, "compensator.apply"))
    if not out.get("found"):  # the written records all carry the same keys
        out.update(
            extrapolated=bool(out.get("extrapolated", False)),
            raw_x_cm=out.get("x_cm"),
            raw_y_cm=out.get("y_cm"),
            raw_z_cm=out.get("z_cm"),
        )
    return {"location": out}
