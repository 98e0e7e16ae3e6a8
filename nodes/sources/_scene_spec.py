"""The explicit scenes ``source.synthetic`` takes in YAML (``scenes: [...]``), as pydantic models,
so that a misspelt key or a missing size is refused by ``stereograph validate`` at its line instead
of being ignored. The renderer reads them as plain dicts (``model_dump``): see :mod:`._raycast`
(``_objects_of``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from stereograph.api import Field, Params

Colour = str | tuple[int, int, int]
Point = tuple[float, float] | tuple[float, float, float]


class SceneBall(Params):
    """The ball to locate."""

    center_cm: Point = Field(
        ..., description="Centre on the table, x, y (z = its radius) or x, y, z (cm, table frame)."
    )
    radius_cm: float = Field(2.0, gt=0, le=100, description="Radius (cm).")
    color: Colour = Field(
        "orange", description="A colour name of nodes/sources/_materials.py or [b, g, r] 0-255."
    )


class SceneObject(Params):
    """Clutter: a box, a cylinder or another ball."""

    type: Literal["box", "cylinder", "ball", "sphere"] = Field("box", description="Shape (name).")
    center_cm: Point = Field(
        ..., description="Centre on the table, x, y (cm, table frame); a ball's may give z."
    )
    size_cm: tuple[float, float, float] | None = Field(
        None, description="A box's x, y, z size (cm)."
    )
    yaw_deg: float = Field(0.0, description="A box's rotation about the table's normal (degrees).")
    radius_cm: float | None = Field(
        None, gt=0, description="A cylinder's or ball's radius (cm; a ball's default 2)."
    )
    height_cm: float | None = Field(None, gt=0, description="A cylinder's height (cm).")
    color: Colour = Field("grey", description="A colour name or [b, g, r] 0-255.")

    @model_validator(mode="after")
    def _shape_has_its_sizes(self) -> SceneObject:
        need = {"box": ["size_cm"], "cylinder": ["radius_cm", "height_cm"]}.get(self.type, [])
        missing = [n for n in need if getattr(self, n) is None]
        if missing:
            raise ValueError(f"a {self.type} needs {' and '.join(missing)}")
        return self


class SceneSpec(Params):
    """One explicit scene (``scenes:`` of source.synthetic)."""

    id: str | None = Field(None, description="The pair's id; default customNNN.")
    kind: str = Field("custom", description="A label carried into the truth (name).")
    ball: SceneBall | None = Field(None, description="The ball to locate; none = an empty scene.")
    objects: list[SceneObject] = Field(default_factory=list, description="Clutter objects.")
