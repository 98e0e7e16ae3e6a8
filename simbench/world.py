"""A simulated table that reacts to the arm: balls, places (bins, spots) and the gripper.

The state is one JSON file (:func:`read_world`, :func:`write_world`, under a file lock), so the
servo emulator that moves the arm and the camera that renders the table share it across threads
and processes as a real bench shares the physical world. :class:`ArmFollower` is the emulator's
``on_motion`` hook: it turns servo positions into the tool point (the arm model's forward
kinematics, then the arm base's pose on the table) and :func:`step` applies the physics: a gripper
closing within ``grasp_tolerance_cm`` of a ball's centre holds it, the ball moves with the tool and
drops where it is released (into a place when over one); a gripper closed elsewhere holds nothing;
a ball the fingers (or the carried ball) sweep through is pushed aside. Every such event is
appended to ``events``. Frames and units: table frame, cm (docs/conventions.md).
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from filelock import FileLock

from nodes.contracts.arm import JOINTS, fk, joint, servo_units_to_joints

__all__ = ["ArmFollower", "new_world", "read_world", "step", "write_world"]

FINGER_RADIUS_CM = 0.8  # the closed fingers' reach beyond the tool point, seen from a ball
# an overlap this small is a touch, not a push (the grasp centres a ball by up to
CONTACT_TOLERANCE_CM = 0.2
# the grasp tolerance, nudging a neighbour it touches)


def new_world(
    balls: list[dict],
    places: list[dict],
    grasp_tolerance_cm: float = 1.0,
    finger_radius_cm: float = FINGER_RADIUS_CM,
    missed_grasps: int = 0,
    miss_offset_cm: float = 2.0,
) -> dict:
    """A world: ``balls`` [{id, object, color_bgr, radius_cm, center_cm}] resting on the table,
    ``places`` [{name, object, center_cm: [x, y], radius_cm, height_cm}] (height 0: a spot on the
    table; above 0: a bin whose rim is that high; a ball released over it ends inside).
    ``missed_grasps``: the first that many closings happen ``miss_offset_cm`` off the tool point
    (sideways: a gripper that slipped, a servo that stopped short) -- the fault a pick must
    catch."""
    for b in balls:
        b.setdefault("state", "table")
        b.setdefault("place", None)
        b["center_cm"] = [float(v) for v in b["center_cm"]]
    return {
        "version": 1,
        "balls": balls,
        "places": places,
        "grasp_tolerance_cm": float(grasp_tolerance_cm),
        "finger_radius_cm": float(finger_radius_cm),
        "faults": {"missed_grasps": int(missed_grasps), "miss_offset_cm": float(miss_offset_cm)},
        "gripper": {"tool_cm": None, "closed": False, "holding": None},
        "events": [],
    }


def read_world(path: str | Path) -> dict:
    """The world's state now."""
    with FileLock(str(path) + ".lock"):
        return json.loads(Path(path).read_text())


def write_world(path: str | Path, world: dict) -> None:
    """Replace the state (atomically: a reader sees the old or the new one, never half of one)."""
    with FileLock(str(path) + ".lock"):
        _write(Path(path), world)


def _write(path: Path, world: dict) -> None:
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(world))
    os.replace(tmp, path)


def _event(world: dict, what: str, ball: dict | None, **kw: Any) -> None:
    world["events"].append(
        {"t": time.time(), "what": what, "ball": ball["id"] if ball else None, **kw}
    )


def _segment_distance(p0: np.ndarray, p1: np.ndarray, c: np.ndarray) -> tuple[float, np.ndarray]:
    """Distance from ``c`` to the segment p0-p1, and the segment's nearest point."""
    d = p1 - p0
    t = 0.0 if not d.any() else float(np.clip(np.dot(c - p0, d) / np.dot(d, d), 0.0, 1.0))
    q = p0 + t * d
    return float(np.linalg.norm(c - q)), q


def _push(
    world: dict, ball: dict, q: np.ndarray, clearance_cm: float, by: str, path: np.ndarray
) -> None:
    """Move ``ball`` on the table, straight away from ``q`` (horizontally), to ``clearance_cm``; a
    ball hit head-on goes to the side of the ``path`` (direction), out of its way."""
    c = np.asarray(ball["center_cm"], float)
    away = c[:2] - q[:2]
    n = float(np.linalg.norm(away))
    if n < 1e-6:
        side = (
            np.array([-path[1], path[0]])
            if np.linalg.norm(path[:2]) > 1e-9
            else np.array([1.0, 0.0])
        )
        away, n = side, float(np.linalg.norm(side))
    away = away / n
    new = q[:2] + away * clearance_cm
    moved = float(np.linalg.norm(new - c[:2]))
    ball["center_cm"] = [float(new[0]), float(new[1]), float(ball["radius_cm"])]
    _event(world, "push", ball, by=by, moved_cm=round(moved, 3))


