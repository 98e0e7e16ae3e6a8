"""``objects.declare``: what the pipeline looks for, declared once
(``nodes/contracts/objects.py``)."""

from __future__ import annotations

from nodes.contracts.objects import ObjectsParams, objects_value
from stereograph.api import Out, node


@node(
    "objects.declare",
    outputs={"objects": Out("Objects", description="The objects and the working range.")},
    params=ObjectsParams,
    version="1",
)
def declare(params: ObjectsParams) -> dict:
    """Declare the objects on the table (name, radius, colour, place) and the working range, once
    for the pipeline; wire `objects` into the segmenter, and any segmenter type keeps them."""
    return {"objects": objects_value(params)}
