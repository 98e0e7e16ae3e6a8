"""``actuator.dynamixel``: run a PickPlan on AX-12A servos with the real dynamixel-sdk (Protocol 1.0).

The same code path for hardware and emulation: with ``port: sim`` the node starts the project's
emulator (:mod:`nodes.actuators.servo_sim`) on a pseudo-terminal and talks to it through the real
``PortHandler`` / ``PacketHandler(1.0)`` / ``GroupSyncWrite``.

Safety order: (1) every goal of the plan is checked against the joint limits before the port is
even opened — one bad goal refuses the whole plan; (2) every servo must answer a ping; (3) each
servo's own CW/CCW angle limits must contain its goals; only then is anything written. Each
waypoint is one GroupSyncWrite (goal position + moving speed for all servos at once), read back,
then present positions are polled one servo at a time until all are within ``tolerance_units``
(the gripper may also stop short, closed on the object) or the move times out. Timeouts and
checksum errors are retried ``retries`` times; after that, or on a servo error (angle limit,
overload, overheating, voltage, range), torque is turned off on every servo and the node fails
with the reason.
"""

from __future__ import annotations

import contextlib
import errno
import json
import time

from nodes.ik._model import joint
from stereograph.api import Field, In, NodeError, Out, Params, node

from ._plan import (
    ADDR_GOAL,
    REGISTER_NAMES,
    Selection,
    check_plan,
    move_seconds,
    select_plans,
    summary,
    waypoint_data,
)
from .servo_sim import (
    ERR_ANGLE,
    ERR_CHECKSUM,
    ERR_INSTRUCTION,
    ERR_OVERHEAT,
    ERR_OVERLOAD,
    ERR_RANGE,
    ERR_VOLTAGE,
    Faults,
    ServoSim,
    decode_error,
)

ADDR_CW_LIMIT, ADDR_TORQUE, ADDR_POSITION, ADDR_MOVING = 6, 24, 36, 46
HARD_ERRORS = ERR_VOLTAGE | ERR_ANGLE | ERR_OVERHEAT | ERR_RANGE | ERR_OVERLOAD
SOFT_ERRORS = ERR_CHECKSUM | ERR_INSTRUCTION  # the servo got a damaged packet: send it again


class SimFaults(Params):
    """Fault injection for ``port: sim`` (demos and tests)."""

    drop_reply_prob: float = Field(0.0, ge=0, le=1, description="Probability of a dropped status packet.")
    drop_replies: int = Field(0, ge=0, description="Drop this many status packets first (count).")
    corrupt_prob: float = Field(0.0, ge=0, le=1, description="Probability of a status packet with a bad checksum.")
    corrupt_replies: int = Field(0, ge=0, description="Corrupt this many status packets first (count).")
    unplugged_ids: list[int] = Field(default_factory=list, description="Servo IDs that do not answer.")
    only_ids: list[int] | None = Field(None, description="Restrict dropped/corrupted replies to these IDs.")
    after_replies: int = Field(0, ge=0, description="Inject faults only after this many status packets (count).")
    seed: int = Field(0, ge=0, description="Random seed of the faults.")


class DynamixelParams(Selection):
    port: str = Field("/dev/ttyUSB0", description="Serial port of the USB2Dynamixel / U2D2, or 'sim' to start the "
                                                  "AX-12A emulator on a pseudo-terminal.")
    baud: int = Field(1_000_000, description="Baud rate (bit/s); AX-12A default 1000000.")
    retries: int = Field(3, ge=0, le=20, description="Re-sends after a timeout or checksum error (count).")
    tolerance_units: int = Field(3, ge=0, le=50, description="Arrival tolerance (servo units, 1 unit = 0.293 deg).")
    move_timeout_s: float | None = Field(None, gt=0, le=600, description="Per-waypoint timeout (s); default "
                                                                         "1.5 x the expected move time + 1 s.")
    poll_interval_s: float = Field(0.02, ge=0, le=1, description="Pause between position polls (s).")
    torque_off_at_end: bool = Field(False, description="Turn torque off after the last waypoint (drops a held object).")
    sim_time_scale: float = Field(1.0, gt=0, le=1000, description="port sim: motion speed-up factor (1 = real time).")
    sim_faults: SimFaults = Field(default_factory=SimFaults, description="port sim: fault injection.")


