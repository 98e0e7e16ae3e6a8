"""Scene descriptions of the synthetic rig: plain ball placements and the hard kinds
(clutter, border, occlusion, ...), with their exact truth.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from nodes.sources._hard_scenes import HARD_KINDS, make_hard_scene
from nodes.sources._materials import COLORS
from nodes.sources._silhouette import silhouette

#: Scene kinds understood by :func:`make_scene`.
SCENE_KINDS = (
    "plain",
    "clutter",
    "second_ball",
    "border",
    "occluded",
    "hidden",
    "empty",
    *HARD_KINDS,
)


def _table_to_cam(rig: dict, cam_index: int, pts_table: np.ndarray) -> np.ndarray:
    cam = rig["cams"][cam_index]
    return (np.atleast_2d(pts_table) - cam["origin_table"]) @ cam["R_table_from_cam"]


def _bbox_inside(rig, sil: dict, margin: float) -> bool:
    w, h = rig["truth"]["image_size"]
    u0, v0, u1, v1 = sil["bbox_px"]
    return u0 >= margin and v0 >= margin and u1 <= w - 1 - margin and v1 <= h - 1 - margin


def _ball_sils(rig, center_table, radius):
    out = []
    for i in (0, 1):
        cc = _table_to_cam(rig, i, np.asarray(center_table, float))[0]
        if cc[2] <= radius:
            return None
        out.append(silhouette(rig["cams"][i]["K"], rig["cams"][i]["D"], cc, radius, n_boundary=256))
    return out


def _ball_on_table(
    C1: np.ndarray, dist_cm: float, bearing_rad: float, radius_cm: float
) -> np.ndarray | None:
    """Centre (table frame, cm) of a ball resting on the table ``dist_cm`` from the left camera's
    centre ``C1`` at ``bearing_rad`` from the table's y axis; None where the table is nearer than
    that."""
    dz = C1[2] - radius_cm
    if dist_cm <= dz:
        return None
    ground = math.sqrt(dist_cm * dist_cm - dz * dz)
    return np.array(
        [C1[0] + ground * math.sin(bearing_rad), C1[1] + ground * math.cos(bearing_rad), radius_cm]
    )


def _in_region(c: np.ndarray, region_cm) -> bool:
    return (
        region_cm is None
        or region_cm[2] <= math.hypot(c[0] - region_cm[0], c[1] - region_cm[1]) <= region_cm[3]
    )


#: Bearings (rad, from the table's y axis) :func:`make_scene` draws a ball at.
_BEARING_RAD = 0.7


def placeable_distance_range(
    rig: dict,
    radius_cm: float,
    accept,
    region_cm=None,
    n_draws: int = 3000,
    max_ground_cm: float = 250.0,
) -> tuple[float, float] | None:
    """(nearest, farthest) distance (cm) from the left camera at which :func:`make_scene`'s sampler
    finds a ball its scene kind accepts; None if it finds none.

    The kind's own test (``accept(center, silhouettes)``: inside both images, cut by a border, ...)
    and the placement region decide, so the range is the one the refused request had to fall in, not
    the plain "in both images" view (a ``border`` ball needs ~46 cm and more with the default rig,
    where a whole ball is seen from ~34 cm). A deterministic scan: distances stratified over the
    table up to ``max_ground_cm``, random bearings (seed 0); ~1 s, run only to explain a refusal.
    The ends are a few draws apart, a slight understatement of the range, so a range within them is
    placeable.
    """
    C1 = rig["cams"][0]["origin_table"]
    dz = C1[2] - radius_cm
    lo, hi = max(dz, 0.0), math.hypot(max_ground_cm, dz)
    rng = np.random.default_rng(0)
    found = []
    for k in range(n_draws):
        dist = lo + (k + rng.random()) * (hi - lo) / n_draws
        c = _ball_on_table(C1, dist, rng.uniform(-_BEARING_RAD, _BEARING_RAD), radius_cm)
        if c is None or not _in_region(c, region_cm):
            continue
        sils = _ball_sils(rig, c, radius_cm)
        if sils is not None and accept(c, sils):
            found.append(dist)
    return (min(found), max(found)) if found else None


def _unplaceable_message(rig: dict, kind: str, lo_cm: float, hi_cm: float, seen, region_cm) -> str:
    """Why no ball of ``kind`` could be drawn lo_cm-hi_cm from the left camera, and the fix that
    matches the cause: the range (beyond the rig's view of the table: which way to move the
    cameras), the placement region, or a request overlapping too little of what can be placed."""
    p = rig.get("params", {})
    rig_s = (
        f"with this rig (camera_height_cm {p.get('camera_height_cm', '?')}, camera_tilt_deg "
        f"{p.get('camera_tilt_deg', '?')}"
        + (f", placement region {list(region_cm)}" if region_cm is not None else "")
        + ")"
    )
    head = (
        f"could not place a ball for scene kind {kind!r} {lo_cm:g}-{hi_cm:g} cm from the left "
        f"camera: {rig_s}"
    )
    region_fix = ", widen the placement region" if region_cm is not None else ""
    if seen is None:
        return (
            f"{head} no such ball can be placed at any distance"
            + (" in the placement region" if region_cm is not None else "")
            + ": the cameras do not see the table where it must be; move the cameras "
            "(camera_height_cm, "
            f"camera_tilt_deg){region_fix}"
        )
    where = (
        f" such a ball can be placed only about {seen[0]:.0f} to {seen[1]:.0f} cm from the "
        "left camera"
    )
    if hi_cm < seen[0]:
        move = ", or bring the table nearer: camera_height_cm lower, camera_tilt_deg steeper"
    elif lo_cm > seen[1]:
        move = (
            ", or let the cameras see farther: camera_height_cm higher, camera_tilt_deg shallower"
        )
    else:  # overlapping: the requested range holds too little of it for the random draws
        return (
            f"{head}{where}, and {lo_cm:g}-{hi_cm:g} cm holds too little of that for "
            "random draws; set "
            f"min_distance_cm / max_distance_cm to cover more of it{region_fix}"
        )
    return f"{head}{where}; set min_distance_cm / max_distance_cm within that{region_fix}{move}"


def make_scene(
    rig: dict,
    kind: str = "plain",
    rng: np.random.Generator | int | None = None,
    radius_cm: float = 2.0,
    color: Any = "orange",
    min_distance_cm: float = 30.0,
    max_distance_cm: float = 60.0,
    border_margin_px: float = 4.0,
    region_cm: tuple[float, float, float, float] | None = None,
) -> dict:
    """Draw a random scene of a given kind (see the module docstring).

    Parameters
    ----------
    rig : dict
        From :func:`make_rig`.
    kind : str
        One of :data:`SCENE_KINDS`.
    rng : Generator or int or None
        Random source (or seed).
    radius_cm : float
        Ball radius, cm.
    color : str or [b, g, r]
        Ball colour.
    min_distance_cm, max_distance_cm : float
        Range of the ball centre's distance from the left camera, cm.
    border_margin_px : float
        For non-border kinds, the ball's silhouette stays this far inside both images.
    region_cm : (x, y, r_min, r_max) or None
        Keep the ball centre in this annulus of the table plane (table frame, cm): e.g. the
        part of the table a robot arm standing at (x, y) can reach.

    Returns
    -------
    scene : dict (plain data)
    """
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; use one of {SCENE_KINDS}")
    rng = np.random.default_rng(rng)
    ball = {"radius_cm": float(radius_cm), "color": color}
    C1 = rig["cams"][0]["origin_table"]

    draw_ball = functools.partial(
        _draw_ball, rig, rng, kind, radius_cm, (min_distance_cm, max_distance_cm), region_cm
    )

    def inside_both(c, sils):
        return all(_bbox_inside(rig, s, border_margin_px) for s in sils)

    if kind in HARD_KINDS:  # issue 15's kinds, measured visibility (nodes/sources/_hard_scenes.py)
        return make_hard_scene(rig, kind, rng, radius_cm, color, draw_ball, inside_both)
    scene: dict = {"kind": kind, "ball": None, "objects": []}
    others = [
        n for n in COLORS if n not in (color if isinstance(color, str) else "", "white", "black")
    ]
    if kind == "empty":
        c, _ = draw_ball(inside_both)
        scene["objects"].append(_box_in_place_of_ball(rng, c, others))
        return scene
    if kind == "border":
        c, _ = draw_ball(_border_cut(rig, int(rng.choice([0, 1])), border_margin_px))
    else:
        c, _ = draw_ball(inside_both)
    ball["center_cm"] = [float(c[0]), float(c[1])]
    scene["ball"] = ball
    if kind == "clutter":
        scene["objects"] += _clutter(rng, c, radius_cm, others)
    elif kind == "second_ball":
        scene["objects"].append(_second_ball(rng, c, radius_cm, others))
    elif kind in ("occluded", "hidden"):
        scene["objects"].append(_occluder(rng, kind, c, C1, radius_cm, others))
    return scene


def _draw_ball(rig, rng, kind, radius_cm, distance_range, region_cm, accept) -> tuple:
    """``(centre, silhouettes)`` of a ball on the table that ``accept(c, sils)`` takes: uniform
    in distance (``distance_range``, cm, from the left camera) and bearing, then checked against
    both images; RuntimeError naming the placeable range when none is found."""
    C1 = rig["cams"][0]["origin_table"]
    min_distance_cm, max_distance_cm = distance_range
    for _ in range(4000):
        # Uniform in distance and bearing, then checked against both images.
        # (the bearing is drawn only for a distance beyond the table: the draws, and so the
        # scenes of a seed, stay as they were)
        dist = rng.uniform(min_distance_cm, max_distance_cm)
        if dist <= C1[2] - radius_cm:
            continue
        c = _ball_on_table(C1, dist, rng.uniform(-_BEARING_RAD, _BEARING_RAD), radius_cm)
        if not _in_region(c, region_cm):
            continue
        sils = _ball_sils(rig, c, radius_cm)
        if sils is not None and accept(c, sils):
            return c, sils
    seen = placeable_distance_range(rig, radius_cm, accept, region_cm)
    raise RuntimeError(
        _unplaceable_message(rig, kind, min_distance_cm, max_distance_cm, seen, region_cm)
    )


def _box_in_place_of_ball(rng: np.random.Generator, c: np.ndarray, others: list[str]) -> dict:
    """A box where a ball could have been (the "empty" kind: nothing to find)."""
    return {
        "type": "box",
        "center_cm": [float(c[0]), float(c[1])],
        "size_cm": [5.0, 4.0, 3.0],
        "yaw_deg": float(rng.uniform(0, 90)),
        "color": str(rng.choice(others)),
    }


def _border_cut(rig: dict, side: int, margin_px: float) -> Callable[[Any, list], bool]:
    """A test of a ball's silhouettes: the left image's cuts it at its left border (``side`` 0, the
    right image's then whole) or its right border (1), at most half hidden, clear of the top and
    bottom by ``margin_px``."""
    w, h = rig["truth"]["image_size"]

    def cut(c, sils):
        u0, v0, u1, v1 = sils[0]["bbox_px"]
        inside_v = v0 > margin_px and v1 < h - 1 - margin_px
        if side == 0:  # cut by the left border of the left image
            return inside_v and u0 < 0 < (u0 + u1) / 2 and _bbox_inside(rig, sils[1], -1e9)
        return inside_v and (u0 + u1) / 2 < w - 1 < u1

    return cut


def _clutter(rng: np.random.Generator, c: np.ndarray, r: float, others: list[str]) -> list[dict]:
    """Two to four boxes and cylinders of other colours around the ball (centre ``c``, radius
    ``r``, cm)."""
    objects: list[dict] = []
    for _ in range(int(rng.integers(2, 5))):
        ang = rng.uniform(0, 2 * np.pi)
        d = rng.uniform(3.5 * r, 8 * r)
        pos = [float(c[0] + d * math.cos(ang)), float(c[1] + d * math.sin(ang))]
        if rng.random() < 0.5:
            objects.append(
                {
                    "type": "box",
                    "center_cm": pos,
                    "size_cm": [
                        float(rng.uniform(2, 6)),
                        float(rng.uniform(2, 6)),
                        float(rng.uniform(1.5, 6)),
                    ],
                    "yaw_deg": float(rng.uniform(0, 90)),
                    "color": str(rng.choice(others)),
                }
            )
        else:
            objects.append(
                {
                    "type": "cylinder",
                    "center_cm": pos,
                    "radius_cm": float(rng.uniform(1, 2.5)),
                    "height_cm": float(rng.uniform(2, 8)),
                    "color": str(rng.choice(others)),
                }
            )
    return objects


def _second_ball(rng: np.random.Generator, c: np.ndarray, r: float, others: list[str]) -> dict:
    """A ball of another colour near the ball."""
    ang = rng.uniform(0, 2 * np.pi)
    d = rng.uniform(3 * r, 7 * r)
    return {
        "type": "ball",
        "center_cm": [float(c[0] + d * math.cos(ang)), float(c[1] + d * math.sin(ang))],
        "radius_cm": float(r * rng.uniform(0.8, 1.3)),
        "color": str(rng.choice(others)),
    }


def _occluder(
    rng: np.random.Generator, kind: str, c: np.ndarray, C1: np.ndarray, r: float, others: list[str]
) -> dict:
    """A box on the line of sight from the left camera (at ``C1``), between it and the ball: beside
    the line, hiding part of the ball ("occluded"), or across it, hiding all of it ("hidden")."""
    to_cam = C1[:2] - c[:2]
    dist_xy = np.linalg.norm(to_cam)
    u = to_cam / dist_xy
    perp = np.array([-u[1], u[0]])
    gap = r + 2.0
    pos = c[:2] + u * (gap + 1.5)
    # Height the line of sight needs to be blocked at that position, plus margin.
    frac = (gap + 1.5) / dist_xy
    sight = c[2] + (C1[2] - c[2]) * frac
    if kind == "occluded":
        pos = pos + perp * rng.choice([-1, 1]) * r * rng.uniform(1.0, 1.5)
        size = [2.0 * r, 2.0, sight + r * rng.uniform(0.5, 1.2)]
    else:
        size = [4.0 * r, 2.0, sight + 2.0 * r]
    return {
        "type": "box",
        "center_cm": [float(pos[0]), float(pos[1])],
        "size_cm": [float(s) for s in size],
        "yaw_deg": float(math.degrees(math.atan2(perp[1], perp[0]))),
        "color": str(rng.choice(others)),
    }
