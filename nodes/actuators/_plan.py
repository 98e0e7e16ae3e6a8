"""Shared by the actuators: choosing plans, checking them against the arm model, what a waypoint
sends.

Both actuators take every PickPlan of the run at once (``gather``), choose which to execute
(:class:`Selection`: split, explicit items, how many) and run them one after the other, as one
arm would. Their ``log`` output::

    {"ok": bool, "picks": [PickLog, ...], "not_picked": {item: reason}}

and a short ``summary`` (object position, joint angles, servo goals at the grasp) for the terminal.

PickLog (one executed plan)::

    {"pair": str, "port": str, "baud": int, "dry_run": bool, "ok": bool,
     "servo_ids": [int, ...],
     "commands": [{"t_s": float, "waypoint": str, "instruction": "SYNC_WRITE" | "WRITE" | ...,
                   "id": int, "address": int, "register": str, "value": int}, ...],
     "packets_hex": [str, ...]                    # dry run: the sync-write packets byte by byte
     "reached": [{"waypoint": str, "goal_units": {id: int}, "present_units": {id: int},
                  "max_error_units": int, "seconds": float}, ...],
     "events": [str, ...],                         # retries, warnings
     "retries": int, "seconds": float,
     "sim": {"writes": [...], "faults": [...]} | None}   # the emulator's own log (port: sim)
"""

from __future__ import annotations

from typing import Literal

from nodes.contracts.arm import servo_limits_units
from stereograph.api import Field, NodeError, Params

ADDR_GOAL = 30
ADDR_SPEED = 32
REGISTER_NAMES = {24: "torque_enable", 30: "goal_position", 32: "moving_speed"}


def check_plan(plan: dict, arm: dict) -> None:
    """Refuse the whole plan if any goal lies outside its joint's limits or any value is invalid.

    Runs before the port is opened, so that a bad plan never moves the arm.

    Raises
    ------
    NodeError
        Naming the waypoint, servo, goal and allowed range.
    """
    if not isinstance(plan, dict) or not plan.get("waypoints"):
        raise NodeError("the pick plan has no waypoints.", hint="wire plan: <pick_sequence>.plan.")
    limits = servo_limits_units(arm)
    for w in plan["waypoints"]:
        goals, speeds = w.get("servo_units") or {}, w.get("speed_units") or {}
        for sid, goal in goals.items():
            if sid not in limits:
                raise NodeError(
                    f"refusing the whole plan: waypoint {w.get('name')!r} commands servo "
                    f"{sid}, which is "
                    f"not in the arm model (servos {sorted(limits, key=int)}).",
                    hint="build the plan and the actuator from the same ik.arm node.",
                )
            lo, hi = limits[sid]
            if not isinstance(goal, int) or not lo <= goal <= hi:
                raise NodeError(
                    f"refusing the whole plan: waypoint {w.get('name')!r} would send "
                    f"servo {sid} to "
                    f"{goal} units, outside its joint limits {lo}..{hi} units; nothing was sent.",
                    hint="re-plan with ik.pick_sequence from the same arm model, or fix the "
                    "joint limits.",
                )
            sp = speeds.get(sid, 0)
            if not isinstance(sp, int) or not 0 <= sp <= 1023:
                raise NodeError(
                    f"refusing the whole plan: waypoint {w.get('name')!r} has moving "
                    f"speed {sp} for servo "
                    f"{sid}; AX-12A speeds are 0-1023.",
                    hint="re-plan with ik.pick_sequence.",
                )


def waypoint_data(w: dict) -> dict[int, tuple[int, int]]:
    """``{id: (goal_units, speed_units)}`` of a waypoint, ids in ascending order."""
    return {
        int(k): (int(v), int(w["speed_units"].get(k, 0)))
        for k, v in sorted(w["servo_units"].items(), key=lambda kv: int(kv[0]))
    }


def sync_write_packet(data: dict[int, tuple[int, int]]) -> bytes:
    """The Protocol 1.0 SYNC_WRITE packet (goal position + moving speed, 4 bytes per servo)."""
    from nodes.contracts.dynamixel_protocol import BROADCAST_ID, INST_SYNC_WRITE, instruction_packet

    params = bytearray([ADDR_GOAL, 4])
    for sid, (goal, speed) in data.items():
        params += bytes([sid, goal & 0xFF, goal >> 8, speed & 0xFF, speed >> 8])
    return instruction_packet(BROADCAST_ID, INST_SYNC_WRITE, bytes(params))


