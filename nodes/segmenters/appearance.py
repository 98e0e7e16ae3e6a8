"""``segmenter.appearance``: learn the ball's colour from the training placements' ground truth.

Without ``object.color_bgr`` a segmenter can only tell the ball from another round object of a
ball's size by size, and refuses the pair as ambiguous when both are plausible. The training
placements (pairs whose ``split`` is ``train`` and whose ``truth`` gives the ball's centre) say
where the ball is: its true centre is projected into both rectified images, the pixels of the
inner part of its disc are read, and their median colour becomes the object's colour for every
segmenter wired to this node's ``appearance`` output (a colour given in the segmenter's own
YAML wins). A placement whose disc colour disagrees with the others' by far more than they
disagree among themselves (wrong truth, ball hidden) is left out and listed with its distance.

The tolerance is the 0.15 a user gets by default when giving the colour, so that a learned colour
behaves exactly as a given one -- the segmenters' tie-break between two round candidates compares
colour scores relative to the tolerance, and a tighter one would turn shading differences between
two balls of one colour into a confident choice. Only when the placements' own colours spread
more (3 robust standard deviations, 1.4826 MAD, of their distances) is it widened, up to 0.3.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from nodes.contracts.segmenter._checks import pair_is_raw
from nodes.contracts.segmenter._color import color_distance_map
from nodes.contracts.views import pair_views
from stereograph.api import Field, In, NodeError, Out, Params, node

# ObjectSpec.color_tolerance's default: a learned colour is never tighter than a given one
MIN_TOLERANCE = 0.15
MAX_TOLERANCE = 0.3  # chromaticity L1: looser than this, other coloured objects pass as the ball
DARK = 25  # gray levels: chromaticity is noise below this (as color_distance_map)


class AppearanceParams(Params):
    """Parameters of ``segmenter.appearance``."""

    split: Literal["train", "all"] = Field(
        "train",
        description="Which placements with truth to learn from: train = those of the training "
        "split, all = "
        "every pair with truth (name).",
    )
    radius_cm: float = Field(
        2.0, gt=0, le=100, description="Ball radius when the truth does not give one (cm)."
    )
    disc_fraction: float = Field(
        0.6,
        gt=0.1,
        le=0.9,
        description="Radius of the disc read around the projected centre, as a share of the "
        "ball's image radius (ratio): the inner part, away from the outline.",
    )
    min_pairs: int = Field(
        3,
        ge=1,
        le=1000,
        description="Fewest placements whose colour agrees; fewer -> the node refuses (count).",
    )
    max_outlier_distance: float = Field(
        0.08,
        gt=0,
        le=2,
        description="A placement whose median colour is farther than this from the others' "
        "(chromaticity L1, unitless), and than 4 times their spread, is left out.",
    )


def _centre_in_rectified(
    X_left_cm: np.ndarray, rect: dict, side: str
) -> tuple[float, float, float] | None:
    """(u, v, z_cm) of a left-camera-frame point in the rectified ``side`` image, None behind the
    camera."""
    Xr = np.asarray(rect["R1"], float) @ X_left_cm  # rectified-left frame
    P = np.asarray(rect["P1" if side == "left" else "P2"], float)
    x = P @ np.append(Xr, 1.0)
    if Xr[2] <= 0 or x[2] <= 0:
        return None
    return float(x[0] / x[2]), float(x[1] / x[2]), float(Xr[2])


def disc_pixels(view, u: float, v: float, r_px: float) -> np.ndarray | None:
    """BGR uint8 pixels (Nx3) of the disc of radius ``r_px`` around (u, v) in a rectified view;
    None when the disc is not wholly inside the image."""
    h, w = view.shape[:2]
    u0, v0 = int(math.floor(u - r_px)), int(math.floor(v - r_px))
    u1, v1 = int(math.ceil(u + r_px)) + 1, int(math.ceil(v + r_px)) + 1
    if u0 < 0 or v0 < 0 or u1 > w or v1 > h or r_px < 1.0:
        return None
    win = view.window(u0, v0, u1, v1)
    yy, xx = np.mgrid[v0:v1, u0:u1]
    inside = (xx - u) ** 2 + (yy - v) ** 2 <= r_px * r_px
    px = win[inside]
    return px if px.ndim == 2 and px.shape[1] == 3 else None


def _truth_centre(truth: dict | None, T_table_from_left) -> np.ndarray | None:
    if not truth:
        return None
    if truth.get("center_left_cm") is not None:
        return np.asarray(truth["center_left_cm"], float)
    if truth.get("center_table_cm") is not None and T_table_from_left is not None:
        T = np.asarray(T_table_from_left, float)
        return np.linalg.solve(T[:3, :3], np.asarray(truth["center_table_cm"], float) - T[:3, 3])
    return None


def learn_appearance(
    pairs: dict, rect: dict, params: AppearanceParams, raw: bool, T_table_from_left=None
) -> dict:
    """The ``ObjectAppearance`` of the ball from the placements with truth (see the module
    docstring)."""
    colours, used, left_out, considered = _placement_colours(
        pairs, rect, params, raw, T_table_from_left
    )
    if not colours:
        raise NodeError(
            f"segmenter.appearance: none of the {len(pairs)} pairs is a {params.split} "
            "placement with a usable "
            f"ball centre in its truth{_first_reasons(left_out)}.",
            hint="learn from pairs with ground truth (source.files with a `truth` file, "
            "source.synthetic), set "
            "`split: all` to use every pair with truth, or give object.color_bgr to the "
            "segmenter instead.",
        )
    colours = np.asarray(colours)
    dist, keep = _agreeing(colours, used, params, left_out)
    n_keep = int(keep.sum())
    if n_keep < params.min_pairs:
        raise NodeError(
            f"segmenter.appearance: {n_keep} of the {considered} {params.split} "
            "placement(s) with truth give the "
            f"ball's colour, fewer than min_pairs {params.min_pairs}{_first_reasons(left_out)}.",
            hint="add training placements with ground truth, lower `min_pairs`, or give "
            "object.color_bgr to the "
            "segmenter.",
        )
    colour = np.median(colours[keep], axis=0)
    d_keep = _distances(colours[keep], colour)
    spread_tol = 3.0 * 1.4826 * float(np.median(d_keep))
    tol = float(np.clip(spread_tol, MIN_TOLERANCE, MAX_TOLERANCE))
    return {
        "color_bgr": [int(round(c)) for c in colour],
        "color_tolerance": tol,
        # the placements' colours spread more than 0.15
        "tolerance_widened": bool(spread_tol > MIN_TOLERANCE),
        "note": "color_bgr is the median of the ball's lit and shaded pixels: darker than its "
        "paint, with the "
        "same chromaticity, which is what the segmenters compare (distance: chromaticity L1, 0-2)",
        "n_considered": considered,
        "n_pairs": n_keep,
        "pairs": [p for p, k in zip(used, keep, strict=True) if k],
        "distance": {p: float(d) for p, d in zip(used, dist, strict=True)},
        "left_out": left_out,
        "split": params.split,
    }


def _placement_colours(pairs: dict, rect: dict, params: AppearanceParams, raw: bool, T):
    """``(the ball's colour in each usable placement, their ids, {id: why not} for the others,
    how many of the split's placements have truth)``."""
    colours, used, left_out = [], [], {}
    considered = 0
    for pid, pair in sorted(pairs.items()):
        if not isinstance(pair, dict):
            continue
        if params.split == "train" and pair.get("split") != "train":
            continue
        truth = pair.get("truth")
        considered += bool(truth)
        X = _truth_centre(truth, T)
        if X is None:
            if truth:
                left_out[pid] = (
                    "truth has no ball centre in the left-camera frame (wire `rig` for a "
                    "table-frame one)"
                )
            continue
        colour, why = _pair_colour(pair, rect, params, raw, X, truth)
        if why is not None:
            left_out[pid] = why
            continue
        colours.append(colour)
        used.append(pid)
    return colours, used, left_out, considered


def _agreeing(
    colours: np.ndarray, used: list[str], params: AppearanceParams, left_out: dict
) -> tuple[np.ndarray, np.ndarray]:
    """``(each placement's colour distance to the median, which agree)``: a robust spread, never
    tighter than ``max_outlier_distance``; each one that does not is added to ``left_out``."""
    dist = _distances(colours, np.median(colours, axis=0))
    spread = 1.4826 * float(np.median(dist)) + 1e-3
    keep = dist <= max(params.max_outlier_distance, 4.0 * spread)
    for pid, d, k in zip(used, dist, keep, strict=True):
        if not k:
            left_out[pid] = (
                f"its colour is {d:.3f} from the others' (chromaticity L1): wrong truth "
                "or ball hidden?"
            )
    return dist, keep


def _pair_colour(
    pair: dict, rect: dict, params: AppearanceParams, raw: bool, X: np.ndarray, truth: dict | None
) -> tuple[np.ndarray | None, str | None]:
    """``(median BGR of the ball's disc in both images, None)`` of one placement whose true
    centre is ``X`` (left-camera frame, cm), or ``(None, why not)``."""
    R = float((truth or {}).get("radius_cm") or params.radius_cm)
    views = pair_views(rect, np.asarray(pair["left"]), np.asarray(pair["right"]), raw)
    px, why = [], None
    for side, view in zip(("left", "right"), views, strict=True):
        c = _centre_in_rectified(X, rect, side)
        if c is None:
            why = f"the true centre is behind the {side} camera"
            break
        u, v, z = c
        r_px = params.disc_fraction * float(rect["f_px"]) * R / z
        p = disc_pixels(view, u, v, r_px) if view.image.ndim == 3 else None
        if p is None:
            why = (
                f"the ball's disc is not wholly inside the {side} image"
                if view.image.ndim == 3
                else "gray images carry no colour"
            )
            break
        px.append(p)
    if why is not None:
        return None, why
    p = np.concatenate(px)
    p = p[p.max(axis=1) >= DARK]
    if len(p) < 10:
        return None, "the ball's disc is too dark to have a colour"
    return np.median(p.astype(np.float64), axis=0), None


def _distances(colours: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Chromaticity L1 distance of each BGR colour (Nx3) to ``ref`` (0..2)."""
    img = np.clip(np.round(colours), 0, 255).astype(np.uint8)[None]
    return color_distance_map(img, [float(c) for c in ref]).reshape(-1).astype(np.float64)


def _first_reasons(left_out: dict) -> str:
    if not left_out:
        return ""
    items = list(left_out.items())[:3]
    more = f" and {len(left_out) - 3} more" if len(left_out) > 3 else ""
    return " (left out: " + "; ".join(f"{k}: {v}" for k, v in items) + more + ")"


@node(
    "segmenter.appearance",
    inputs={
        "pair": In(
            "RectifiedPair | StereoPair",
            gather=True,
            description="All pairs; the training placements with truth are read (camera pairs are "
            "rectified on request).",
        ),
        "rectification": In(
            "Rectification",
            description="R1, P1, P2 to project the true centres; the maps for camera pairs.",
        ),
        "rig": In(
            "RigTruth | TableFrame",
            optional=True,
            description="T_table_from_left, for truth given in the table frame only.",
        ),
    },
    outputs={
        "appearance": Out(
            "ObjectAppearance",
            save=True,
            description="Learned color_bgr and color_tolerance, with the placements used and "
            "left out.",
        )
    },
    params=AppearanceParams,
    version="1",
)
def appearance(params: AppearanceParams, pair, rectification, rig=None, ctx=None):
    """Learn the ball's colour from the training placements' truth, for segmenters given no colour.

    Wire a segmenter's `appearance` input to this node's output; a colour in the segmenter's own
    object.color_bgr wins. Placements whose colour disagrees with the others are left out and
    listed.
    """
    if not isinstance(pair, dict):
        raise NodeError(
            "segmenter.appearance expects the gathered pairs ({id: pair}).",
            hint="wire `pair` to a source's `pairs` output or rectifier.remap's `rectified`.",
        )
    for key in ("R1", "P1", "P2", "f_px"):
        if not isinstance(rectification, dict) or rectification.get(key) is None:
            raise NodeError(
                f"segmenter.appearance: the Rectification lacks {key!r}.",
                hint="wire `rectification` to rectifier.opencv's output.",
            )
    raw = pair_is_raw(ctx, rectification)
    out = learn_appearance(pair, rectification, params, raw, (rig or {}).get("T_table_from_left"))
    if ctx is not None:
        b, g, r = out["color_bgr"]
        ctx.warn(
            f"learned BGR ({b}, {g}, {r}), tolerance {out['color_tolerance']:.2f}, from "
            f"{out['n_pairs']}/"
            f"{out['n_considered']} {params.split} placements with truth"
        )
        if out["left_out"]:
            ctx.warn(
                f"{len(out['left_out'])} placement(s) left out of the "
                f"colour{_first_reasons(out['left_out'])}"
            )
    return {"appearance": out}
