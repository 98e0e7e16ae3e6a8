"""Candidate regions of a mask and the choice of the object among them (size, roundness,
colour, then the largest).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ._color import object_color_score, object_pixel_count
from ._params import SegmenterParams


def candidates(mask: np.ndarray, min_area_px: float) -> list[dict]:
    """Outer contours of a 0/255 mask (holes ignored) with their shape measures.

    Returns a list of dicts: ``contour`` (Nx2 int), ``area_px`` (pixel count, approximated by
    the contour area plus half its perimeter), ``bbox`` [u0,v0,u1,v1] (inclusive),
    ``centroid_px``, ``roundness`` (area / (pi r_max^2), 1 for a disc).
    """
    cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    out = []
    for c in cnts:
        if len(c) < 4:
            continue
        m = cv2.moments(c)
        if m["m00"] <= 0:
            continue
        # Contour points are the centres of boundary pixels: the region extends half a pixel
        # further, hence + perimeter / 2 for the pixel count and + 0.5 for the radius.
        area = m["m00"] + 0.5 * cv2.arcLength(c, True)
        if area < min_area_px:
            continue
        x, y, w, h = cv2.boundingRect(c)
        out.append(
            {
                "contour": c,
                "area_px": float(area),
                "bbox": [x, y, x + w - 1, y + h - 1],
                "centroid_px": [m["m10"] / m["m00"], m["m01"] / m["m00"]],
                "roundness": roundness(c, m, area),
            }
        )
    return out


def roundness(contour: np.ndarray, moments: dict, area_px: float) -> float:
    """Pixel area over the disc of the farthest outline point from the centroid (1 for a disc).

    Contour points are the centres of boundary pixels, so the radius gets + 0.5 px.
    """
    cu, cv_ = moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]
    pts = contour.reshape(-1, 2)
    r_max = float(np.sqrt(((pts[:, 0] - cu) ** 2 + (pts[:, 1] - cv_) ** 2).max())) + 0.5
    return float(area_px / (math.pi * r_max**2))


def _filled(contour: np.ndarray, bbox) -> np.ndarray:
    """uint8 0/255 mask of a filled contour inside its bbox."""
    x0, y0, x1, y1 = bbox
    sub = np.zeros((y1 - y0 + 1, x1 - x0 + 1), np.uint8)
    cv2.drawContours(sub, [contour - np.int32([x0, y0])], -1, 255, cv2.FILLED)
    return sub


def _region(img_bgr: np.ndarray, c: dict) -> tuple[np.ndarray, np.ndarray]:
    """A candidate's bbox crop of the image and its filled mask there."""
    x0, y0, x1, y1 = c["bbox"]
    return img_bgr[y0 : y1 + 1, x0 : x1 + 1], _filled(c["contour"], c["bbox"])


def select_candidate(
    cands: list[dict],
    img_bgr: np.ndarray,
    r_range_px: tuple[float, float],
    params: SegmenterParams,
) -> tuple[dict | None, str | None]:
    """Choose the object among the candidates (coordinates of ``img_bgr``).

    Rules: plausible area (pi r^2 within the expected radius range), roundness, colour
    distance within tolerance (when a colour is configured); among the survivors the one most
    consistent with the colour, else the largest (the thesis's rule). Two survivors of
    near-equal area and no colour to tell them apart -> ambiguous.

    Every candidate that is not the one returned gets a one-word ``rejected`` tag (size,
    round, colour, smaller, ambiguous) for the overlays' rejected outlines.

    Returns
    -------
    (candidate or None, reason or None)
    """
    if not cands:
        return None, "no region found"
    a_min = math.pi * r_range_px[0] ** 2
    a_max = math.pi * r_range_px[1] ** 2
    ok, rejected = _plausible(cands, img_bgr, a_min, a_max, params)
    if not ok:
        return None, _none_plausible(cands, img_bgr, a_min, rejected)
    ok.sort(key=lambda c: -c["area_px"])
    if params.object.color_bgr is None and params.object.hue_range_deg is None:
        why = _merged_rival(cands, ok[0], a_max, params)
        if why:
            return None, why
    winner, why = _larger_or_better_coloured(ok, params)
    if winner is None:
        return None, why
    if winner.get("color_score") is not None:
        rival = _object_coloured_rival(cands, winner, img_bgr, a_min, a_max, params)
        if rival is not None:
            winner["rejected"] = rival["rejected"] = "ambiguous"
            return None, (
                "ambiguous: another region holds as much of the ball's colour "
                f"({rival['_object_px']:.0f} "
                f"px of it, the chosen one {winner['area_px']:.0f} px): a second ball of "
                "that colour, "
                "merged with its shadow or with what it touches?"
            )
    return winner, None


