"""Hard scene kinds of issue 15 for the synthetic rig: partial views and touching objects.

Each kind is drawn by rejection sampling until the *measured* visibility of the target ball
(share of its silhouette that the camera really sees: inside the image and not hidden by another
object) lies in the kind's range, so a benchmark can state "found rate for balls with >= 50 %
visible" without guessing. Kinds (``make_hard_scene(rig, kind, rng, ...)``):

``border_cut``     cut by the left or right border of the left image, 40-90 % visible (the less
                   visible of the two views; the other view may show more).
``occluded_part``  a box between the left camera and the ball hides part of it: 50-95 % visible.
``touching_box``   a box of another colour standing against the ball; the ball >= 97 % visible.
``touching_ball``  a ball of another colour (0.8-1.3 x the radius) touching it; >= 97 % visible.
``distractor``     a ball of another colour and about the same size (0.85-1.15 x) nearby, not
                   touching; the target >= 97 % visible.
``same_color``     a second ball of the *same* colour and about the same size, touching or close:
                   the right answer is "ambiguous" (not found).

Pure functions of the rig and the random generator; the older kinds in :mod:`._scenes` are not
touched (their renders stay byte-identical).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

HARD_KINDS = (
    "border_cut",
    "occluded_part",
    "touching_box",
    "touching_ball",
    "distractor",
    "same_color",
)

_N_RAYS = 600  # rays per view for the visibility estimate (binomial sd ~2 % at 50 %)


def _objects(scene: dict) -> list[dict]:
    from nodes.sources._raycast import _objects_of

    return _objects_of(scene)


def visible_fraction(rig: dict, scene: dict, cam_index: int, rng_seed: int = 0) -> float:
    """Share (0..1) of the target ball's silhouette that camera ``cam_index`` sees.

    Rays are drawn uniformly inside the ball's tangent cone (its solid angle, which for a ball
    of a few degrees is its image area up to < 1 %): a ray counts when its pixel lies inside the
    image and no other object is hit before the ball.
    """
    from nodes.sources._lens import project_points
    from nodes.sources._raycast import _hit_box, _hit_cylinder, _hit_sphere

    objs = _objects(scene)
    ball = objs[0]
    cam = rig["cams"][cam_index]
    O, Rtc = cam["origin_table"], cam["R_table_from_cam"]
    c_cam = (ball["c"] - O) @ Rtc
    dist = float(np.linalg.norm(c_cam))
    axis = c_cam / dist
    cos_a = math.sqrt(max(1.0 - (ball["r"] / dist) ** 2, 0.0))
    rng = np.random.default_rng(rng_seed)
    # Uniform in solid angle inside the cone: cos(theta) uniform in [cos_a, 1].
    ct = rng.uniform(cos_a, 1.0, _N_RAYS)
    st = np.sqrt(1.0 - ct * ct)
    ph = rng.uniform(0, 2 * np.pi, _N_RAYS)
    e1 = np.cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    rays = ct[:, None] * axis + st[:, None] * (np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2)
    w, h = rig["truth"]["image_size"]
    px = project_points(cam["K"], cam["D"], rays)
    seen = (px[:, 0] >= -0.5) & (px[:, 0] <= w - 0.5) & (px[:, 1] >= -0.5) & (px[:, 1] <= h - 0.5)
    D = rays @ Rtc.T  # table frame
    t_ball = _hit_sphere(O, D, ball["c"], ball["r"])
    for o in objs[1:]:
        if o["type"] == "sphere":
            t = _hit_sphere(O, D, o["c"], o["r"])
        elif o["type"] == "box":
            t, _ = _hit_box(O, D, o)
        else:
            t, _ = _hit_cylinder(O, D, o)
        seen &= ~(t < t_ball)
    return float(seen.mean())


def _other_colors(color: Any) -> list[str]:
    from nodes.sources._materials import COLORS

    own = color if isinstance(color, str) else ""
    # Not orange's neighbours either: "another colour" means one a colour test can tell apart.
    near = {"orange": {"red", "yellow", "pink"}, "red": {"orange", "pink"}}.get(own, set())
    return [n for n in COLORS if n not in {own, "white", "black", "grey"} | near]


def make_hard_scene(
    rig: dict,
    kind: str,
    rng: np.random.Generator,
    radius_cm: float,
    color: Any,
    draw_ball,
    inside_both,
) -> dict:
    """One scene of ``kind`` (see the module docstring); ``draw_ball(accept)`` and ``inside_both``
    are :func:`nodes.sources._scenes.make_scene`'s ball sampler and its "inside both images"
    test."""
    r = float(radius_cm)
    others = _other_colors(color)
    w, _ = rig["truth"]["image_size"]
    for _attempt in range(400):
        scene: dict = {"kind": kind, "ball": {"radius_cm": r, "color": color}, "objects": []}
        if kind == "border_cut":
            side = int(rng.integers(0, 2))

            def cut(c, sils, side=side):
                u0, _, u1, _ = sils[0]["bbox_px"]
                return u0 < 0 < u1 if side == 0 else u0 < w - 1 < u1

            c, _ = draw_ball(cut)
            lo, hi = 0.4, 0.9
        else:
            c, _ = draw_ball(inside_both)
            lo, hi = (0.5, 0.95) if kind == "occluded_part" else (0.97, 1.0)
        scene["ball"]["center_cm"] = [float(c[0]), float(c[1])]
        ang = rng.uniform(0, 2 * np.pi)
        obj = _hard_object(rig, kind, rng, c, r, ang, color, others)
        if obj is not None:
            scene["objects"].append(obj)
        vis = [
            visible_fraction(rig, scene, i, rng_seed=int(rng.integers(0, 2**31 - 1)))
            for i in (0, 1)
        ]
        if kind == "border_cut":
            ok = lo <= min(vis) <= hi and max(vis) >= lo
        elif kind == "occluded_part":
            ok = lo <= vis[0] <= hi and vis[1] >= lo
        else:
            ok = min(vis) >= lo
        if ok:
            return scene
    raise RuntimeError(
        f"could not build a {kind!r} scene with the required visibility; widen the distance range"
    )


def _hard_object(
    rig: dict,
    kind: str,
    rng: np.random.Generator,
    c: np.ndarray,
    r: float,
    ang: float,
    color: Any,
    others: list[str],
) -> dict | None:
    """The object that makes a scene of ``kind`` hard, beside the ball (centre ``c``, radius
    ``r``, cm) in the direction ``ang``: a box hiding part of it, a box or ball touching it, a
    look-alike; None for a kind without one."""
    dirv = np.array([math.cos(ang), math.sin(ang)])
    if kind == "occluded_part":
        C1 = rig["cams"][0]["origin_table"]
        to_cam = C1[:2] - c[:2]
        dist_xy = float(np.linalg.norm(to_cam))
        u = to_cam / dist_xy
        perp = np.array([-u[1], u[0]])
        gap = r + rng.uniform(1.0, 4.0)
        sight = c[2] + (C1[2] - c[2]) * gap / dist_xy
        pos = c[:2] + u * gap + perp * rng.choice([-1, 1]) * r * rng.uniform(0.9, 2.0)
        size = [2.0 * r, 1.5, sight + r * rng.uniform(0.3, 1.5)]
        return {
            "type": "box",
            "center_cm": [float(pos[0]), float(pos[1])],
            "size_cm": [float(s) for s in size],
            "yaw_deg": float(math.degrees(math.atan2(perp[1], perp[0]))),
            "color": str(rng.choice(others)),
        }
    elif kind == "touching_box":
        sx, sy = rng.uniform(2.5, 6.0), rng.uniform(2.5, 6.0)
        # Box face perpendicular to dirv at distance r from the centre: they touch.
        pos = c[:2] + dirv * (r + sy / 2.0)
        return {
            "type": "box",
            "center_cm": [float(pos[0]), float(pos[1])],
            "size_cm": [float(sx), float(sy), float(rng.uniform(1.5, 2.5 * r))],
            "yaw_deg": float(math.degrees(ang) - 90.0),
            "color": str(rng.choice(others)),
        }
    elif kind in ("touching_ball", "distractor", "same_color"):
        if kind == "touching_ball":
            r2, gap = r * rng.uniform(0.8, 1.3), 0.0
        elif kind == "distractor":
            r2, gap = r * rng.uniform(0.85, 1.15), rng.uniform(0.5, 5.0) * r
        else:
            r2, gap = (
                r * rng.uniform(0.9, 1.1),
                (0.0 if rng.random() < 0.5 else rng.uniform(0.2, 2.0) * r),
            )
        pos = c[:2] + dirv * (r + r2 + gap)
        col = color if kind == "same_color" else str(rng.choice(others))
        return {
            "type": "ball",
            "center_cm": [float(pos[0]), float(pos[1])],
            "radius_cm": float(r2),
            "color": col,
        }
    return None