class ServoFailure(Exception):
    """Communication or servo failure after the bounded retries (message says which servo and why)."""


class Bus:
    """dynamixel-sdk Protocol 1.0 calls with bounded retries and a command log."""

    def __init__(self, port_path: str, baud: int, retries: int, t0: float):
        from dynamixel_sdk import PacketHandler, PortHandler
        self.port_path, self.baud, self.retries, self.t0 = port_path, baud, retries, t0
        self.port = PortHandler(port_path)
        self.ph = PacketHandler(1.0)
        self.commands: list[dict] = []
        self.events: list[str] = []
        self.n_retries = 0
        self.waypoint = "setup"

    def open(self) -> None:
        try:
            ok = self.port.openPort()
        except Exception as e:  # noqa: BLE001 - pyserial raises SerialException subclasses of OSError
            err = getattr(e, "errno", None)
            text = str(e)
            if err == errno.EACCES or "Permission denied" in text:
                hint = (f"add yourself to the dialout group (sudo usermod -aG dialout $USER, then log in again) "
                        f"or check the permissions of {self.port_path}.")
            elif err == errno.ENOENT or "No such file" in text or "could not open" in text:
                hint = ("plug in the USB2Dynamixel / U2D2 and check the device name (ls /dev/ttyUSB* /dev/ttyACM*); "
                        "use port: sim to run on the emulator.")
            else:
                hint = "check the adapter and that no other program has the port open."
            raise NodeError(f"cannot open serial port {self.port_path}: {text}", hint=hint) from None
        if not ok or not self.port.setBaudRate(self.baud):
            with contextlib.suppress(Exception):
                self.port.closePort()
            raise NodeError(f"cannot set serial port {self.port_path} to {self.baud} baud.",
                            hint="use a rate the SDK supports (AX-12A default 1000000; also 57600, 115200, ...).")

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.port.closePort()

    def _t(self) -> float:
        return round(time.monotonic() - self.t0, 6)

    def _call(self, what: str, sid: int, fn, *args, reply_has_value: bool = True):
        """Call an SDK TxRx function with retries; return its value (or None for writes)."""
        last = ""
        for attempt in range(self.retries + 1):
            out = fn(self.port, sid, *args)
            value, comm, err = out if reply_has_value else (None, *out)
            if comm == 0 and not (err & SOFT_ERRORS) and not (err & HARD_ERRORS):
                return value
            if comm == 0 and err & HARD_ERRORS:
                raise ServoFailure(f"servo {sid} reported {', '.join(decode_error(err))} during {what}")
            last = self.ph.getTxRxResult(comm) if comm != 0 else ", ".join(decode_error(err))
            if attempt < self.retries:
                self.n_retries += 1
                self.events.append(f"{self._t():.3f}s {self.waypoint}: {what} on servo {sid}: {last}; retry "
                                   f"{attempt + 1}/{self.retries}")
        raise ServoFailure(f"servo {sid} did not answer {what} correctly after {self.retries + 1} tries ({last})")

    def ping(self, sid: int) -> int:
        return self._call("ping", sid, self.ph.ping)

    def bare_ping(self, sid: int) -> bool:
        """A lone PING packet. The SDK's Protocol 1 ``ping`` also READs the model number, which a
        servo with status return level 0 never answers; this tells "absent" from "silent"."""
        from dynamixel_sdk import COMM_SUCCESS

        tx = [0] * 6
        tx[2], tx[3], tx[4] = sid, 2, 1  # ID, LENGTH, INST_PING (checksum added by the SDK)
        for _ in range(self.retries + 1):
            _, comm, _ = self.ph.txRxPacket(self.port, tx)
            if comm == COMM_SUCCESS:
                return True
        return False

    def read1(self, sid: int, addr: int, what: str) -> int:
        return self._call(what, sid, self.ph.read1ByteTxRx, addr)

    def read2(self, sid: int, addr: int, what: str) -> int:
        return self._call(what, sid, self.ph.read2ByteTxRx, addr)

    def read4(self, sid: int, addr: int, what: str) -> int:
        return self._call(what, sid, self.ph.read4ByteTxRx, addr)

    def write1(self, sid: int, addr: int, value: int, what: str) -> None:
        self._log("WRITE", sid, addr, value)
        self._call(what, sid, self.ph.write1ByteTxRx, addr, value, reply_has_value=False)

    def sync_write(self, data: dict[int, tuple[int, int]]) -> None:
        from dynamixel_sdk import DXL_HIBYTE, DXL_LOBYTE, GroupSyncWrite
        g = GroupSyncWrite(self.port, self.ph, ADDR_GOAL, 4)
        for sid, (goal, speed) in data.items():
            g.addParam(sid, [DXL_LOBYTE(goal), DXL_HIBYTE(goal), DXL_LOBYTE(speed), DXL_HIBYTE(speed)])
            self._log("SYNC_WRITE", sid, 30, goal)
            self._log("SYNC_WRITE", sid, 32, speed)
        comm = g.txPacket()
        if comm != 0:
            raise ServoFailure(f"sync write failed on {self.port_path}: {self.ph.getTxRxResult(comm)}")

    def _log(self, instruction: str, sid: int, addr: int, value: int) -> None:
        self.commands.append({"t_s": self._t(), "waypoint": self.waypoint, "instruction": instruction, "id": int(sid),
                              "address": addr, "register": REGISTER_NAMES.get(addr, str(addr)), "value": int(value)})

    def torque_off(self, ids: list[int]) -> list[str]:
        """Torque off everywhere: one broadcast (needs no reply) then each servo once; never raises."""
        from dynamixel_sdk import BROADCAST_ID
        notes = []
        with contextlib.suppress(Exception):
            self.port.is_using = False  # a failed exchange may have left the SDK's busy flag set
            self._log("WRITE", BROADCAST_ID, ADDR_TORQUE, 0)
            self.ph.write1ByteTxOnly(self.port, BROADCAST_ID, ADDR_TORQUE, 0)
        for sid in ids:
            try:
                self._log("WRITE", sid, ADDR_TORQUE, 0)
                comm, err = self.ph.write1ByteTxRx(self.port, sid, ADDR_TORQUE, 0)
                if comm != 0:
                    notes.append(f"servo {sid}: no confirmation ({self.ph.getTxRxResult(comm)})")
            except Exception as e:  # noqa: BLE001 - best effort while failing
                notes.append(f"servo {sid}: {e}")
        return notes


