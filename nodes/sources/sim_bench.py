"""``source.sim_bench``: a simulated bench whose table reacts to the arm; each call grabs a pair of
it.

The table (balls of the declared objects, bins) lives in a world file (:mod:`simbench.world`) in
the run folder, made at the first call of the run and kept for every cycle of the loop. The
``world`` output tells ``actuator.dynamixel`` (``port: sim``) where it is: the emulated servos
then move the balls as they pick, carry and release them. Every call renders the table as it is
now through the rig's two cameras (``source.synthetic``'s rig and renderer), so the next cycle
sees what the last one did. Never cached.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from nodes.contracts.objects import ObjectDecl
from nodes.sources._render import render_scene
from nodes.sources._scenes import _ball_sils, _bbox_inside
from nodes.sources.synthetic import SyntheticParams, _shared_rig
from simbench.world import new_world, read_world, write_world
from stereograph.api import Field, In, NodeError, Out, Params, node


class BallAt(Params):
    """One ball placed by hand."""

    object: str = Field(..., description="Name of a declared object (objects.declare).")
    center_cm: tuple[float, float] = Field(
        ..., description="Where it rests, x y in the table frame (cm)."
    )


class SimBenchParams(Params):
    rig: SyntheticParams = Field(
        default_factory=SyntheticParams,
        description="The cameras, light and noise (source.synthetic's params; its scene "
        "and view counts are not used).",
    )
    balls: list[BallAt] = Field(
        default_factory=list, description="Balls placed by hand; empty = a random table."
    )
    n_balls: tuple[int, int] = Field(
        (4, 4), description="Random table: fewest and most balls (count)."
    )
    touching_fraction: float = Field(
        0.3, ge=0, le=1, description="Random table: share of balls put against another (0..1)."
    )
    region_cm: tuple[float, float, float, float] = Field(
        (0.0, 0.0, 12.0, 22.0),
        description="Random table: balls within this annulus, centre x y and radii min "
        "max (cm, table frame): where the arm reaches.",
    )
    depth_cm: tuple[float, float] = Field(
        (33.0, 55.0),
        description="Random table: nearest and farthest ball centre along the left camera's "
        "optical axis (cm): inside the range the depth compensation was fitted on.",
    )
    seed: int = Field(0, ge=0, description="Random table: seed of the placements and image noise.")
    base_in_table_cm: tuple[float, float] = Field(
        (0.0, 0.0), description="Where the arm base stands, x y (table frame, cm)."
    )
    base_yaw_deg: float = Field(
        90.0, description="Which way the arm base faces (deg about the table's z)."
    )
    bin_radius_cm: float = Field(
        3.5, gt=0, le=30, description="Radius of each object's place (cm)."
    )
    grasp_tolerance_cm: float = Field(
        1.0,
        gt=0,
        le=10,
        description="A closing gripper holds a ball whose centre "
        "is this close to its tool point (cm).",
    )
    missed_grasps: int = Field(
        0,
        ge=0,
        le=100,
        description="Fault injection: the first that many grasps close "
        "miss_offset_cm off the tool point (count).",
    )
    miss_offset_cm: float = Field(
        2.0, ge=0, le=20, description="Fault injection: how far off a missed grasp closes (cm)."
    )


def _pose(params: SimBenchParams) -> np.ndarray:
    a = math.radians(params.base_yaw_deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    T[:2, 3] = params.base_in_table_cm
    return T


def _in_view(rig: dict, center_cm, radius_cm: float) -> bool:
    """The whole ball inside both images (4 px from the border)."""
    sils = _ball_sils(rig, center_cm, radius_cm)
    return sils is not None and all(_bbox_inside(rig, s, 4.0) for s in sils)


def _ball(k: int, decl: ObjectDecl, xy) -> dict:
    """Ball ``b<k+1>`` of a declared object, resting on the table at ``xy`` (table frame, cm)."""
    r = float(decl.radius_cm)
    return {
        "id": f"b{k + 1}",
        "object": decl.name,
        "color_bgr": list(decl.color_bgr or (128, 128, 128)),
        "radius_cm": r,
        "center_cm": [float(xy[0]), float(xy[1]), r],
    }


def _random_balls(
    params: SimBenchParams, decls: list[ObjectDecl], places: list[dict], rig: dict
) -> list[dict]:
    rng = np.random.default_rng([params.seed, 29])
    T = np.asarray(rig["truth"]["T_table_from_left"], float)
    lo, hi = params.n_balls
    n = int(rng.integers(min(lo, hi), max(lo, hi) + 1))
    cx, cy, r_min, r_max = params.region_cm
    balls: list[dict] = []
    for k in range(n):
        d = decls[k % len(decls)] if k < len(decls) else decls[int(rng.integers(len(decls)))]
        r = float(d.radius_cm)
        for _ in range(2000):
            if balls and rng.random() < params.touching_fraction:
                other = balls[int(rng.integers(len(balls)))]
                a = rng.uniform(0, 2 * math.pi)
                gap = r + other["radius_cm"] + rng.uniform(0.0, 0.1)
                xy = np.asarray(other["center_cm"][:2]) + gap * np.array([math.cos(a), math.sin(a)])
            else:
                rad, a = math.sqrt(rng.uniform(r_min**2, r_max**2)), rng.uniform(0, 2 * math.pi)
                xy = np.array([cx + rad * math.cos(a), cy + rad * math.sin(a)])
            if not r_min <= math.dist(xy, (cx, cy)) <= r_max:
                continue
            if any(math.dist(xy, b["center_cm"][:2]) < r + b["radius_cm"] for b in balls):
                continue
            if any(math.dist(xy, p["center_cm"][:2]) < p["radius_cm"] + r + 1.0 for p in places):
                continue
            depth = float((T[:3, :3].T @ (np.array([*xy, r]) - T[:3, 3]))[2])
            if not params.depth_cm[0] <= depth <= params.depth_cm[1]:
                continue
            if not _in_view(rig, [*xy, r], r):  # (the costly test last: two silhouettes)
                continue
            balls.append(_ball(k, d, xy))
            break
    return balls


def _world(params: SimBenchParams, objects: dict, folder: Path, rig: dict) -> dict:
    decls = [ObjectDecl(**o) for o in objects["objects"]]
    places = [
        {
            "name": f"{d.name}_place",
            "object": d.name,
            "center_cm": list(d.drop_place_cm[:2]),
            "height_cm": float(d.drop_place_cm[2]),
            "radius_cm": params.bin_radius_cm,
        }
        for d in decls
        if d.drop_place_cm is not None
    ]
    by_name = {d.name: d for d in decls}
    if params.balls:
        unknown = sorted({b.object for b in params.balls} - set(by_name))
        if unknown:
            raise NodeError(
                f"source.sim_bench: balls of undeclared objects {unknown} (declared: "
                f"{sorted(by_name)}).",
                hint="name a declared object in each ball, or declare it in objects.declare",
            )
        balls = [_ball(k, by_name[b.object], b.center_cm) for k, b in enumerate(params.balls)]
    else:
        balls = _random_balls(params, decls, places, rig)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "world.json"
    write_world(
        path,
        new_world(
            balls,
            places,
            params.grasp_tolerance_cm,
            missed_grasps=params.missed_grasps,
            miss_offset_cm=params.miss_offset_cm,
        ),
    )
    return {"path": str(path), "T_table_from_base": _pose(params).tolist()}


def scene_of(world: dict) -> dict:
    """The renderer's scene for the world now: the balls not inside a bin, and the bins."""
    objs = [
        {
            "type": "ball",
            "center_cm": b["center_cm"],
            "radius_cm": b["radius_cm"],
            "color": b["color_bgr"],
        }
        for b in world["balls"]
        if not (b["state"] == "placed" and b["center_cm"][2] > b["radius_cm"] + 0.01)
    ]
    objs += [
        {
            "type": "cylinder",
            "center_cm": p["center_cm"][:2],
            "radius_cm": p["radius_cm"],
            "height_cm": p["height_cm"],
            "color": "grey",
        }
        for p in world["places"]
        if p["height_cm"] > 0
    ]
    return {"kind": "bench", "objects": objs}


