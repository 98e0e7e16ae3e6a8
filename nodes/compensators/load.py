"""``compensator.load``: a compensation model fitted by an earlier pipeline, read from its file.

Reads the ``CompensationModel`` JSON a run wrote (``<run>/<fit node>/model.json``); nothing is
refitted. Given a ``calibration`` input, a model fitted on another rig (image size, focal
length, baseline) is refused, naming both files. The cache key follows the file's content.
"""

from __future__ import annotations

from pathlib import Path

from nodes.compensators._table import PREDICTORS
from nodes.contracts.calibration_file import (
    ArtifactLoadParams,
    artifact_kind,
    artifact_reads,
    check_rig,
    read_artifact,
    resolve_path,
)
from stereograph.api import In, NodeError, Out, node

__all__ = ["load"]

_MADE_BY = "<run>/<fit node>/model.json, written by compensator.polynomial / .xyz / ..."


@node(
    "compensator.load",
    inputs={
        "calibration": In(
            "StereoCalibration",
            optional=True,
            description="The rig's calibration: the model must be fitted on it.",
        )
    },
    outputs={
        "model": Out("CompensationModel", description="The fitted model, as written by its run.")
    },
    params=ArtifactLoadParams,
    version="1",
    reads=artifact_reads,
)
def load(params: ArtifactLoadParams, calibration=None, ctx=None) -> dict:
    """Load a fitted compensation model (<run>/<fit>/model.json), checked against the rig."""
    label = "compensator.load"
    path = resolve_path(params.path, ctx.pipeline_dir if ctx is not None else Path.cwd())
    model = read_artifact(path, label, "CompensationModel", _MADE_BY)
    if artifact_kind(model) != "a CompensationModel":
        raise NodeError(
            f"{label}: {path} holds {artifact_kind(model)}, not a CompensationModel.",
            hint=f"give the model file a fit wrote: {_MADE_BY}",
        )
    if model["type"] not in PREDICTORS:
        raise NodeError(
            f"{label}: {path} holds a compensation model of unknown type {model['type']!r}; known: "
            f"{', '.join(sorted(PREDICTORS))}.",
            hint=f"give the model file a fit wrote: {_MADE_BY}",
        )
    check_rig(
        label,
        model.get("rig"),
        path,
        calibration,
        params.rig_tolerance,
        ctx.warn if ctx is not None else None,
    )
    model["source_file"] = str(path)
    return {"model": model}
