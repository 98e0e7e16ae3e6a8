"""``rectifier.given``: a ``Rectification`` for image pairs that are already rectified.

Public stereo data sets (Middlebury, KITTI, ETH3D) and many camera drivers deliver pairs that are
rectified already, with the rectified camera's focal length, principal point and baseline
published beside them. This node turns those numbers into the ``Rectification`` every other node
reads: identity remap maps (``rectifier.remap`` then passes the images through unchanged, so
``source.files`` reads such pairs as they are), ``P1``, ``P2`` and the reprojection matrix ``Q``
of OpenCV's ``stereoRectify`` convention, and ``R1 = I`` (the rectified left camera *is* the left
camera, so points come out in the left-camera frame).

The two principal points may differ in x (``cx_right_px``): then a point's disparity is
``d = f B / Z - (cx_right - cx)``; Middlebury calls ``cx_right - cx`` ``doffs`` (``dmin`` in the
2005/2006 sets). ``Q`` carries it, so ``Z = f B / (d + doffs)`` wherever ``Q`` is used.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np

from stereograph.api import Field, Out, Params, node

__all__ = ["GivenParams", "given", "given_rectification"]


class GivenParams(Params):
    """The rectified pair's published camera: focal length, principal points, baseline, size."""

    f_px: float = Field(..., gt=0, description="Focal length of the rectified cameras (px).")
    cx_px: float = Field(..., description="Principal point x of the rectified left image (px).")
    cy_px: float = Field(..., description="Principal point y of both rectified images (px).")
    cx_right_px: float | None = Field(
        None,
        description="Principal point x of the rectified right image (px); null = same as cx_px. "
        "cx_right_px - cx_px is Middlebury's doffs / dmin (px).",
    )
    baseline_cm: float = Field(
        ..., gt=0, description="Distance between the two camera centres (cm)."
    )
    image_size: tuple[
        Annotated[int, Field(gt=0, le=100_000)], Annotated[int, Field(gt=0, le=100_000)]
    ] = Field(..., description="Width and height of the images (px).")


def given_rectification(params: GivenParams) -> dict:
    """A ``Rectification`` (docs/artifacts.md) of an already rectified pair: identity maps, R1 = R2
    = I.

    Returns
    -------
    dict
        ``R1``, ``R2``, ``P1``, ``P2``, ``Q``, float identity maps ``map_{left,right}_{x,y}``
        (float32 HxW), ``f_px``, ``cx_px``, ``cy_px``, ``cx_right_px``, ``baseline_cm`` (cm),
        ``doffs_px`` (cx_right - cx, px), ``image_size``, ``K1``, ``D1`` (zero distortion), ``K2``,
        ``D2``, ``R`` (I), ``T_cm`` ([-B, 0, 0]), ``dy_mean_px`` / ``dy_max_px`` (None: nothing to
        measure).
    """
    w, h = (int(v) for v in params.image_size)
    f, cx, cy, b = (
        float(params.f_px),
        float(params.cx_px),
        float(params.cy_px),
        float(params.baseline_cm),
    )
    cxr = cx if params.cx_right_px is None else float(params.cx_right_px)
    K1 = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    K2 = np.array([[f, 0.0, cxr], [0.0, f, cy], [0.0, 0.0, 1.0]])
    P1 = np.hstack([K1, np.zeros((3, 1))])
    P2 = np.hstack([K2, np.array([[-f * b], [0.0], [0.0]])])
    # OpenCV's Q for a horizontal rig with Tx = -B: W = (d - (cx - cx_right)) / B, Z = f / W.
    Q = np.array(
        [
            [1.0, 0.0, 0.0, -cx],
            [0.0, 1.0, 0.0, -cy],
            [0.0, 0.0, 0.0, f],
            [0.0, 0.0, 1.0 / b, (cxr - cx) / b],
        ]
    )
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    eye = np.eye(3)
    return {
        "R1": eye,
        "R2": eye.copy(),
        "P1": P1,
        "P2": P2,
        "Q": Q,
        "map_left_x": xs,
        "map_left_y": ys,
        "map_right_x": xs,
        "map_right_y": ys,
        "f_px": f,
        "cx_px": cx,
        "cy_px": cy,
        "cx_right_px": cxr,
        "doffs_px": cxr - cx,
        "baseline_cm": b,
        "image_size": [w, h],
        "source_size": [w, h],
        "K1": K1,
        "D1": np.zeros(5),
        "K2": K2,
        "D2": np.zeros(5),
        "R": eye.copy(),
        "T_cm": np.array([-b, 0.0, 0.0]),
        "dy_mean_px": None,
        "dy_max_px": None,
        "method": "given",
    }


@node(
    "rectifier.given",
    outputs={
        "rectification": Out(
            "Rectification", description="Identity maps, P1, P2, Q of the given camera."
        )
    },
    params=GivenParams,
    version="1",
)
def given(params: GivenParams) -> dict:
    """Pass-through rectifier for pairs that are already rectified: f, principal points, baseline ->
    Rectification."""
    return {"rectification": given_rectification(params)}