class _Grabs:
    """The run's world and how many pairs were grabbed from it."""

    def __init__(self, ref: dict):
        self.ref, self.n = ref, 0


@node(
    "source.sim_bench",
    inputs={
        "objects": In(
            "Objects", description="What is on the table: each object's radius, colour, place."
        )
    },
    outputs={
        "pairs": Out(
            "StereoPair", collection=True, description="The table as the cameras see it now."
        ),
        "world": Out("BenchWorld", description="Where the world file is and where the arm stands."),
    },
    params=SimBenchParams,
    version="1",
    cacheable=False,
)
def sim_bench(params: SimBenchParams, objects, ctx=None):
    """Render the simulated table as it is now (the world is made at the run's first call)."""
    folder = ctx.out_dir if ctx is not None else Path.cwd() / "sim_bench"
    rig = _shared_rig(params.rig.model_dump_json())
    grabs = (
        ctx.resource("world", lambda: _Grabs(_world(params, objects, folder, rig))) if ctx else None
    )
    grabs = grabs or _Grabs(_world(params, objects, folder, rig))
    grabs.n += 1
    world = read_world(grabs.ref["path"])
    left, right, _ = render_scene(rig, scene_of(world), seed=params.seed * 100003 + grabs.n)
    pid = f"grab{grabs.n:04d}"
    # (read afresh from the file: nobody else holds it)
    truth = {
        "kind": "bench",
        "balls": world["balls"],
        "T_table_from_left": np.asarray(rig["truth"]["T_table_from_left"]).tolist(),
    }
    return {
        "pairs": {pid: {"id": pid, "left": left, "right": right, "truth": truth, "split": "test"}},
        "world": grabs.ref,
    }