def move_seconds(prev: dict[int, int] | None, data: dict[int, tuple[int, int]]) -> float:
    """Expected duration (s) of a move at the commanded speeds (0.111 rpm per unit, 0 = 59 rpm)."""
    if prev is None:
        return 0.0
    t = 0.0
    for sid, (goal, speed) in data.items():
        if sid in prev:
            rpm = 59.0 if speed == 0 else min(59.0, 0.111 * speed)
            t = max(t, abs(goal - prev[sid]) / (rpm * 6.0 * 1023.0 / 300.0))
    return t


class Selection(Params):
    """Which plans an actuator executes."""

    split: Literal["all", "train", "test"] = Field(
        "all", description="Only plans of items in this split."
    )
    items: list[str] | None = Field(
        None, description="Only these item ids (in this order); default all, in order."
    )
    max_picks: int = Field(
        1, ge=1, le=10000, description="Execute at most this many plans (count)."
    )


def select_plans(plans, sel: Selection) -> tuple[list[dict], dict[str, str]]:
    """The plans to execute, and the reason for each plan that is not executed."""
    if isinstance(plans, dict) and "waypoints" in plans:
        plans = {str(plans.get("pair")): plans}
    plans = dict(plans or {})
    order = [i for i in (sel.items or list(plans)) if i in plans]
    chosen, skipped = [], {}
    for item in plans:
        if sel.items is not None and item not in sel.items:
            skipped[item] = "not in items"
    for item in order:
        p = plans[item]
        if p.get("idle"):  # nothing to do (a cleared table): not a refusal
            skipped[item] = f"idle: {p.get('reason')}"
        elif p.get("refused"):
            skipped[item] = f"refused: {p.get('reason')}"
        elif sel.split != "all" and p.get("split") not in (None, sel.split):
            skipped[item] = f"split {p.get('split')}"
        elif len(chosen) >= sel.max_picks:
            skipped[item] = f"max_picks {sel.max_picks} reached"
        else:
            chosen.append(p)
    if not chosen and skipped and all(plans[i].get("idle") for i in skipped):
        return [], skipped
    if not chosen:
        reasons = sorted({r.split(":")[0] for r in skipped.values()})
        first_item = next((i for i, r in skipped.items() if r.startswith("refused")), None)
        first = skipped.get(first_item) if first_item else None
        if first:  # the plan's own reason already ends with its fix
            first = first.split("; fix: ")[0]
        # a refused plan knows its fix (arm geometry, hand-eye, ...); otherwise it is the selection
        hint = (plans[first_item].get("hint") if first_item else None) or (
            "check the located objects (found, extrapolated, reachable) or the "
            "actuator's split / items selection"
        )
        raise NodeError(
            f"no pick plan to execute: {len(plans)} plan(s), none selected "
            f"({', '.join(reasons) or 'empty'})" + (f"; e.g. {first}" if first else ""),
            hint=hint,
        )
    return chosen, skipped


def _r(v, nd=2):
    return None if v is None else [round(float(x), nd) for x in v]


def summary(picks: list[dict], plans: list[dict], skipped: dict[str, str]) -> dict:
    """A short, printable account of each executed pick, and why the other plans were not executed.

    ``not_picked`` counts them; ``not_picked_why`` counts them by reason (``max_picks 1 reached``,
    ``split train``, ``refused``, ...), so that 119 plans not picked of 120 reads as the selection
    it is.
    """
    out = []
    for log_, plan in zip(picks, plans):
        g = plan["waypoints"][plan["grasp_index"]]
        # (the outcome first: what a person reads first, on the run's page too)
        out.append(
            {
                "item": plan.get("pair"),
                "ok": log_["ok"],
                "object_base_cm": _r(plan.get("target_base_cm")),
                "object_left_cm": _r(plan.get("location_cm")),
                "seconds": log_["seconds"],
                "servo_commands": len(log_["commands"]),
                "grasp_joints_deg": {k: round(v, 2) for k, v in g["joints_deg"].items()},
                "grasp_servo_goals": g["servo_units"],
            }
        )
    why: dict[str, int] = {}
    for reason in skipped.values():
        # a refusal's own text is in the log; here only that it was refused
        key = reason.split(":")[0]
        why[key] = why.get(key, 0) + 1
    return {"picks": out, "not_picked": len(skipped), "not_picked_why": why}
