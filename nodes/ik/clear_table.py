"""``ik.clear_table``: clear the table one pick a cycle: look again, choose the next ball, plan pick
-> place.

Each cycle of the loop it gets every located ball of the new pair (the IK nodes' JointTargets, one
per instance). First it judges the last pick (:func:`._clear.look_again`): its ball gone means
done; still there means a miss, retried once and then reported. Then the next ball: found,
reachable, its object's place known and reachable, not already at its place, nearest the base
first, and a path (approach and leave from above) that passes no other ball. Its plan is
``ik.pick_sequence``'s pick with the place; with nothing left it says why and asks the loop to
stop (``ctx.stop_loop``). A ball it cannot pick is reported, never attempted.
"""

from __future__ import annotations

import math

import numpy as np

from nodes.contracts.objects import ObjectDecl
from stereograph.api import Field, In, NodeError, Out, Params, node

from ._clear import Memory, at_place, look_again, path_clearance, sort_picks
from ._clear_picture import draw_cycle
from .pick_sequence import PickParams, plan_pick


class ClearParams(Params):
    approach_height_cm: float = Field(
        6.0,
        ge=0,
        le=100,
        description="Height above a ball's centre (and a place) to approach and leave from (cm).",
    )
    lift_height_cm: float = Field(
        8.0, ge=0, le=100, description="Height to lift a picked ball by (cm)."
    )
    release_gap_cm: float = Field(
        0.5,
        ge=0,
        le=20,
        description="Release a ball with its bottom this far above "
        "its place's floor or a bin's rim (cm).",
    )
    place_radius_cm: float = Field(
        3.0,
        gt=0,
        le=50,
        description="A ball this close to its object's place (horizontally) is there already (cm).",
    )
    finger_clearance_cm: float = Field(
        1.0,
        ge=0,
        le=10,
        description="Gap the fingers keep from every other ball along the path (cm).",
    )
    look_again_cm: float | None = Field(
        None,
        gt=0,
        le=20,
        description="A ball of the picked object this close "
        "to where it was is the one that was "
        "missed (cm); default its radius.",
    )
    max_retries: int = Field(
        1, ge=0, le=5, description="Picks again after a miss before it is reported (count)."
    )


def _places_base(objects: dict, hand_eye: dict, params: ClearParams) -> dict[str, dict]:
    T = hand_eye.get("T_base_from_table")
    if T is None:
        raise NodeError(
            "ik.clear_table: the hand-eye does not place the arm base in the table frame, so the "
            "objects' places (table frame) cannot be reached.",
            hint="set base_in_table on calibrator.hand_eye (or a hand-eye file that has it)",
        )
    T = np.asarray(T, float)
    out = {}
    for o in objects["objects"]:
        d = ObjectDecl(**o)
        if d.drop_place_cm is not None:
            x, y, h = d.drop_place_cm
            release = [x, y, h + d.radius_cm + params.release_gap_cm]
            out[d.name] = {
                "center_cm": (T[:3, :3] @ np.asarray([x, y, h]) + T[:3, 3]).tolist(),
                "release_cm": (T[:3, :3] @ np.asarray(release) + T[:3, 3]).tolist(),
                "radius_cm": params.place_radius_cm,
                "on_table": h <= 0.0,
            }
    return out


def _try(
    params: ClearParams, arm: dict, t: dict, place: dict, others: list
) -> tuple[dict | None, str | None]:
    pp = PickParams(
        approach_height_cm=params.approach_height_cm,
        lift_height_cm=params.lift_height_cm,
        place_cm=place["release_cm"],
        return_home=True,
    )
    try:
        plan = plan_pick(pp, arm, t)
    except NodeError as e:
        return None, e.message.split(": ", 1)[-1]
    gap, where = path_clearance(arm, plan, others, params.finger_clearance_cm)
    if gap < 0:
        return None, f"its path ({where}) passes {-gap:.1f} cm into another ball's space"
    plan.update(object=t.get("object"), path_clearance_cm=round(gap, 3))
    return plan, None


def _choose(params, arm, order, places, memory, first, n_now, unclear):
    """The first ball of the ``order`` that can be picked, its plan, and why the others cannot."""
    skipped = {}
    for t in order:
        place = places.get(t.get("object"))
        if place is None:
            skipped[t["pair"]] = f"object {t.get('object')!r} has no drop_place_cm"
            continue
        others = [
            (np.asarray(o["target_base_cm"]), float(o.get("object_radius_cm") or 0.0))
            for o in order
            if o is not t
        ]
        plan, why = _try(params, arm, t, place, others)
        if plan is not None:
            attempt = memory.last["attempt"] + 1 if first == t["pair"] and memory.last else 1
            memory.last = {
                "object": t.get("object"),
                "where": t["target_base_cm"],
                "attempt": attempt,
                "n_before": n_now.get(t.get("object"), 0),
                "unclear": unclear.get(t.get("object"), 0),
            }
            return plan, skipped
        skipped[t["pair"]] = why
    return None, skipped


def _given_up(memory: Memory, t: dict) -> bool:
    r = float(t.get("object_radius_cm") or 2.0)
    return any(
        g["object"] == t.get("object") and math.dist(g["where"], t["target_base_cm"]) <= r
        for g in memory.given_up
    )