def _gripper_ids(arm: dict) -> set[int]:
    try:
        return {s["id"] for s in joint(arm, "gripper")["servos"]}
    except KeyError:
        return set()


def execute_plan(params: DynamixelParams, plan: dict, arm: dict, port_path: str) -> dict:
    """Ping, check, and run every waypoint of ``plan`` on the bus at ``port_path``; return the ServoLog.

    Raises
    ------
    NodeError
        A missing servo (nothing written), a goal outside a servo's own angle limits (nothing
        written), or a failure during the motion (torque turned off first).
    """
    check_plan(plan, arm)
    ids = sorted({int(k) for w in plan["waypoints"] for k in w["servo_units"]})
    t0 = time.monotonic()
    bus = Bus(port_path, params.baud, params.retries, t0)
    bus.open()
    where = f"{params.port if params.port != 'sim' else 'the emulator (' + port_path + ')'} at {params.baud} baud"
    reached: list[dict] = []
    moved = False
    try:
        # 1. Everyone present? Nothing is written before all servos answered.
        for sid in ids:
            try:
                model = bus.ping(sid)
            except ServoFailure:
                if bus.bare_ping(sid):
                    raise NodeError(
                        f"servo ID {sid} answers a PING on {where} but not a READ: its status return level "
                        f"(address 16) is 0, so its position cannot be read back; the arm was not moved.",
                        hint=f"set servo {sid}'s status return level to 1 or 2 (Dynamixel Wizard / RoboPlus, or "
                             f"a WRITE of 1 to address 16).") from None
                raise NodeError(
                    f"servo ID {sid} did not answer a ping on {where} (after {params.retries + 1} tries); the arm was "
                    f"not moved.",
                    hint=f"check servo {sid}'s cable in the daisy chain and the 9-12 V supply, that its ID is {sid} and "
                         f"its baud rate {params.baud} (set both with Dynamixel Wizard / RoboPlus).") from None
            if model not in (12, 18, 44, 300):
                bus.events.append(f"servo {sid} reports model number {model}, not an AX-12A (12)")
        # 2. The servos' own angle limits must allow every goal.
        for sid in ids:
            limits = bus.read4(sid, ADDR_CW_LIMIT, "read of the angle limits")
            cw, ccw = limits & 0xFFFF, limits >> 16
            for w in plan["waypoints"]:
                g = w["servo_units"].get(str(sid))
                if g is not None and not (cw == ccw == 0) and not cw <= g <= ccw:
                    raise NodeError(f"refusing the whole plan: servo {sid}'s own angle limits are {cw}..{ccw} units but "
                                    f"waypoint {w['name']!r} needs {g}; nothing was sent.",
                                    hint="fix the servo's CW/CCW angle limits (addresses 6/8) or the arm model's "
                                         "joint limits / zero offsets.")
        present = {sid: bus.read2(sid, ADDR_POSITION, "read of the present position") for sid in ids}
        grippers = _gripper_ids(arm)
        for w in plan["waypoints"]:
            bus.waypoint = w["name"]
            data = waypoint_data(w)
            expected = move_seconds(present, data)
            timeout = params.move_timeout_s or (1.5 * expected + 1.0)
            t_start = time.monotonic()
            moved = True
            # 3. All joints at once; read the goals back, since a broadcast has no reply to confirm it.
            for attempt in range(params.retries + 1):
                bus.sync_write(data)
                got = {sid: bus.read2(sid, ADDR_GOAL, "read-back of the goal position") for sid in data}
                missing = [sid for sid in data if got[sid] != data[sid][0]]
                if not missing:
                    break
                if attempt == params.retries:
                    raise ServoFailure(f"servos {missing} did not take their goal positions after "
                                       f"{params.retries + 1} sync writes")
                bus.n_retries += 1
                bus.events.append(f"{w['name']}: goal read-back mismatch on servos {missing}; sync write again")
            # 4. Poll until every servo is there (the gripper may stop on the object) or time out.
            while True:
                pos = {sid: bus.read2(sid, ADDR_POSITION, "read of the present position") for sid in data}
                err = {sid: abs(pos[sid] - data[sid][0]) for sid in data}
                pending = [sid for sid in data if err[sid] > params.tolerance_units]
                if pending and set(pending) <= grippers:
                    if all(bus.read1(sid, ADDR_MOVING, "read of the moving flag") == 0 for sid in pending):
                        # Stopped: at the goal by now, or short of it, closed on the object.
                        for sid in pending:
                            pos[sid] = bus.read2(sid, ADDR_POSITION, "read of the present position")
                            err[sid] = abs(pos[sid] - data[sid][0])
                        short = [sid for sid in pending if err[sid] > params.tolerance_units]
                        if short:
                            bus.events.append(f"{w['name']}: gripper stopped {max(err[s] for s in short)} units "
                                              f"short of its goal (holding the object)")
                        pending = []
                if not pending:
                    break
                if time.monotonic() - t_start > timeout:
                    raise ServoFailure(
                        f"waypoint {w['name']!r}: servos {pending} still {[err[s] for s in pending]} units from their "
                        f"goals after {timeout:.1f} s")
                time.sleep(params.poll_interval_s)
            present = pos
            reached.append({"waypoint": w["name"], "goal_units": {str(s): data[s][0] for s in data},
                            "present_units": {str(s): int(pos[s]) for s in data},
                            "max_error_units": int(max(err.values())),
                            "seconds": round(time.monotonic() - t_start, 4)})
        if params.torque_off_at_end:
            bus.torque_off(ids)
    except (ServoFailure, NodeError) as e:
        if not moved:
            bus.close()
            if isinstance(e, NodeError):
                raise
            raise NodeError(f"servo check failed on {where}: {e}; the arm was not moved.",
                            hint="check the cables, the power supply and the servo settings.") from None
        notes = bus.torque_off(ids)
        bus.close()
        msg = (f"arm stopped during waypoint {bus.waypoint!r} on {where}: {e}. Torque was turned off on all servos "
               f"{ids}" + (f" ({'; '.join(notes)})" if notes else "") + ".")
        err = NodeError(msg, hint="check the cables and the 9-12 V supply, then run again; a noisy bus may need a "
                                  "shorter cable or more retries.")
        err.partial_log = _servo_log(plan, params, port_path, bus, reached, ok=False, t0=t0)
        raise err from None
    bus.close()
    return _servo_log(plan, params, port_path, bus, reached, ok=True, t0=t0)