def _sweep(world: dict, p0: np.ndarray, p1: np.ndarray) -> None:
    """Push every ball on the table that the fingers, or the carried ball, pass through."""
    g = world["gripper"]
    held = next((b for b in world["balls"] if b["id"] == g["holding"]), None)
    tol, finger = world["grasp_tolerance_cm"], world["finger_radius_cm"]
    for b in world["balls"]:
        if b["state"] != "table":
            continue
        c = np.asarray(b["center_cm"], float)
        r = float(b["radius_cm"])
        dist, q = _segment_distance(p0, p1, c)
        if held is not None and dist < r + float(held["radius_cm"]) - CONTACT_TOLERANCE_CM:
            _push(
                world,
                b,
                q,
                r + float(held["radius_cm"]) + 0.05,
                f"carried ball {held['id']}",
                p1 - p0,
            )
            continue
        if dist >= r + finger - CONTACT_TOLERANCE_CM:
            continue
        # open fingers straddle a ball they come down on (within the grasp tolerance of its centre)
        horizontal = float(np.linalg.norm(c[:2] - p1[:2]))
        if not g["closed"] and horizontal <= tol:
            continue
        _push(world, b, q, r + finger + 0.05, "fingers", p1 - p0)


def _close(world: dict, tool: np.ndarray) -> None:
    faults = world.get("faults") or {}
    if faults.get("missed_grasps", 0) > 0:
        faults["missed_grasps"] -= 1
        tool = tool + np.array([float(faults["miss_offset_cm"]), 0.0, 0.0])
    free = [b for b in world["balls"] if b["state"] == "table"]
    near = min(free, key=lambda b: np.linalg.norm(np.asarray(b["center_cm"]) - tool), default=None)
    dist = float(np.linalg.norm(np.asarray(near["center_cm"]) - tool)) if near else math.inf
    if near is not None and dist <= world["grasp_tolerance_cm"]:
        near["state"] = "held"
        world["gripper"]["holding"] = near["id"]
        _event(world, "grasp", near, off_cm=round(dist, 3))
    else:
        _event(
            world, "closed on nothing", near, nearest_cm=None if near is None else round(dist, 3)
        )


def _release(world: dict, tool: np.ndarray) -> None:
    b = next(b for b in world["balls"] if b["id"] == world["gripper"]["holding"])
    world["gripper"]["holding"] = None
    r = float(b["radius_cm"])
    for p in world["places"]:
        if math.dist(tool[:2], p["center_cm"][:2]) <= float(p["radius_cm"]):
            b.update(
                state="placed",
                place=p["name"],
                center_cm=[float(tool[0]), float(tool[1]), float(p.get("height_cm", 0.0)) + r],
            )
            _event(
                world, "placed", b, place=p["name"], right=p.get("object") in (None, b["object"])
            )
            return
    b.update(state="table", place=None, center_cm=[float(tool[0]), float(tool[1]), r])
    _event(world, "dropped", b, at_cm=[round(float(v), 2) for v in tool[:2]])


def step(world: dict, tool_cm, closed: bool) -> None:
    """Move the gripper to ``tool_cm`` (table frame) with its fingers ``closed``, and apply the
    physics."""
    g = world["gripper"]
    tool = np.asarray(tool_cm, float)
    prev = np.asarray(g["tool_cm"], float) if g["tool_cm"] is not None else tool
    _sweep(world, prev, tool)
    g["tool_cm"] = [float(v) for v in tool]
    if closed and not g["closed"]:
        g["closed"] = True
        _close(world, tool)
    elif not closed and g["closed"]:
        g["closed"] = False
        if g["holding"] is not None:
            _release(world, tool)
    if g["holding"] is not None:
        b = next(b for b in world["balls"] if b["id"] == g["holding"])
        b["center_cm"] = [float(v) for v in tool]


class ArmFollower:
    """The servo emulator's ``on_motion`` hook: the world follows the emulated arm.

    Parameters
    ----------
    path : path of the world file
    arm : the ArmModel (``ik.arm``)
    T_table_from_base : 4x4, cm: where the arm base stands on the table (the bench's truth)
    """

    def __init__(self, path, arm: dict, T_table_from_base, min_move_cm: float = 0.05):
        self.path, self.arm = Path(path), arm
        self.T = np.asarray(T_table_from_base, float)
        self.min_move_cm = min_move_cm
        self._last: tuple[np.ndarray, bool] | None = None
        g = joint(arm, "gripper")
        self._grip = (float(g["open_deg"]), float(g["closed_deg"]))

    def __call__(self, positions: dict[int, float]) -> None:
        joints = servo_units_to_joints(self.arm, {str(i): u for i, u in positions.items()})
        tool = (self.T @ np.append(fk(self.arm, np.radians([joints[n] for n in JOINTS])), 1.0))[:3]
        open_deg, closed_deg = self._grip
        closed = abs(joints["gripper"] - closed_deg) < abs(joints["gripper"] - open_deg)
        if (
            self._last is not None
            and self._last[1] == closed
            and np.linalg.norm(tool - self._last[0]) < self.min_move_cm
        ):
            return
        self._last = (tool, closed)
        with FileLock(str(self.path) + ".lock"):
            world = json.loads(self.path.read_text())
            step(world, tool, closed)
            _write(self.path, world)
