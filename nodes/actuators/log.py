"""``actuator.log``: a dry run — check a PickPlan like ``actuator.dynamixel`` and record what it
would send.

No port is opened. The ServoLog lists, per waypoint, the GroupSyncWrite that would go out (goal
position + moving speed per servo) with the exact Protocol 1.0 packet bytes, and the expected
move time at the commanded speeds.
"""

from __future__ import annotations

from stereograph.api import Field, In, Out, node

from ._plan import (
    Selection,
    check_plan,
    move_seconds,
    select_plans,
    summary,
    sync_write_packet,
    waypoint_data,
)


class LogParams(Selection):
    start_units: int = Field(
        512,
        ge=0,
        le=1023,
        description="Assumed servo positions before the first waypoint (units), for timing.",
    )


def dry_run(params: LogParams, plan: dict, arm: dict) -> dict:
    """The ServoLog of a plan that is checked but not sent (see ``_plan.py``)."""
    check_plan(plan, arm)
    ids = sorted({int(k) for w in plan["waypoints"] for k in w["servo_units"]})
    commands, packets, reached = [], [], []
    present = {sid: params.start_units for sid in ids}
    t = 0.0
    for w in plan["waypoints"]:
        data = waypoint_data(w)
        for sid, (goal, speed) in data.items():
            commands.append(
                {
                    "t_s": round(t, 4),
                    "waypoint": w["name"],
                    "instruction": "SYNC_WRITE",
                    "id": sid,
                    "address": 30,
                    "register": "goal_position",
                    "value": goal,
                }
            )
            commands.append(
                {
                    "t_s": round(t, 4),
                    "waypoint": w["name"],
                    "instruction": "SYNC_WRITE",
                    "id": sid,
                    "address": 32,
                    "register": "moving_speed",
                    "value": speed,
                }
            )
        packets.append(sync_write_packet(data).hex(" "))
        dt = move_seconds(present, data)
        t += dt
        present = {sid: g for sid, (g, _) in data.items()}
        reached.append(
            {
                "waypoint": w["name"],
                "goal_units": {str(s): g for s, (g, _) in data.items()},
                "present_units": None,
                "max_error_units": None,
                "seconds": round(dt, 4),
            }
        )
    return {
        "pair": plan.get("pair"),
        "port": None,
        "baud": None,
        "dry_run": True,
        "ok": True,
        "servo_ids": ids,
        "commands": commands,
        "packets_hex": packets,
        "reached": reached,
        "events": [],
        "retries": 0,
        "seconds": round(t, 4),
        "sim": None,
    }


@node(
    "actuator.log",
    inputs={
        "arm": In("ArmModel"),
        "plans": In("PickPlan", gather=True, description="Every item's plan."),
    },
    outputs={
        "log": Out("ServoLog", save=True, description="The commands that would be sent."),
        "summary": Out(
            "PickSummary",
            save=True,
            headline=True,
            description="Object position, joint angles, servo goals.",
        ),
    },
    params=LogParams,
    version="1",
    cacheable=False,
)
def log(params: LogParams, arm, plans):
    """Dry run: check the chosen plans and record the servo commands they would send, without a
    port."""
    chosen, skipped = select_plans(plans, params)
    for p in chosen:  # all checked before any is 'sent'
        check_plan(p, arm)
    picks = [dry_run(params, p, arm) for p in chosen]
    return {
        "log": {"ok": True, "picks": picks, "not_picked": skipped},
        "summary": summary(picks, chosen, skipped),
    }
