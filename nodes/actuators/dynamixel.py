"""``actuator.dynamixel``: run a PickPlan on AX-12A servos with the real dynamixel-sdk (Protocol
1.0).

The same code path for hardware and emulation: with ``port: sim`` the node starts the project's
emulator (:mod:`simbench.servo_sim`) on a pseudo-terminal and talks to it through the real
``PortHandler`` / ``PacketHandler(1.0)`` / ``GroupSyncWrite``.

Safety order: (1) every goal of the plan is checked against the joint limits before the port is
even opened — one bad goal refuses the whole plan; (2) every servo must answer a PING and a READ
(:mod:`._bus` checks every reply and classifies each try; :mod:`._diagnose` names the cause: no
reply, late reply, corrupted replies, alarm bits, status return level 0 — and whether torque is
still on); (3) each servo's own CW/CCW angle limits must contain its goals; only then is anything
written. Each waypoint is one GroupSyncWrite (goal position + moving speed for all servos at
once), read back, then present positions are polled one servo at a time until all are within
``tolerance_units`` (the gripper may also stop short, closed on the object) or the move times out.
A failure while moving turns torque off on every servo and names the cause. Ctrl-C or SIGTERM while
moving ends the motion as ``on_interrupt`` says (:mod:`._stop`), closes the port and re-raises.
See docs/arm.md, "Servo faults" and "Ctrl-C and SIGTERM".

In a ``--repeat`` loop the port (and the emulator) stay open from one plan to the next
(``ctx.resource``; the engine closes them when the run ends): steps (2)-(3) read the servos once per
open port, and later plans check their goals against the limits read then and write the first goal
after one present-position READ per servo. Any failure or interrupt closes the port, so the next
plan checks every servo again (docs/live.md, "Latency").
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
from pathlib import Path
from typing import Literal, NoReturn

from nodes.contracts.arm import (
    JOINTS,
    joint,
    joints_to_servo_units,
    servo_limits_units,
    speed_to_units,
)
from simbench.servo_sim import Faults, ServoSim
from simbench.world import ArmFollower
from stereograph.api import Field, In, NodeError, Out, Params, node

from . import _diagnose
from ._bus import Bus, PortLost, ServoFailure
from ._plan import (
    ADDR_GOAL,
    Selection,
    check_plan,
    move_seconds,
    select_plans,
    summary,
    waypoint_data,
)
from ._stop import Terminated, hold, rest, stop_signals_as_interrupt

ADDR_CW_LIMIT, ADDR_TORQUE, ADDR_POSITION, ADDR_MOVING = 6, 24, 36, 46
ADDR_MAX_TORQUE, ADDR_TORQUE_LIMIT = 14, 34
ALARM_NAMES = {"voltage": 1, "angle_limit": 2, "overheating": 4, "range": 8, "overload": 32}


class SimFaults(Params):
    """Fault injection for ``port: sim`` (demos and tests); see ``servo_sim.Faults``."""

    drop_reply_prob: float = Field(
        0.0, ge=0, le=1, description="Probability of a dropped status packet."
    )
    drop_replies: int = Field(0, ge=0, description="Drop this many status packets first (count).")
    corrupt_prob: float = Field(
        0.0, ge=0, le=1, description="Probability of a status packet with a bad checksum."
    )
    corrupt_replies: int = Field(
        0, ge=0, description="Corrupt this many status packets first (count)."
    )
    short_replies: int = Field(
        0, ge=0, description="Send this many READ replies without their data (count)."
    )
    late_prob: float = Field(
        0.0, ge=0, le=1, description="Probability of a status packet held back by late_ms."
    )
    late_replies: int = Field(
        0, ge=0, description="Hold back this many status packets first (count)."
    )
    late_ms: float = Field(80.0, ge=0, le=2000, description="Delay of a late status packet (ms).")
    unplugged_ids: list[int] = Field(
        default_factory=list, description="Servo IDs that do not answer."
    )
    only_ids: list[int] | None = Field(
        None, description="Restrict dropped/corrupted/late replies to these IDs."
    )
    instructions: list[Literal["PING", "READ", "WRITE"]] | None = Field(
        None,
        description="Restrict dropped/corrupted/late replies and alarms to replies to these "
        "instructions.",
    )
    after_replies: int = Field(
        0, ge=0, description="Inject faults only after this many status packets (count)."
    )
    after_goal_writes: int = Field(
        0,
        ge=0,
        description="Inject faults only once this many goal positions were "
        "accepted, i.e. once the arm moves (count).",
    )
    alarms: dict[
        int, list[Literal["voltage", "angle_limit", "overheating", "range", "overload"]]
    ] = Field(
        default_factory=dict,
        description="Alarm bits a servo sets in its status packets, e.g. {3: [overload]}.",
    )
    jammed_at_units: dict[int, float] = Field(
        default_factory=dict,
        description="An obstruction per servo at "
        "this position (units): the joint stalls there and overloads.",
    )
    seed: int = Field(0, ge=0, description="Random seed of the faults.")

    def to_faults(self) -> Faults:
        d = self.model_dump()
        d["unplugged_ids"] = set(d["unplugged_ids"])
        d["only_ids"] = None if d["only_ids"] is None else set(d["only_ids"])
        d["instructions"] = None if d["instructions"] is None else set(d["instructions"])
        d["alarms"] = {int(k): sum(ALARM_NAMES[w] for w in v) for k, v in d["alarms"].items()}
        return Faults(**d)


class DynamixelParams(Selection):
    port: str = Field(
        "/dev/ttyUSB0",
        min_length=1,
        description="Serial port of the USB2Dynamixel / U2D2 "
        "(/dev/ttyUSB0, COM3), or 'sim' to start the AX-12A "
        "emulator on a pseudo-terminal.",
    )
    baud: int = Field(1_000_000, description="Baud rate (bit/s); AX-12A default 1000000.")
    retries: int = Field(
        3, ge=0, le=20, description="Re-sends after a missing, late or corrupted reply (count)."
    )
    late_window_ms: float = Field(
        250.0,
        ge=0,
        le=2000,
        description="After dynamixel-sdk's reply timeout "
        "(~34 ms), keep listening this long (ms) to tell a late reply from none.",
    )
    reply_timeout_extra_ms: float = Field(
        0.0,
        ge=0,
        le=1000,
        description="Added to dynamixel-sdk's reply "
        "timeout (ms), for an adapter whose latency timer cannot be lowered.",
    )
    tolerance_units: int = Field(
        3, ge=0, le=50, description="Arrival tolerance (servo units, 1 unit = 0.293 deg)."
    )
    move_timeout_s: float | None = Field(
        None,
        gt=0,
        le=600,
        description="Per-waypoint timeout (s); default 1.5 x the expected move time + 1 s.",
    )
    poll_interval_s: float = Field(
        0.02, ge=0, le=1, description="Pause between position polls (s)."
    )
    torque_off_at_end: bool = Field(
        False, description="Turn torque off after the last waypoint (drops a held object)."
    )
    torque_off_on_failure: bool = Field(
        False,
        description="When a run fails before moving, turn torque off on "
        "every servo (it may be on from an earlier run; the arm may then sag).",
    )
    on_interrupt: Literal["hold", "rest", "torque_off"] = Field(
        "hold",
        description="Ctrl-C / SIGTERM during a motion: hold = stop where it is with torque on; "
        "rest = "
        "arm joints to the arm model's home pose (gripper holds); torque_off = go limp.",
    )
    rest_speed_deg_s: float = Field(
        30.0, gt=0, le=300, description="Joint speed of the move to the rest pose (deg/s)."
    )
    sim_time_scale: float = Field(
        1.0, gt=0, le=1000, description="port sim: motion speed-up factor (1 = real time)."
    )
    sim_faults: SimFaults = Field(
        default_factory=SimFaults, description="port sim: fault injection."
    )


def _gripper_ids(arm: dict) -> set[int]:
    try:
        return {s["id"] for s in joint(arm, "gripper")["servos"]}
    except KeyError:
        return set()


def _check_servos(bus: Bus, ids: list[int], plan: dict, params: DynamixelParams) -> dict[int, int]:
    """Ping, identify and check every servo before anything is written; return present positions.

    On a bus kept open across the cycles of a run, the PINGs and the reads of model, status return
    level and angle limits are done once (and again after a fault, which closes the port): later
    plans are checked against the limits read then, and each servo answers one READ of its present
    position before anything is written — the proof that it is still there.

    Raises
    ------
    NodeError
        Naming the servo and the cause (no / late / corrupted reply, alarm bits, status return
        level 0, angle limits).
    """
    if not set(ids) <= set(bus.limits):
        _setup_servos(bus, ids, params)
    _check_own_limits(bus.limits, plan)
    return {sid: bus.read(sid, ADDR_POSITION, 2, "read of the present position") for sid in ids}


def _ping(bus: Bus, sid: int, ids: list[int], baud: int) -> None:
    """PING ``sid``. An alarm in a status packet that is the PING itself byte for byte (a PING's
    echo reads as an input-voltage alarm) is checked: if another servo's reply comes after an echo
    of its own PING, the adapter echoes, and ``sid`` is pinged again with the echoes skipped; if
    every PING comes back as itself and nothing else, no servo answers behind an echoing adapter."""
    try:
        bus.ping(sid)
        return
    except ServoFailure as e:
        if e.exchange is None or not e.exchange.echo_like or bus.echoes:
            raise
        others = [bus.probe_ping(other) for other in ids if other != sid]
        if not bus.echoes:
            if all(t.echo_like for t in others):
                raise NodeError(
                    *_diagnose.silent_bus(bus.port_path, ids, baud, echoed=True)
                ) from None
            raise
    bus.ping(sid)


def _setup_servos(bus: Bus, ids: list[int], params: DynamixelParams) -> None:
    """PING and READ every servo, read its status return level and CW/CCW limits into
    ``bus.limits``."""
    for k, sid in enumerate(ids):
        try:
            _ping(bus, sid, ids, params.baud)
        except PortLost:
            raise
        except ServoFailure as e:
            if (
                k == 0
                and e.exchange is not None
                and e.exchange.kind == "no_reply"
                and not any(bus.answers_ping(other) for other in ids[1:])
            ):
                raise NodeError(*_diagnose.silent_bus(bus.port_path, ids, params.baud)) from None
            raise NodeError(*_diagnose.missing_servo(bus, sid, ids, e, params.baud)) from None
        if sid in bus.twins:
            raise NodeError(*_diagnose.twin_id(bus.port_path, sid, ids))
        try:
            model = bus.read(sid, 0, 2, "read of the model number")
        except PortLost:
            raise
        except ServoFailure as e:
            raise NodeError(*_diagnose.after_ping(bus, sid, e, params.baud)) from None
        if model not in SAME_UNITS_AS_AX12:
            raise NodeError(
                _foreign_model(sid, model),
                hint=f"check that ID {sid} is the arm's servo and not another device on the "
                "bus; the "
                f"arm needs AX-12A servos or models with the same position units "
                f"({', '.join(sorted(set(SAME_UNITS_AS_AX12.values())))}).",
            )
        if model != 12:
            bus.events.append(
                f"servo {sid} reports model number {model} ({SAME_UNITS_AS_AX12[model]}), not an "
                f"AX-12A (12): same position units"
            )
    limits = {}
    for sid in ids:
        bus.status_level[sid] = bus.read(sid, 16, 1, "read of the status return level")
        both = bus.read(sid, ADDR_CW_LIMIT, 4, "read of the angle limits")
        limits[sid] = (both & 0xFFFF, both >> 16)
        if bus.read(sid, ADDR_TORQUE_LIMIT, 2, "read of the torque limit") == 0:
            raise NodeError(*_no_torque(bus, sid))
    bus.limits.update(limits)  # only once every servo passed


def _no_torque(bus: Bus, sid: int) -> tuple[str, str]:
    """Servo ``sid``'s torque limit is 0: it cannot move. The other joints would go to the first
    waypoint and the move then time out, torque off on the whole arm (which sags); refuse before
    anything is written."""
    max_torque = bus.read(sid, ADDR_MAX_TORQUE, 2, "read of the max torque")
    head = (
        f"refusing the whole plan: servo {sid}'s torque limit (address 34) is 0, so it "
        "has no force to move "
        "its joint: the other joints would move, then this one would never arrive; "
        "nothing was sent."
    )
    if max_torque == 0:
        hint = (
            f"servo {sid}'s max torque (address 14) is 0, and the torque limit is loaded "
            "from it at power-on: "
            "write 1023 (or the force the joint needs) to address 14 with Dynamixel "
            "Wizard / RoboPlus, then to "
            f"address 34 or power the servos off and on."
        )
    else:
        hint = (
            "the AX-12A sets its torque limit to 0 on an alarm shutdown (overload or "
            "overheating, address 18): "
            "find and clear the cause (an obstruction, a heavy load, heat), then power "
            "the servos off and on "
            f"(address 34 is reloaded from max torque, address 14, = {max_torque}) or "
            f"write {max_torque} to "
            f"address 34."
        )
    return head, hint


# Protocol 1.0 models whose goal/present positions are 0-1023 over 300 deg, as the arm model's
# units.
SAME_UNITS_AS_AX12 = {
    12: "AX-12A",
    18: "AX-18A",
    44: "AX-12W",
    300: "AX-12W",
    10: "RX-10",
    24: "RX-24F",
    28: "RX-28",
    64: "RX-64",
    113: "DX-113",
    116: "DX-116",
    117: "DX-117",
}
# Models whose positions mean something else: an AX-12A goal would send them elsewhere.
OTHER_UNITS = {
    29: "MX-28 (0-4095 over 360 deg)",
    310: "MX-64 (0-4095 over 360 deg)",
    320: "MX-106 (0-4095 over 360 deg)",
    360: "MX-12W (0-4095 over 360 deg)",
    107: "EX-106+ (0-4095 over 251 deg)",
}


def _foreign_model(sid: int, model: int) -> str:
    what = (
        f"an {OTHER_UNITS[model]}"
        if model in OTHER_UNITS
        else "not a model this actuator knows to count 0-1023 over 300 deg like the AX-12A"
    )
    return (
        f"refusing the whole plan: servo {sid} reports model number {model}, {what}; the "
        "arm model's goals are "
        f"AX-12A units, which would turn it to other angles than planned; nothing was sent."
    )


def _check_own_limits(limits: dict[int, tuple[int, int]], plan: dict) -> None:
    """Every goal of the plan within its servo's own CW/CCW angle limits; none in wheel mode
    (0/0)."""
    for sid, (cw, ccw) in limits.items():
        if cw == ccw == 0:
            # Wheel (endless turn) mode: the servo ignores goal positions and turns for as long as
            # its moving speed is non-zero: the speed of the first waypoint would spin the joint.
            raise NodeError(
                f"refusing the whole plan: servo {sid} is in wheel (endless turn) mode, "
                "its CW and CCW "
                "angle limits (addresses 6/8) are both 0, so it would ignore its goal "
                "positions and "
                f"keep turning at the moving speed; nothing was sent.",
                hint=f"put servo {sid} back in joint mode: CW angle limit 0 and CCW angle "
                "limit 1023 "
                f"(or the joint's own range) with Dynamixel Wizard / RoboPlus, or a WRITE to "
                f"addresses 6 and 8.",
            )
        for w in plan["waypoints"]:
            g = w["servo_units"].get(str(sid))
            if g is not None and not cw <= g <= ccw:
                raise NodeError(
                    f"refusing the whole plan: servo {sid}'s own angle limits are "
                    f"{cw}..{ccw} units but "
                    f"waypoint {w['name']!r} needs {g}; nothing was sent.",
                    hint="fix the servo's CW/CCW angle limits (addresses 6/8) or the arm model's "
                    "joint limits / zero offsets.",
                )


def _run_waypoint(
    bus: Bus, w: dict, present: dict[int, int], params: DynamixelParams, grippers: set[int]
):
    """One waypoint: sync write, read back, poll until there (or the gripper closed on the
    object)."""
    data = waypoint_data(w)
    expected = move_seconds(present, data)
    timeout = params.move_timeout_s or (1.5 * expected + 1.0)
    t_start = time.monotonic()
    _send_goals(bus, w, data, params)
    last: dict[int, int] = {}
    still_since: float | None = None  # since when every pending joint has kept its position
    while True:
        pos = {sid: bus.read(sid, ADDR_POSITION, 2, "read of the present position") for sid in data}
        err = {sid: abs(pos[sid] - data[sid][0]) for sid in data}
        pending = [sid for sid in data if err[sid] > params.tolerance_units]
        if pending and set(pending) <= grippers:
            if _not_moving(bus, pending):
                # Stopped: at the goal by now, or short of it, closed on the object.
                for sid in pending:
                    pos[sid] = bus.read(sid, ADDR_POSITION, 2, "read of the present position")
                    err[sid] = abs(pos[sid] - data[sid][0])
                short = [sid for sid in pending if err[sid] > params.tolerance_units]
                if short:
                    bus.events.append(
                        f"{w['name']}: gripper stopped {max(err[s] for s in short)} units "
                        f"short of its goal (holding the object)"
                    )
                pending = []
        if not pending:
            break
        now = time.monotonic()
        # Past the move's planned time, joints that keep their position and say they are not moving
        # have stopped short for good (compliance under load): say so now, not after the whole
        # timeout.
        if now - t_start > expected and all(last.get(sid) == pos[sid] for sid in pending):
            still_since = still_since if still_since is not None else now
        else:
            still_since = None
        stopped = (
            still_since is not None and now - still_since >= SETTLED_S and _not_moving(bus, pending)
        )
        if stopped or now - t_start > timeout:
            _raise_stalled(bus, pending, err, data, pos, now - t_start, expected, stopped, params)
        last = dict(pos)
        time.sleep(params.poll_interval_s)
    return pos, {
        "waypoint": w["name"],
        "goal_units": {str(s): data[s][0] for s in data},
        "present_units": {str(s): int(pos[s]) for s in data},
        "max_error_units": int(max(err.values())),
        "seconds": round(time.monotonic() - t_start, 4),
    }


def _send_goals(bus: Bus, w: dict, data: dict, params: DynamixelParams) -> None:
    """Every joint's goal at once (sync write), read back, since a broadcast has no reply to
    confirm it; written again on a mismatch, ``params.retries`` times at most."""
    for attempt in range(params.retries + 1):
        bus.sync_write(data)
        got = {sid: bus.read(sid, ADDR_GOAL, 2, "read-back of the goal position") for sid in data}
        missing = [sid for sid in data if got[sid] != data[sid][0]]
        if not missing:
            break
        if attempt == params.retries:
            raise ServoFailure(
                f"servos {missing} did not take their goal positions after "
                f"{params.retries + 1} sync writes"
            )
        bus.n_retries += 1
        bus.events.append(
            f"{w['name']}: goal read-back mismatch on servos {missing}; sync write again"
        )


def _raise_stalled(
    bus: Bus,
    pending: list[int],
    err: dict,
    data: dict,
    pos: dict,
    elapsed: float,
    expected: float,
    stopped: bool,
    params: DynamixelParams,
) -> NoReturn:
    """Joints short of their goals when the move's time is up, or stopped short for good: a
    :class:`_Stalled` that says where, and whether it is the small settling gap."""
    head = (
        f"servos {pending} still {[err[s] for s in pending]} units from their goals "
        f"{[data[s][0] for s in pending]} after {elapsed:.1f} s (at "
        f"{[pos[s] for s in pending]})"
    )
    worst = max(err[s] for s in pending)
    if stopped or (worst <= SHORT_UNITS and _not_moving(bus, pending)):
        head += ", stopped there (moving flag 0" + (
            f", not moving for {SETTLED_S:g} s past the move's {expected:.1f} s)"
            if stopped
            else ")"
        )
        raise _Stalled(
            head,
            hint=SHORT_HINT.format(n=worst, tol=params.tolerance_units)
            if worst <= SHORT_UNITS
            else None,
        )
    raise _Stalled(head)


def _not_moving(bus: Bus, ids: list[int]) -> bool:
    """Every servo of ``ids`` reports its moving flag 0 (address 46): it has stopped."""
    return all(bus.read(sid, ADDR_MOVING, 1, "read of the moving flag") == 0 for sid in ids)


class _Stalled(ServoFailure):
    """A joint did not reach its goal in time (no alarm bit): load or obstruction, or it settled a
    few units short (``hint``)."""

    def __init__(self, message: str, hint: str | None = None):
        super().__init__(message)
        self.hint = hint


# a stop this close to the goal (3.5 deg) is the servo's compliance under load, not a blockage
SHORT_UNITS = 12
# s: past its planned time, a move whose joints keep still this long (moving flag 0) has ended
SETTLED_S = 0.3
SHORT_HINT = (
    "a joint that stops {n} units short of its goal and reports it is not moving has "
    "settled within its "
    "compliance margin and slope (addresses 26-29) under the load it carries, which the "
    "arrival tolerance "
    "({tol} units) does not allow: if {n} units (0.29 deg each) are acceptable for the pick, --set "
    "act.tolerance_units={n}; otherwise lower the servo's compliance margin / slope or "
    "raise its punch "
    "(address 48), or lighten the load."
)


STALL_HINT = (
    "a joint that does not reach its goal is blocked or overloaded: look for an "
    "obstruction in its path, "
    "the arm or gripper pressing on the table or the object, a load too heavy for the speed, or a "
    "torque limit (address 34) set too low; with torque off, check that the joint turns freely."
)


def _motion_failure(e: ServoFailure, bus: Bus, ids: list[int], where: str, baud: int) -> NodeError:
    notes = bus.torque_off(ids)
    if isinstance(e, _Stalled):
        head, hint = str(e), e.hint or STALL_HINT
    else:
        head, hint = _diagnose.head_and_hint(e, moving=True, baud=baud)
    if bus.lost is not None:
        # Nothing can be sent: the servos go on to the last goals written and hold there, powered.
        last = {
            c["id"]: c["value"]
            for c in bus.commands
            if c["instruction"] == "SYNC_WRITE" and c["address"] == 30
        }
        goals = f" ({', '.join(f'servo {k}: {v}' for k, v in last.items())} units)" if last else ""
        msg = (
            f"lost contact with the arm during waypoint {bus.waypoint!r} on {where}: "
            f"{head}; torque could not be "
            f"turned off: the servos go on to their last goals{goals} and hold there with "
            "torque on."
        )
        return NodeError(msg, hint=hint, lasting=True)
    msg = (
        f"arm stopped during waypoint {bus.waypoint!r} on {where}: {head}. Torque was "
        "turned off on all servos "
        f"{ids}" + (f" ({'; '.join(notes)})" if notes else "") + "."
    )
    # lasting: a --repeat loop ends here. The next cycle would reopen the port and move the arm as
    # soon as every servo answered again -- while a person may be at the arm, reseating a connector.
    return NodeError(msg, hint=hint, lasting=True)


def _safe_stop(bus: Bus, ids: list[int], arm: dict, params: DynamixelParams) -> dict:
    """End an interrupted motion as ``on_interrupt`` says; never raises."""
    limits = servo_limits_units(arm)
    speed = max(1, min(1023, speed_to_units(params.rest_speed_deg_s)))
    try:
        bus.recover()
        if params.on_interrupt == "torque_off":
            notes = bus.torque_off(ids)
            return {
                "action": "torque_off",
                "detail": "torque turned off on all servos (the arm is limp)"
                + (f" ({'; '.join(notes)})" if notes else ""),
            }
        if params.on_interrupt == "rest":
            home = {j["name"]: j["home_deg"] for j in arm["joints"] if j["name"] != "gripper"}
            rest_units = {
                int(k): v for k, v in joints_to_servo_units(arm, home).items() if int(k) in ids
            }
            return rest(bus, ids, limits, rest_units, speed, params.tolerance_units)
        return hold(bus, ids, limits, speed)
    except Exception as e:  # noqa: BLE001 - the bus failed while stopping: the last resort is torque off
        notes = bus.torque_off(ids)
        if bus.lost is not None:
            return {
                "action": "none",
                "detail": f"could not {params.on_interrupt} ({e}): torque could not be turned "
                f"off either, the servos go on to their last goals with torque on",
            }
        return {
            "action": "torque_off",
            "detail": f"could not {params.on_interrupt} ({e}); torque turned off "
            f"instead" + (f" ({'; '.join(notes)})" if notes else ""),
        }


def open_bus(params: DynamixelParams, port_path: str) -> Bus:
    """The bus at ``port_path``, open (a NodeError names the port and the fix when it cannot be)."""
    bus = Bus(
        port_path,
        params.baud,
        params.retries,
        time.monotonic(),
        late_window_ms=params.late_window_ms,
        reply_timeout_extra_ms=params.reply_timeout_extra_ms,
    )
    bus.open()
    return bus


def execute_plan(
    params: DynamixelParams, plan: dict, arm: dict, port_path: str, bus: Bus | None = None
) -> dict:
    """Ping, check, and run every waypoint of ``plan`` on the bus at ``port_path``; return the
    ServoLog.

    ``bus``: a bus kept open by the caller across plans (the cycles of a ``--repeat`` run); it is
    left open after a plan that succeeded, closed after any failure or interrupt (reopened and all
    servos checked again on the next plan). Without it the port is opened and closed here.

    Raises
    ------
    NodeError
        A servo fault before moving (nothing written; the message says whether torque is still on),
        a goal outside a servo's own angle limits (nothing written), or a failure during the motion
        (torque turned off first).
    KeyboardInterrupt
        Ctrl-C or SIGTERM (:class:`~nodes.actuators._stop.Terminated`): the motion was ended as
        ``on_interrupt`` says and the port closed first; ``servo_log`` on the exception holds the
        log.
    """
    check_plan(plan, arm)
    ids = sorted({int(k) for w in plan["waypoints"] for k in w["servo_units"]})
    t0 = time.monotonic()
    own = bus is None
    if own:
        bus = open_bus(params, port_path)
    elif not bus.is_open:
        bus.open()  # closed by a fault or an interrupt in an earlier plan: set up again
    bus.begin(t0)
    reached: list[dict] = []
    moved = False
    try:
        with stop_signals_as_interrupt():
            present = _check_servos(bus, ids, plan, params)
            grippers = _gripper_ids(arm)
            for w in plan["waypoints"]:
                bus.waypoint = w["name"]
                moved = True
                present, r = _run_waypoint(bus, w, present, params, grippers)
                reached.append(r)
            if params.torque_off_at_end:
                bus.torque_off(ids)
    except (ServoFailure, NodeError) as e:
        if not moved:
            raise _not_moved_error(e, bus, ids, params) from None
        err = _motion_failure(e, bus, ids, _bus_name(params, port_path), params.baud)
        bus.close()
        err.partial_log = _servo_log(plan, params, port_path, bus, reached, ok=False, t0=t0)
        raise err from None
    # Ctrl-C, SIGTERM, or a bug: end the motion safely before anything else
    except BaseException as e:
        signame = _interrupt_name(e)
        during = bus.waypoint if moved else "setup"
        if moved:
            stop = _safe_stop(bus, ids, arm, params)
        else:
            bus.recover()
            stop = {
                "action": "none",
                "detail": "interrupted before any goal was written; nothing moved",
            }
        bus.close()
        stop.update({"cause": signame, "during": during, "port_closed": True})
        log = _servo_log(plan, params, port_path, bus, reached, ok=False, t0=t0)
        log["stop"] = stop
        e.servo_log = log
        with contextlib.suppress(Exception):
            e.add_note(
                f"actuator: {signame} during {stop['during']!r}: {stop['detail']}; port closed."
            )
        raise
    if own:
        bus.close()
    return _servo_log(plan, params, port_path, bus, reached, ok=True, t0=t0)


def _bus_name(params: DynamixelParams, port_path: str) -> str:
    """The bus in words, for messages: its port (or the emulator's) and baud rate."""
    return (
        f"{params.port if params.port != 'sim' else 'the emulator (' + port_path + ')'} at "
        f"{params.baud} baud"
    )


def _not_moved_error(
    e: ServoFailure | NodeError, bus: Bus, ids: list[int], params: DynamixelParams
) -> NodeError:
    """A failure before any goal was written: what went wrong and whether torque is still on;
    the port is closed."""
    if isinstance(e, ServoFailure):
        head, hint = _diagnose.head_and_hint(e, moving=False, baud=params.baud)
    else:
        head, hint = e.message, e.hint
    torque, left_on = _diagnose.torque_report(bus, ids, params.torque_off_on_failure)
    bus.close()
    if left_on and not params.torque_off_on_failure:
        hint = (
            hint or ""
        ) + " To turn torque off when a run fails: --set act.torque_off_on_failure=true."
    msg = head.rstrip(".") + "; the arm was not moved." + (" " + torque if torque else "")
    return NodeError(msg, hint=hint)


def _interrupt_name(e: BaseException) -> str:
    """What ended the motion, in words: our own SIGTERM handler raises :class:`Terminated`; the
    engine's (``stereograph run --repeat``) raises ``KeyboardInterrupt("SIGTERM")``."""
    if isinstance(e, Terminated) or (
        isinstance(e, KeyboardInterrupt) and e.args[:1] == ("SIGTERM",)
    ):
        return "SIGTERM"
    return (
        "Ctrl-C (SIGINT)"
        if isinstance(e, KeyboardInterrupt)
        else f"an unexpected {type(e).__name__}"
    )


def _servo_log(plan, params, port_path, bus: Bus, reached, ok: bool, t0: float) -> dict:
    return {
        "pair": plan.get("pair"),
        "port": params.port if params.port != "sim" else f"sim:{port_path}",
        "baud": params.baud,
        "dry_run": False,
        "ok": ok,
        "servo_ids": sorted({int(k) for w in plan["waypoints"] for k in w["servo_units"]}),
        "commands": bus.commands,
        "reached": reached,
        "events": bus.events,
        "retries": bus.n_retries,
        "seconds": round(time.monotonic() - t0, 4),
        "sim": None,
    }


@node(
    "actuator.dynamixel",
    inputs={
        "arm": In("ArmModel"),
        "plans": In("PickPlan", gather=True, description="Every item's plan."),
        "world": In(
            "BenchWorld",
            optional=True,
            description="port sim: a simulated table (source.sim_bench) the emulated arm acts on.",
        ),
    },
    outputs={
        "log": Out("ServoLog", save=True, description="Commands sent, positions reached, timing."),
        "summary": Out(
            "PickSummary",
            save=True,
            headline=True,
            description="Object position, joint angles, servo goals.",
        ),
    },
    params=DynamixelParams,
    version="1",
    cacheable=False,
)
def dynamixel(params: DynamixelParams, arm, plans, world=None, ctx=None):
    """Run pick plans on AX-12A servos (real dynamixel-sdk, Protocol 1.0); port 'sim' = the
    emulator."""
    try:
        return _act(params, arm, plans, ctx, world)
    except KeyboardInterrupt as e:
        # before or between motions: no goal of this call was written
        if not getattr(e, "servo_logged", False):
            _save_interrupt_log(
                ctx,
                {
                    "stop": {
                        "action": "none",
                        "cause": _interrupt_name(e),
                        "during": "setup",
                        "port_closed": True,
                        "detail": "interrupted before any goal of this cycle was written; the "
                        "servos hold their last "
                        "goals (the port is closed as the run ends)",
                    }
                },
            )
        raise


def _save_interrupt_log(ctx, log: dict) -> Path | None:
    """``servo_log_interrupted.json`` in the node's folder (None without a run folder)."""
    if ctx is None:
        return None
    with contextlib.suppress(OSError):
        ctx.out_dir.mkdir(parents=True, exist_ok=True)
        path = ctx.out_dir / "servo_log_interrupted.json"
        path.write_text(json.dumps(log, indent=1))
        return path
    return None


def _emulator(params: DynamixelParams, arm, world) -> ServoSim:
    """The AX-12A emulator for ``port: sim``; with a simulated table, its arm moves the table's
    balls and starts at the home pose (where a real arm rests before a run)."""
    ids = sorted({s["id"] for j in arm["joints"] for s in j["servos"]})
    follow = positions = None
    if world is not None:
        follow = ArmFollower(world["path"], arm, world["T_table_from_base"])
        home = {
            **{n: joint(arm, n)["home_deg"] for n in JOINTS},
            "gripper": joint(arm, "gripper")["open_deg"],
        }
        positions = {int(i): float(u) for i, u in joints_to_servo_units(arm, home).items()}
    return ServoSim(
        ids,
        faults=params.sim_faults.to_faults(),
        time_scale=params.sim_time_scale,
        positions=positions,
        on_motion=follow,
    ).start()


def _act(params: DynamixelParams, arm, plans, ctx, world=None) -> dict:
    if world is not None and params.port != "sim" and ctx is not None:
        ctx.warn(
            "the wired `world` (a simulated table) is not used: the servos are real (port "
            f"{params.port}), so is the table"
        )
    chosen, skipped = select_plans(plans, params)
    for p in chosen:  # every chosen plan is checked before opening or starting anything
        check_plan(p, arm)
    # Kept open for the whole run when the engine can (every cycle of --repeat): the emulator, then
    # the port, so a cycle writes its first goal after one position read per servo instead of
    # reopening the port and pinging and reading every servo (docs/live.md, "Latency").
    keep = ctx is not None and ctx.resources is not None
    sim = None
    if params.port == "sim":
        sim = (
            ctx.resource("emulator", lambda: _emulator(params, arm, world))
            if keep
            else _emulator(params, arm, world)
        )
    try:
        port_path = sim.port_path if sim else params.port
        bus = (
            ctx.resource(f"bus {port_path}", lambda: open_bus(params, port_path)) if keep else None
        )
        picks = [_run(params, p, arm, port_path, sim, ctx, bus) for p in chosen]
    finally:
        if sim is not None and not keep:
            sim.stop()
    return {
        "log": {"ok": all(p["ok"] for p in picks), "picks": picks, "not_picked": skipped},
        "summary": summary(picks, chosen, skipped),
    }


def _sim_record(sim: ServoSim) -> dict:
    sim.drain()  # the last sync write (a hold, say) may still be on its way through the pty
    return {
        "writes": list(sim.log),
        "faults": list(sim.fault_log),
        "final_positions": {str(k): v for k, v in sim.positions().items()},
    }


def _run(params, plan, arm, port_path, sim, ctx, bus=None) -> dict:
    """execute_plan, plus the emulator's log, and on failure the partial log written next to the
    run's outputs."""
    n0 = len(sim.log) if sim is not None else 0
    try:
        log = execute_plan(params, plan, arm, port_path, bus)
    except NodeError as e:
        partial = getattr(e, "partial_log", None)
        if partial is not None and ctx is not None:
            partial["sim"] = _sim_record(sim) if sim is not None else None
            ctx.out_dir.mkdir(parents=True, exist_ok=True)
            # one file per failed motion of the run: a later cycle's failure must not overwrite the
            # log that an earlier cycle's message names
            failed = ctx.resource("failed logs", list)
            n = len(failed) + 1 if failed is not None else 1
            path = ctx.out_dir / (
                "servo_log_failed.json" if n == 1 else f"servo_log_failed_{n}.json"
            )
            if failed is not None:
                failed.append(path)
            path.write_text(json.dumps(partial, indent=1))
            e.message += f" The commands sent so far are in {path}."
            e.args = (e.message,)
        raise
    # interrupted: say what the arm did, keep the log, let the interrupt go on
    except BaseException as e:
        log = getattr(e, "servo_log", None)
        if log is not None:
            stop = log["stop"]
            text = (
                f"actuator.dynamixel: {stop['cause']} during {stop['during']!r}: "
                f"{stop['detail']}; the port "
                f"{port_path} was closed."
            )
            if sim is not None:
                log["sim"] = _sim_record(sim)
            path = _save_interrupt_log(ctx, log)
            if path is not None:
                text += f" Log: {path}."
            e.servo_logged = True
            print(text, file=sys.stderr, flush=True)
        raise
    if sim is not None:
        rec = _sim_record(sim)
        rec["writes"] = rec["writes"][n0:]
        log["sim"] = rec
    return log
