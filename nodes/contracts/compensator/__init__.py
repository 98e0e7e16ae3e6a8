"""The fit-compensator contract: what a depth-compensation method is, and the shell that makes one a
node.

A method is a *fit function* (:class:`FitFunction`: training :class:`Samples` -> coefficients) and a
*predict function* (coefficients, samples -> corrected xyz, cm). :func:`fit_compensator` turns the
pair into a complete ``compensator.*`` node with the shared ports (:data:`TRAIN_INPUT`, the model,
figure and :data:`METRICS_OUTPUT`), the training-sample checks, the span check, cross-validation and
outlier screening (:func:`build_model`) and the fit figure. Parameters derive from
:class:`FitParams` (or :class:`RayFitParams`). Errors are ``measured - truth`` per axis, in cm.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from nodes.contracts.drawing import load_figures
from stereograph.api import Out, node

from ._common import (
    METRICS_OUTPUT,
    TRAIN_INPUT,
    FitParams,
    RayFitParams,
    Samples,
    build_model,
    model_metrics,
    node_label,
    require_span,
    samples_from_locations,
    training_samples,
)
from ._figure import fit_figure, held_out

__all__ = [
    "METRICS_OUTPUT",
    "TRAIN_INPUT",
    "FitFunction",
    "FitParams",
    "RayFitParams",
    "Samples",
    "build_model",
    "fit_compensator",
    "fit_figure",
    "held_out",
    "model_metrics",
    "node_label",
    "require_span",
    "samples_from_locations",
    "training_samples",
]


class FitFunction(Protocol):
    """``fit(params, samples) -> coefficients``: a method's fit on the training placements."""

    def __call__(self, params: Any, samples: Samples) -> dict[str, Any]: ...


# span -> (the quantity that must spread over the working range, its unit, the figure's x axis)
SPANS = {
    "z": ("measured distance z", "cm", "z_cm"),
    "disparity": ("disparity", "px", "disparity_px"),
}


def fit_compensator(
    name: str,
    *,
    params: type[FitParams],
    predict: Callable,
    inputs: tuple[str, ...],
    min_points: Callable[[Any], int],
    span: Literal["z", "disparity"],
    axes: tuple[str, ...],
    title: Callable[[Any, dict], str],
    model: str,
    figure: str,
    version: str = "1",
    check: Callable | None = None,
    after: Callable | None = None,
) -> Callable[[FitFunction], Callable]:
    """Decorator: a fit function -> a registered ``compensator.*`` node named ``name``.

    ``predict`` and ``inputs`` (the Location keys it reads) describe the model;
    ``min_points(params)`` the fewest usable placements; ``span`` which measured quantity must
    spread over the working range; ``axes`` and ``title(params, model)`` the figure; ``model`` and
    ``figure`` the outputs' descriptions. ``check(params, samples, label)`` may refuse the samples;
    ``after(params, model, samples, ctx)`` may warn about the fitted model. The node's description
    is the fit function's docstring.
    """
    method = name.rpartition(".")[2]
    spec = _FitSpec(name, method, predict, inputs, min_points, span, axes, title, check, after)

    def wrap(fit: FitFunction) -> Callable:
        def run(params, train, ctx=None):
            return _fit_and_describe(spec, fit, params, train, ctx)

        # (the module binds the node to this name: workers find it)
        run.__name__ = run.__qualname__ = method
        run.__module__, run.__doc__ = fit.__module__, fit.__doc__
        run.fit = fit
        outputs = {
            "model": Out("CompensationModel", save=True, description=model),
            "figure": Out("Image", save=True, optional=True, description=figure),
            **METRICS_OUTPUT,
        }
        return node(
            name,
            inputs=TRAIN_INPUT,
            outputs=outputs,
            params=params,
            version=version,
            prepare=load_figures,
        )(run)

    return wrap


@dataclass(frozen=True)
class _FitSpec:
    """What :func:`fit_compensator` was told about its model (see its docstring)."""

    name: str
    method: str
    predict: Callable
    inputs: tuple[str, ...]
    min_points: Callable[[Any], int]
    span: str
    axes: tuple[str, ...]
    title: Callable[[Any, dict], str]
    check: Callable | None
    after: Callable | None


def _fit_and_describe(spec: _FitSpec, fit: FitFunction, params, train, ctx) -> dict:
    """What a node made by :func:`fit_compensator` does: the usable training placements, their
    spread checked, the model fitted and described, its metrics and figure."""
    label = node_label(ctx, spec.name)
    n_min = spec.min_points(params)
    samples = training_samples(train, label, needs=spec.inputs, min_points=n_min)
    if spec.check is not None:
        spec.check(params, samples, label)
    what, unit, axis = SPANS[spec.span]
    values = samples.xyz_cm[:, 2] if spec.span == "z" else samples.disparity_px
    require_span(values, what, label, params.min_span_fraction, unit)
    fitted = build_model(
        spec.method,
        samples,
        lambda s: fit(params, s),
        spec.predict,
        spec.inputs,
        label,
        params.cv_folds,
        params.cv_seed,
        params.model_dump(),
        robust=params,
        min_points=n_min,
        ctx=ctx,
    )
    if spec.after is not None:
        spec.after(params, fitted, samples, ctx)
    picture = fit_figure(
        fitted,
        samples,
        spec.predict,
        held_out(train, spec.inputs),
        axis,
        spec.axes,
        spec.title(params, fitted),
        enabled=params.figure,
    )
    return {"model": fitted, "metrics": model_metrics(fitted), "figure": picture}
