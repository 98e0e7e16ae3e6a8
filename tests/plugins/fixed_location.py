"""``toy.fixed_location``: one Location given in params (no images), for actuator tests through the
CLI. Not part of the built-in library."""

from __future__ import annotations

from stereograph.api import Field, Out, Params, node


class FixedParams(Params):
    x_cm: float = Field(17.0, description="x in the left-camera frame (cm).")
    y_cm: float = Field(4.0, description="y in the left-camera frame (cm).")
    z_cm: float = Field(2.5, description="z in the left-camera frame (cm).")


@node(
    "toy.fixed_location", outputs={"location": Out("Location", collection=True)}, params=FixedParams
)
def fixed_location(params: FixedParams):
    """One item, ``fixed``: a found object at the given point."""
    return {
        "location": {
            "fixed": {
                "pair": "fixed",
                "found": True,
                "reason": None,
                "x_cm": params.x_cm,
                "y_cm": params.y_cm,
                "z_cm": params.z_cm,
                "frame": "left_camera",
            }
        }
    }
