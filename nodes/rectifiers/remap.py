"""``rectifier.remap``: apply a rectification to every stereo pair (``cv2.remap`` with precomputed
maps)."""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from nodes.rectifiers.opencv import rectified_points
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["RemapParams", "rectified_truth", "remap", "remap_pair"]

_INTERP = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "nearest": cv2.INTER_NEAREST}


def remap_pair(rect: dict, left: np.ndarray, right: np.ndarray, interpolation: str = "linear"):
    """Rectify one stereo pair with the rectification's precomputed fixed-point maps."""
    w, h = rect.get("source_size", rect["image_size"])
    for side, im in (("left", left), ("right", right)):
        if im.shape[1] != w or im.shape[0] != h:
            raise NodeError(
                f"rectifier.remap: the {side} image is {im.shape[1]}x{im.shape[0]} but "
                "the calibration "
                f"is for {w}x{h}.",
                hint="calibrate with images from the same cameras and "
                "resolution (a rectifier.given camera: set its image_size to the images' size)",
            )
    flag = _INTERP[interpolation]
    if "map_left_fixed" in rect:
        ml = (rect["map_left_fixed"], rect["map_left_interp"])
        mr = (rect["map_right_fixed"], rect["map_right_interp"])
    else:  # a Rectification from elsewhere: float maps only
        ml = (rect["map_left_x"], rect["map_left_y"])
        mr = (rect["map_right_x"], rect["map_right_y"])
    return cv2.remap(left, *ml, flag), cv2.remap(right, *mr, flag)


def rectified_truth(rect: dict, truth: dict | None) -> dict | None:
    """Add the ground truth's rectified-frame view: centre (cm) and its rectified pixels."""
    if truth is None or "center_left_cm" not in truth:
        return truth
    out = dict(truth)
    c = np.asarray(truth["center_left_cm"], dtype=float)
    c_rect = rect["R1"] @ c
    out["center_rectified_left_cm"] = [float(v) for v in c_rect]
    for side, P in (("left", rect["P1"]), ("right", rect["P2"])):
        p = P @ np.append(c_rect, 1.0)
        out[f"center_px_rect_{side}"] = [float(p[0] / p[2]), float(p[1] / p[2])]
    sil = truth.get("silhouette_left")
    if sil is not None:
        out["silhouette_centroid_px_rect_left"] = [
            float(v) for v in rectified_points(rect, sil["centroid_px"])[0]
        ]
    return out


class RemapParams(Params):
    interpolation: Literal["linear", "cubic", "nearest"] = Field(
        "linear", description="Resampling kernel (name); linear uses the fast fixed-point maps."
    )


@node(
    "rectifier.remap",
    inputs={"rectification": In("Rectification"), "pair": In("StereoPair")},
    outputs={"rectified": Out("RectifiedPair")},
    params=RemapParams,
    version="1",
)
def remap(params: RemapParams, rectification: dict, pair: dict) -> dict:
    """Rectify one stereo pair; copies ``split`` and adds the rectified-frame truth."""
    left, right = remap_pair(rectification, pair["left"], pair["right"], params.interpolation)
    out = {
        "id": pair["id"],
        "left": left,
        "right": right,
        "truth": rectified_truth(rectification, pair.get("truth")),
    }
    if "split" in pair:
        out["split"] = pair["split"]
    if pair.get("truth_disparity_path") and all(
        np.allclose(rectification.get(k, 0), np.eye(3)) for k in ("R1", "R2")
    ):
        # a dataset's truth holds for unrotated images
        out["truth_disparity_path"] = pair["truth_disparity_path"]
    return {"rectified": out}
