"""Shared by the actuators: checking a PickPlan against the arm model, and what a waypoint sends.

ServoLog (what both actuators output, saved to the run folder)::

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

from stereograph.api import NodeError

from nodes.ik._model import servo_limits_units

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
                raise NodeError(f"refusing the whole plan: waypoint {w.get('name')!r} commands servo {sid}, which is "
                                f"not in the arm model (servos {sorted(limits, key=int)}).",
                                hint="build the plan and the actuator from the same ik.arm node.")
            lo, hi = limits[sid]
            if not isinstance(goal, int) or not lo <= goal <= hi:
                raise NodeError(f"refusing the whole plan: waypoint {w.get('name')!r} would send servo {sid} to "
                                f"{goal} units, outside its joint limits {lo}..{hi} units; nothing was sent.",
                                hint="re-plan with ik.pick_sequence from the same arm model, or fix the joint limits.")
            sp = speeds.get(sid, 0)
            if not isinstance(sp, int) or not 0 <= sp <= 1023:
                raise NodeError(f"refusing the whole plan: waypoint {w.get('name')!r} has moving speed {sp} for servo "
                                f"{sid}; AX-12A speeds are 0-1023.", hint="re-plan with ik.pick_sequence.")


def waypoint_data(w: dict) -> dict[int, tuple[int, int]]:
    """``{id: (goal_units, speed_units)}`` of a waypoint, ids in ascending order."""
    return {int(k): (int(v), int(w["speed_units"].get(k, 0))) for k, v in sorted(w["servo_units"].items(),
                                                                             key=lambda kv: int(kv[0]))}


def sync_write_packet(data: dict[int, tuple[int, int]]) -> bytes:
    """The Protocol 1.0 SYNC_WRITE packet (goal position + moving speed, 4 bytes per servo)."""
    from .servo_sim import BROADCAST_ID, INST_SYNC_WRITE, instruction_packet
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