def _servo_log(plan, params, port_path, bus: Bus, reached, ok: bool, t0: float) -> dict:
    return {"pair": plan.get("pair"), "port": params.port if params.port != "sim" else f"sim:{port_path}",
            "baud": params.baud, "dry_run": False, "ok": ok,
            "servo_ids": sorted({int(k) for w in plan["waypoints"] for k in w["servo_units"]}),
            "commands": bus.commands, "reached": reached, "events": bus.events, "retries": bus.n_retries,
            "seconds": round(time.monotonic() - t0, 4), "sim": None}


@node("actuator.dynamixel",
      inputs={"arm": In("ArmModel"), "plans": In("PickPlan", gather=True, description="Every item's plan.")},
      outputs={"log": Out("ServoLog", save=True, description="Commands sent, positions reached, timing."),
               "summary": Out("PickSummary", description="Object position, joint angles, servo goals.")},
      params=DynamixelParams, version="1", cacheable=False)
def dynamixel(params: DynamixelParams, arm, plans, ctx=None):
    """Run pick plans on AX-12A servos (real dynamixel-sdk, Protocol 1.0); port 'sim' = the emulator."""
    chosen, skipped = select_plans(plans, params)
    for p in chosen:  # every chosen plan is checked before opening or starting anything
        check_plan(p, arm)
    sim = None
    if params.port == "sim":
        f = params.sim_faults
        faults = Faults(drop_reply_prob=f.drop_reply_prob, drop_replies=f.drop_replies, corrupt_prob=f.corrupt_prob,
                        corrupt_replies=f.corrupt_replies, unplugged_ids=set(f.unplugged_ids),
                        only_ids=None if f.only_ids is None else set(f.only_ids),
                        after_replies=f.after_replies, seed=f.seed)
        ids = sorted({s["id"] for j in arm["joints"] for s in j["servos"]})
        sim = ServoSim(ids, faults=faults, time_scale=params.sim_time_scale).start()
    try:
        port_path = sim.port_path if sim else params.port
        picks = [_run(params, p, arm, port_path, sim, ctx) for p in chosen]
    finally:
        if sim is not None:
            sim.stop()
    return {"log": {"ok": all(p["ok"] for p in picks), "picks": picks, "not_picked": skipped},
            "summary": summary(picks, chosen, len(skipped))}


def _sim_record(sim: ServoSim) -> dict:
    return {"writes": list(sim.log), "faults": list(sim.fault_log),
            "final_positions": {str(k): v for k, v in sim.positions().items()}}


def _run(params, plan, arm, port_path, sim, ctx) -> dict:
    """execute_plan, plus the emulator's log, and on failure the partial log written next to the run's outputs."""
    n0 = len(sim.log) if sim is not None else 0
    try:
        log = execute_plan(params, plan, arm, port_path)
    except NodeError as e:
        partial = getattr(e, "partial_log", None)
        if partial is not None and ctx is not None:
            partial["sim"] = _sim_record(sim) if sim is not None else None
            ctx.out_dir.mkdir(parents=True, exist_ok=True)
            path = ctx.out_dir / "servo_log_failed.json"
            path.write_text(json.dumps(partial, indent=1))
            e.message += f" The commands sent so far are in {path}."
            e.args = (e.message,)
        raise
    if sim is not None:
        rec = _sim_record(sim)
        rec["writes"] = rec["writes"][n0:]
        log["sim"] = rec
    return log
