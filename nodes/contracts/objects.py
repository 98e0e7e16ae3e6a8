"""What the pipeline looks for, declared once: the objects on the table and where they can be.

The ``Objects`` artifact (``objects.declare`` makes it; segmenters read it through their optional
``objects`` input) holds ``{"objects": [{"name", "radius_cm", "color_bgr", "hue_range_deg",
"color_tolerance", "min_saturation", "drop_place_cm"}, ...], "working_range_cm": [near, far]}``.
A node given it uses it instead of its own ``object`` / ``working_range_cm`` params, so swapping
the segmenter type keeps the object. Public names: :class:`ObjectSpec`, :class:`ObjectDecl`,
:class:`ObjectsParams`, :func:`declared_object`, :func:`objects_value`.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import model_validator

from stereograph.api import Field, NodeError, Params, PositiveRange

__all__ = ["ObjectDecl", "ObjectSpec", "ObjectsParams", "declared_object", "objects_value"]

_Channel = Annotated[int, Field(ge=0, le=255)]  # one 8-bit colour channel
_HueDeg = Annotated[float, Field(ge=0, le=360)]


class ObjectSpec(Params):
    """What the object looks like (YAML: ``object: {radius_cm: 2.0, color_bgr: [30, 40, 200]}``)."""

    radius_cm: float = Field(2.0, gt=0, le=100, description="Radius of the ball (cm).")
    color_bgr: tuple[_Channel, _Channel, _Channel] | None = Field(
        None,
        description="Expected colour of the ball, B, G, R in 0-255. Give it, or wire the "
        "segmenter's "
        "`appearance` input (segmenter.appearance learns it from training truth): None = unknown "
        "colour, and then any second round object of a ball's size makes the result ambiguous "
        "(not found); segmenter.color needs a colour (this, hue_range_deg or `appearance`).",
    )
    hue_range_deg: tuple[_HueDeg, _HueDeg] | None = Field(
        None,
        description="Accepted hue range in degrees (0-360, wraps if lo > hi), alternative to "
        "color_bgr.",
    )
    color_tolerance: float = Field(
        0.15,
        gt=0,
        le=2,
        description="Max L1 distance of normalised (b,g,r) chromaticity to color_bgr's (unitless).",
    )
    min_saturation: int = Field(
        60, ge=0, le=255, description="Min HSV saturation (0-255) of object pixels for hue ranges."
    )


class ObjectDecl(ObjectSpec):
    """One object of the declaration: an :class:`ObjectSpec` with a name and, optionally, its
    place."""

    name: str = Field(
        "ball",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9_.-]+$",
        description="What the object is called in results and reports (text).",
    )
    drop_place_cm: tuple[float, float, float] | None = Field(
        None,
        description="Where the object goes once picked (table frame, cm): x, y of the place's "
        "centre and "
        "the height of its floor above the table (0 = a spot on the table; a bin: its rim); "
        "None = no place (ik.clear_table reports such balls, never picks them).",
    )


class ObjectsParams(Params):
    """Parameters of ``objects.declare``: the objects and the working range, for the whole
    pipeline."""

    objects: list[ObjectDecl] = Field(
        default_factory=lambda: [ObjectDecl()],
        min_length=1,
        max_length=32,
        description="The objects on the table (each: name, radius_cm, color_bgr or "
        "hue_range_deg; no colour = learned or unknown).",
    )
    working_range_cm: PositiveRange = Field(
        (20.0, 80.0),
        description="Nearest and farthest distance of the objects from the cameras (cm).",
    )

    @model_validator(mode="after")
    def _objects_fit_the_working_range(self) -> ObjectsParams:
        far = max(self.working_range_cm)
        for o in self.objects:
            if far <= o.radius_cm:
                raise ValueError(
                    f"working_range_cm ends at {far:g} cm, within the radius of {o.name!r} "
                    f"({o.radius_cm:g} cm): the cameras would be inside it; give the "
                    "distances from "
                    "the cameras to the objects' centres, in cm"
                )
        names = [o.name for o in self.objects]
        if len(set(names)) < len(names):
            raise ValueError(
                f"two objects share a name ({sorted({n for n in names if names.count(n) > 1})}): "
                "give each its own"
            )
        return self


def declared_object(
    objects: dict, name: str | None = None
) -> tuple[ObjectSpec, tuple[float, float]]:
    """The object called ``name`` (default: the first) of an ``Objects`` value, and the working
    range.

    Raises
    ------
    NodeError
        The value is not an ``Objects`` artifact, or no object has that name.
    """
    try:
        decls = [ObjectDecl(**o) for o in objects["objects"]]
        near, far = (float(v) for v in objects["working_range_cm"])
    except (KeyError, TypeError, ValueError) as exc:
        raise NodeError(
            f"the `objects` input is not an Objects artifact ({exc}).",
            hint="wire `objects` to an objects.declare node",
        ) from None
    chosen = next((d for d in decls if name is None or d.name == name), None)
    if chosen is None:
        raise NodeError(
            f"no object named {name!r} is declared (declared: {', '.join(d.name for d in decls)}).",
            hint="fix object_name, or declare that object in objects.declare",
        )
    return ObjectSpec(**chosen.model_dump(include=set(ObjectSpec.model_fields))), (near, far)


def objects_value(params: ObjectsParams) -> dict[str, Any]:
    """The ``Objects`` artifact of a declaration."""
    return {
        "objects": [o.model_dump() for o in params.objects],
        "working_range_cm": list(params.working_range_cm),
    }