@node(
    "ik.clear_table",
    inputs={
        "arm": In("ArmModel"),
        "targets": In("JointTarget", gather=True, description="Every located ball."),
        "hand_eye": In("HandEye", description="Where the arm base stands in the table frame."),
        "objects": In("Objects", description="Each object's place (drop_place_cm)."),
        "pair": In(
            "RectifiedPair | StereoPair",
            gather=True,
            optional=True,
            description="The pair the balls were located in: for the cycle's picture.",
        ),
        "rectification": In("Rectification", optional=True, description="For the picture."),
    },
    outputs={
        "plan": Out(
            "PickPlan", collection=True, description="This cycle's pick and place (or idle)."
        ),
        "status": Out(
            "ClearStatus", save=True, headline=True, description="What is left, what was done."
        ),
        "picture": Out(
            "Image",
            save=True,
            lossy=True,
            description="The table seen, each ball's label and order, the arm (needs pair).",
        ),
    },
    params=ClearParams,
    version="1",
    cacheable=False,
)
def clear_table(
    params: ClearParams, arm, targets, hand_eye, objects, pair=None, rectification=None, ctx=None
):
    """Look again at the last pick, then plan the next pick -> place; stop the loop when nothing is
    left."""
    memory = (ctx.resource("memory", Memory) if ctx is not None else None) or Memory()
    memory.cycle += 1
    places = _places_base(objects, hand_eye, params)
    ts = list((targets or {}).values())
    found = [
        t for t in ts if t.get("found") and not _given_up(memory, t) and not at_place(t, places)
    ]
    refused = {t["pair"]: t.get("reason") or "not located" for t in ts if not t.get("found")}
    n_now, unclear = _census(ts, places)
    verdict = _judge_last(params, memory, found, ts, places, n_now, ctx)
    if verdict and verdict["verdict"] == "given up":
        found = [t for t in found if not _given_up(memory, t)]
    first = verdict.get("target") if verdict and verdict["verdict"] == "retry" else None
    order = sort_picks(found, first)
    plan, skipped = _choose(params, arm, order, places, memory, first, n_now, unclear)
    status = {
        "cycle": memory.cycle,
        "seen": len(ts),
        "found": len(found),
        "look_again": verdict,
        "picked": memory.n_picked,
        "retries": memory.n_retries,
        "given_up": memory.given_up,
        "not_pickable": {**refused, **skipped},
        "order": [t["pair"] for t in order],
        "next": None if plan is None else plan["pair"],
        "done": plan is None,
        "why": None if plan else _why(refused, skipped, memory),
    }
    picture = None
    if pair and rectification is not None:
        raw = ctx is not None and (ctx.input_types or {}).get("pair") == "StereoPair"
        last = pair if "left" in pair else pair[sorted(pair)[-1]]
        picture = draw_cycle(last, rectification, ts, status, arm, hand_eye, plan, raw)
    if plan is None:
        if ctx is not None:
            ctx.stop_loop(status["why"])
            for k, r in status["not_pickable"].items():
                ctx.warn(f"{k}: {r}")
        plan = {"pair": "idle", "idle": True, "reason": status["why"], "waypoints": []}
    return {"plan": {plan["pair"]: plan}, "status": status, "picture": picture}


def _census(ts: list[dict], places: dict) -> tuple[dict[str, int], dict[str, int]]:
    """Per object: the balls on the table (found or not; none at its place), and the unclear ones
    (not located, or found in a region of more than one ball: it may hide another)."""
    n_now: dict[str, int] = {}
    unclear: dict[str, int] = {}
    for t in ts:
        o = t.get("object")
        if not (t.get("found") and at_place(t, places)):
            n_now[o] = n_now.get(o, 0) + 1
        if (not t.get("found") and not t.get("unreachable")) or t.get("merged"):
            unclear[o] = unclear.get(o, 0) + 1
    return n_now, unclear


def _judge_last(
    params: ClearParams, memory: Memory, found: list, ts: list, places: dict, n_now: dict, ctx
) -> dict | None:
    """The verdict on the last pick (:func:`._clear.look_again`); a place on the table, in view,
    must show the ball too."""
    tol = params.look_again_cm or max(
        [float(t.get("object_radius_cm") or 2.0) for t in ts] or [2.0]
    )
    last_object = memory.last["object"] if memory.last else None
    verdict = look_again(memory, found, n_now.get(last_object, 0), tol, params.max_retries)
    if (
        verdict
        and verdict["verdict"] == "gone"
        and places.get(verdict["object"], {}).get("on_table")
    ):
        verdict["seen_at_place"] = any(
            t.get("found") and t.get("object") == verdict["object"] and at_place(t, places)
            for t in ts
        )
        if not verdict["seen_at_place"] and ctx is not None:
            ctx.warn(
                f"the {verdict['object']} ball picked last is gone from where it was but "
                "not seen at its place"
            )
    return verdict


def _why(refused: dict, skipped: dict, memory: Memory) -> str:
    left = len(refused) + len(skipped) + len(memory.given_up)
    done = f"{memory.n_picked} picked and placed, {memory.n_retries} retried"
    return (
        f"the table is clear ({done})"
        if not left
        else f"{left} ball(s) left that cannot be picked ({done})"
    )
