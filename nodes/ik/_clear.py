"""Clearing the table, one pick a cycle: what is left, did the last pick work, which ball next.

Pure functions on plain data; ``ik.clear_table`` runs them and keeps :class:`Memory` across the
cycles of the loop. Positions are in the arm-base frame (cm) unless a name says ``table``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nodes.contracts.arm import JOINTS, fk

__all__ = ["Memory", "at_place", "look_again", "path_clearance", "sort_picks"]


@dataclass
class Memory:
    """What the planner remembers between cycles (one per run)."""

    last: dict[str, Any] | None = None  # the last pick: object, where (base cm), attempt
    given_up: list[dict[str, Any]] = field(default_factory=list)  # object, where, reason
    n_picked: int = 0
    n_retries: int = 0
    cycle: int = 0


def _dist(a, b) -> float:
    return float(np.linalg.norm(np.subtract(a, b)))


def at_place(t: dict, places_base: dict[str, dict]) -> bool:
    """A ball already where its object goes (a place on the table, in view)."""
    p = places_base.get(t.get("object"))
    return p is not None and _dist(t["target_base_cm"][:2], p["center_cm"][:2]) <= p["radius_cm"]


def look_again(
    memory: Memory, seen: list[dict], n_now: int, tolerance_cm: float, max_retries: int
) -> dict | None:
    """Judge the last pick from what is seen now: ``seen`` the found balls, ``n_now`` how many of
    its object are on the table now (found or not, none at its place).

    Gone: one fewer of its object than when it was chosen, and none where it was. Else it was missed
    (still there, or knocked elsewhere: then the nearest of its object to where it was is the one):
    retried first, up to ``max_retries``, then given up. Returns the verdict, or None with no last
    pick.
    """
    last = memory.last
    if last is None:
        return None
    mine = [t for t in seen if t.get("object") == last["object"]]
    still = [t for t in mine if _dist(t["target_base_cm"], last["where"]) <= tolerance_cm]
    # one fewer of its object; or a ball that was not located before (hidden, merged with another)
    # may be the one seen now: no evidence of a miss
    if not still and (n_now < last["n_before"] or last.get("unclear", 0) > 0):
        memory.n_picked += 1
        memory.last = None
        return {"verdict": "gone", "object": last["object"], "where": last["where"]}
    if last["attempt"] > max_retries or not mine:
        memory.given_up.append(
            {
                "object": last["object"],
                "where": last["where"],
                "reason": f"still there after {last['attempt']} picks"
                if mine
                else "missed, and not seen since",
            }
        )
        memory.last = None
        return {"verdict": "given up", "object": last["object"], "where": last["where"]}
    memory.n_retries += 1
    nearest = min(mine, key=lambda t: _dist(t["target_base_cm"], last["where"]))
    moved = _dist(nearest["target_base_cm"], last["where"])
    return {
        "verdict": "retry",
        "object": last["object"],
        "where": last["where"],
        "target": nearest["pair"],
        "moved_cm": round(moved, 2),
        "attempt": last["attempt"] + 1,
    }


def sort_picks(targets: list[dict], first: str | None = None) -> list[dict]:
    """Nearest the arm's base axis first (the shortest reach clears the way for the longer ones); a
    retry (``first``) before everything."""

    def key(t):
        x, y, _ = t["target_base_cm"]
        return (t["pair"] != first, math.hypot(x, y))

    return sorted(targets, key=key)


def path_clearance(
    model: dict,
    plan: dict,
    obstacles_base: list[tuple[np.ndarray, float]],
    finger_cm: float,
    steps: int = 12,
) -> tuple[float, str | None]:
    """Smallest gap (cm) between the tool's swept path and any obstacle ball, and where.

    Each move between waypoints is joint-linear (the servos arrive together); the tool, and while
    the gripper is closed the carried ball (radius ``plan``'s object radius), are sampled along it.
    """
    worst, where = math.inf, None
    carried = float(plan.get("object_radius_cm") or 0.0)
    wps = plan["waypoints"]
    for a, b in zip(wps, wps[1:]):
        qa = np.radians([a["joints_deg"][n] for n in JOINTS])
        qb = np.radians([b["joints_deg"][n] for n in JOINTS])
        pts = fk(model, qa[None, :] + np.linspace(0, 1, steps)[:, None] * (qb - qa)[None, :])
        extra = carried if a["gripper"] == "closed" and b["gripper"] == "closed" else finger_cm
        for c, r in obstacles_base:
            gap = float(np.min(np.linalg.norm(pts - c, axis=1))) - r - extra
            if gap < worst:
                worst, where = gap, f"{a['name']} -> {b['name']}"
    return worst, where
