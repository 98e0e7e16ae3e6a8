"""Toy nodes that make Location records with a known systematic error (no images), for the
compensation / compare tests. Not part of the built-in library.

``toy.scenes`` (source, collection of true positions + pixel measurements) ->
``toy.triangulate`` (per item, believed baseline -> Location with truth and split).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ for compensation_data

from compensation_data import make_locations

from stereograph.api import Field, In, Out, Params, node


class ScenesParams(Params):
    n: int = Field(60, ge=1, le=10_000, description="Placements (count).")
    seed: int = Field(0, ge=0, description="Random seed.")
    noise_px: float = Field(0.1, ge=0, description="Pixel noise of u, v and disparity (px).")
    disparity_offset_px: float = Field(
        0.0, description="Offset added to every measured disparity (px)."
    )
    misdetect_fraction: float = Field(
        0.0,
        ge=0,
        le=1,
        description="Share of train placements measuring a distractor 15-40 cm away (unitless).",
    )


@node("toy.scenes", outputs={"scenes": Out("ToyScene", collection=True)}, params=ScenesParams)
def scenes(params: ScenesParams):
    """Placements: true centre (cm) and the rig's noisy pixel measurement of it."""
    locs = make_locations(
        n=params.n,
        seed=params.seed,
        noise_px=params.noise_px,
        disparity_offset_px=params.disparity_offset_px,
        misdetect_fraction=params.misdetect_fraction,
    )
    return {
        "scenes": {
            k: {
                "truth_cm": v["truth_cm"],
                "u_px": v["u_left_px"],
                "v_px": v["v_left_px"],
                "d_px": v["disparity_px"],
                "split": v["split"],
            }
            for k, v in locs.items()
        }
    }


class TriangulateParams(Params):
    f_px: float = Field(800.0, gt=0, description="Focal length (px).")
    baseline_cm: float = Field(10.0, gt=0, description="True baseline (cm).")
    baseline_scale: float = Field(1.0, gt=0, description="Believed / true baseline (unitless).")


@node(
    "toy.triangulate",
    inputs={"scene": In("ToyScene")},
    outputs={"location": Out("Location")},
    params=TriangulateParams,
)
def triangulate(params: TriangulateParams, scene, ctx=None):
    """z = f B / d with the believed baseline; x, y along the ray (pinhole, principal point 320,
    240)."""
    z = params.f_px * params.baseline_cm * params.baseline_scale / scene["d_px"]
    return {
        "location": {
            "pair": ctx.item if ctx else "?",
            "found": True,
            "reason": None,
            "x_cm": (scene["u_px"] - 320.0) * z / params.f_px,
            "y_cm": (scene["v_px"] - 240.0) * z / params.f_px,
            "z_cm": z,
            "sigma_z_cm": None,
            "frame": "left_camera",
            "disparity_px": scene["d_px"],
            "u_left_px": scene["u_px"],
            "v_left_px": scene["v_px"],
            "truth_cm": scene["truth_cm"],
            "split": scene["split"],
        }
    }


@node(
    "toy.count_found",
    inputs={"locations": In("Location", gather=True)},
    outputs={"n": Out("Number")},
)
def count_found(params, locations):
    """How many items were found (a reduce that makes the Location output non-terminal)."""
    return {"n": sum(1 for v in locations.values() if v.get("found"))}