def _plausible(
    cands: list[dict], img_bgr: np.ndarray, a_min: float, a_max: float, params: SegmenterParams
) -> tuple[list[dict], list[str]]:
    """The candidates of a plausible area, round enough and of the object's colour (each with its
    ``color_score``), and why the others are not; each other one gets its ``rejected`` tag."""
    rejected = []
    ok = []
    for c in cands:
        if not (a_min <= c["area_px"] <= a_max):
            c["rejected"] = "size"
            rejected.append(f"area {c['area_px']:.0f} px outside {a_min:.0f}-{a_max:.0f}")
            continue
        if c["roundness"] < params.min_roundness:
            c["_why"] = c["rejected"] = "round"
            rejected.append(f"roundness {c['roundness']:.2f} < {params.min_roundness}")
            continue
        score = None
        if params.object.color_bgr is not None or params.object.hue_range_deg is not None:
            score = object_color_score(*_region(img_bgr, c), params.object)
        if score is not None and score > 1.0:
            c["rejected"] = "colour"
            rejected.append("colour differs from the object's")
            continue
        c["color_score"] = score
        ok.append(c)
    return ok, rejected


def _none_plausible(
    cands: list[dict], img_bgr: np.ndarray, a_min: float, rejected: list[str]
) -> str:
    """Why no candidate is the object: the only sizeable one is cut by the image border, or what
    was wrong with them."""
    h, w = img_bgr.shape[:2]
    biggest = max(cands, key=lambda c: c["area_px"])
    x0, y0, x1, y1 = biggest["bbox"]
    if biggest["area_px"] >= a_min and (x0 <= 0 or y0 <= 0 or x1 >= w - 1 or y1 >= h - 1):
        return "the only sizeable region touches the image border (object cut off?)"
    why = "; ".join(sorted(set(rejected))[:3])
    return f"no plausible region ({len(cands)} candidate(s): {why})"


def _merged_rival(cands: list[dict], a: dict, a_max: float, params: SegmenterParams) -> str | None:
    """(No colour to tell objects apart) why the largest plausible region ``a`` is ambiguous: a
    ball-sized region that failed only the roundness test may be the ball merged with what it
    touches, as plausible as the round winner. None when there is none."""
    rivals = [
        c
        for c in cands
        if c is not a
        and c.get("_why") == "round"
        and params.ambiguity_ratio * a["area_px"] <= c["area_px"] <= 3.0 * a_max
    ]
    if not rivals:
        return None
    a["rejected"] = rivals[0]["rejected"] = "ambiguous"
    return (
        f"ambiguous: 2 objects of about the ball's size ({a['area_px']:.0f} and "
        f"{rivals[0]['area_px']:.0f} px, one not round: touching something?); give "
        "object.color_bgr to tell them apart"
    )


def _larger_or_better_coloured(
    ok: list[dict], params: SegmenterParams
) -> tuple[dict | None, str | None]:
    """Among plausible candidates, largest first: the largest (the thesis's rule), or of two of
    near-equal area the one clearly closer to the object's colour; ``(None, why)`` when they
    cannot be told apart. The others get their ``rejected`` tag."""
    winner = ok[0]
    if len(ok) == 1:
        return winner, None
    a, b = ok[0], ok[1]
    if b["area_px"] < params.ambiguity_ratio * a["area_px"]:
        for c in ok[1:]:
            c["rejected"] = "smaller"
        return winner, None
    if a.get("color_score") is not None and abs(a["color_score"] - b["color_score"]) > 0.25:
        ok.sort(key=lambda c: c["color_score"])
        for c in ok[1:]:
            c["rejected"] = "colour"
        return ok[0], None
    a["rejected"] = b["rejected"] = "ambiguous"
    what = "and colour " if a.get("color_score") is not None else ""
    hint = "" if what else "; give object.color_bgr to tell them apart"
    return None, (
        f"ambiguous: 2 round objects of similar size {what}({a['area_px']:.0f} and "
        f"{b['area_px']:.0f} px){hint}"
    )


def _object_coloured_rival(
    cands: list[dict],
    winner: dict,
    img_bgr: np.ndarray,
    a_min: float,
    a_max: float,
    params: SegmenterParams,
) -> dict | None:
    """A candidate other than ``winner`` that holds a ball-sized patch of the object's colour, or
    None.

    A region's median colour is not enough: a second ball of the object's colour whose outline
    merged with its shadow (or a touching object) has a median pulled away from the colour -- or
    fails the roundness test -- and would leave the other ball as a confident, possibly wrong,
    answer. Counted here are the pixels within the colour tolerance (or hue range); a region with
    at least ``ambiguity_ratio`` of the winner's area of them, and at least the smallest ball's
    area, may be a second ball.
    """
    need = max(a_min, params.ambiguity_ratio * winner["area_px"])
    for c in sorted(cands, key=lambda c: -c["area_px"]):
        if c is winner or c["area_px"] < need or c["area_px"] > 3.0 * a_max:
            continue
        n = object_pixel_count(*_region(img_bgr, c), params.object)
        if n >= need:
            c["_object_px"] = n
            return c
    return None
