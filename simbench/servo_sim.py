"""An AX-12A servo emulator (a bench tool, not a node) speaking Dynamixel Protocol 1.0 on a
pseudo-terminal.

The emulator is a real serial peer: it opens a pty pair, puts the slave side in raw mode and
serves the master side from a background thread, so the real ``dynamixel_sdk`` (PortHandler,
PacketHandler(1.0), GroupSyncWrite) talks to it through ``sim.port_path`` exactly as it talks to a
USB2Dynamixel on ``/dev/ttyUSB0``.

What it emulates, per servo: the AX-12A control table (EEPROM 0-23, RAM 24-49, with each
register's size, access and value range), the instructions PING, READ, WRITE, REG_WRITE, ACTION,
RESET and SYNC_WRITE (broadcast, no reply), status packets with the error bits (angle limit,
range, checksum, instruction; angle-limit errors stay latched until a valid goal is written, as on
the servo), the status return level and return delay time, the baud-rate register (a servo whose
baud rate differs from the port's stays silent), and motion of the present position toward the
goal at the moving speed (0.111 rpm per unit; 0 = the servo's maximum, 59 rpm at 12 V) in real time
or scaled by ``time_scale``.

Fault injection (:class:`Faults`): dropped replies (a probability and/or a count), replies with a
corrupted checksum, late replies (the status packet held back, as a USB adapter's latency timer
does), each optionally only for some IDs, some instructions (e.g. READ only), or only once the
motion has begun (after N goal writes); unplugged IDs (no reply, sync-write data ignored); alarm
bits in every status packet (overload, overheating, input voltage, ...: a servo that reports an
alarm at the ping); and a jammed joint (an obstruction at a position: the servo stalls there,
raises the overload alarm and, as its shutdown register says, turns its torque off). Every write
that reaches a servo is appended to :attr:`ServoSim.log` (time, instruction, id, address, value,
accepted, error) so tests can assert what was commanded.

Usage::

    with ServoSim(ids=[1, 2, 3, 4, 5], faults=Faults(drop_reply_prob=0.1)) as sim:
        port = PortHandler(sim.port_path)
        ...
        goals = sim.writes(address=30)

Command line: ``stereograph servo-sim --ids 1,2,3,4,5 [--link /tmp/ttyDXL]`` (see :func:`cli`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import select
import signal
import threading
import time
import tty
from collections.abc import Iterable
from dataclasses import dataclass, field

from nodes.contracts.dynamixel_protocol import (  # noqa: F401  (re-exported: the emulator speaks it)
    ADDR,
    BROADCAST_ID,
    CONTROL_TABLE,
    EEPROM_END,
    ERR_ANGLE,
    ERR_CHECKSUM,
    ERR_INSTRUCTION,
    ERR_OVERHEAT,
    ERR_OVERLOAD,
    ERR_RANGE,
    ERR_VOLTAGE,
    ERROR_WORDS,
    INST_ACTION,
    INST_BULK_READ,
    INST_PING,
    INST_READ,
    INST_REG_WRITE,
    INST_RESET,
    INST_SYNC_WRITE,
    INST_WRITE,
    INSTRUCTION_NAMES,
    MAX_RPM,
    SPEED_RPM_PER_UNIT,
    TABLE_SIZE,
    UNITS_PER_DEG,
    checksum,
    decode_error,
    instruction_packet,
    status_packet,
)


# --------------------------------------------------------------------------- faults
@dataclass
class Faults:
    """Fault injection.

    Attributes
    ----------
    drop_reply_prob : float
        Probability that a status packet is not sent (the servo executed the instruction).
    drop_replies : int
        Drop this many status packets first (then ``drop_reply_prob`` applies).
    corrupt_prob : float
        Probability that a status packet is sent with a wrong checksum.
    corrupt_replies : int
        Corrupt this many status packets first.
    unplugged_ids : set of int
        Servos that are configured but do not answer or act (a loose cable).
    only_ids : set of int or None
        Restrict dropped / corrupted replies to these IDs.
    after_replies : int
        Start dropping / corrupting only after this many status packets (a fault that appears
        mid-motion).
    seed : int
        Random seed of the probabilistic faults.
    instructions : set of str or None
        Restrict dropped / corrupted / late replies and alarm bits to replies to these instructions
        (``{"READ"}``: a servo that answers PING but loses its READ replies).
    after_goal_writes : int
        Inject faults only once this many goal positions have been accepted (count): a fault that
        appears once the arm moves, whatever the number of packets before.
    short_replies : int
        Send this many status packets without their parameters (a valid checksum, but too short for
        the request: what a late reply to an earlier PING looks like to a READ).
    late_replies : int
        Hold back this many status packets first by ``late_ms`` (then ``late_prob`` applies).
    late_prob : float
        Probability that a status packet is held back by ``late_ms``.
    late_ms : float
        Delay of a late status packet (ms) — dynamixel-sdk stops waiting after ~34 ms at 1 Mbps.
    alarms : dict of int to int
        Alarm bits (ERR_OVERLOAD, ERR_OVERHEAT, ERR_VOLTAGE, ...) a servo sets in every status
        packet.
    jammed_at_units : dict of int to float
        An obstruction per servo at this position (units): the servo cannot pass it; pushing against
        it raises the overload alarm after ``jam_alarm_s`` and, with the overload bit in its
        shutdown register (the default), turns its torque off.
    jam_alarm_s : float
        Stall time before the overload alarm (s, emulated time).
    """

    drop_reply_prob: float = 0.0
    drop_replies: int = 0
    corrupt_prob: float = 0.0
    corrupt_replies: int = 0
    unplugged_ids: set[int] = field(default_factory=set)
    only_ids: set[int] | None = None
    after_replies: int = 0
    seed: int = 0
    instructions: set[str] | None = None
    after_goal_writes: int = 0
    short_replies: int = 0
    late_replies: int = 0
    late_prob: float = 0.0
    late_ms: float = 80.0
    alarms: dict[int, int] = field(default_factory=dict)
    jammed_at_units: dict[int, float] = field(default_factory=dict)
    jam_alarm_s: float = 0.2


# --------------------------------------------------------------------------- one servo
class AX12:
    """State of one emulated AX-12A (control table + motion)."""

    def __init__(self, dxl_id: int, position: float = 512.0, clock=time.monotonic):
        self.clock = clock
        self.table = bytearray(TABLE_SIZE)
        self.reset(dxl_id, position)

    def reset(self, dxl_id: int, position: float | None = None) -> None:
        pos = self.position if position is None else float(position)
        self.table[:] = bytes(TABLE_SIZE)
        for addr, (_name, _size, _w, _lo, _hi, default) in CONTROL_TABLE.items():
            if default is not None:
                self.set(addr, default)
        self.set(ADDR["id"], dxl_id)
        self.position = pos
        self.goal = pos
        self.set(ADDR["goal_position"], int(round(pos)))
        self.t_last = self.clock()
        self.pending: tuple[int, bytes] | None = None
        self.latched = 0
        # an obstruction at this position (units), see Faults.jammed_at_units
        self.jam: float | None = None
        self.jam_alarm_s = 0.2
        self.jam_side = 0
        self.stalled_s = 0.0

    # raw register access -------------------------------------------------------------
    def get(self, addr: int) -> int:
        size = CONTROL_TABLE[addr][1]
        return self.table[addr] | (self.table[addr + 1] << 8 if size == 2 else 0)

    def set(self, addr: int, value: int) -> None:
        self.table[addr] = value & 0xFF
        if CONTROL_TABLE[addr][1] == 2:
            self.table[addr + 1] = (value >> 8) & 0xFF

    @property
    def id(self) -> int:
        return self.table[ADDR["id"]]

    # motion ----------------------------------------------------------------------------
    def speed_units_per_s(self) -> float:
        s = self.get(ADDR["moving_speed"])
        rpm = MAX_RPM if s == 0 else min(MAX_RPM, s * SPEED_RPM_PER_UNIT)
        return rpm * 6.0 * UNITS_PER_DEG

    def update(self, time_scale: float) -> None:
        """Advance the present position toward the goal over the time elapsed since the last
        update."""
        now = self.clock()
        dt = (now - self.t_last) * time_scale
        self.t_last = now
        if self.table[ADDR["torque_enable"]] and self.goal != self.position:
            step = self.speed_units_per_s() * dt
            d = self.goal - self.position
            new = self.goal if abs(d) <= step else self.position + step * (1 if d > 0 else -1)
            j = self.jam
            if j is not None:
                # the obstruction holds the joint on the side it started from; pushing against it
                # overloads it
                if not self.jam_side:
                    self.jam_side = (self.position > j) - (self.position < j)
                new = (
                    max(new, j) if self.jam_side > 0 else min(new, j) if self.jam_side < 0 else new
                )
                if new == j and (self.goal - j) * self.jam_side < 0:
                    self.stalled_s += dt
                    self.set(ADDR["present_load"], 1023)
                    if self.stalled_s >= self.jam_alarm_s:
                        self.latched |= ERR_OVERLOAD
                        if self.table[ADDR["shutdown"]] & ERR_OVERLOAD:
                            self.set(ADDR["torque_enable"], 0)
            self.position = new
        moving = self.table[ADDR["torque_enable"]] and abs(self.goal - self.position) > 1e-9
        self.set(ADDR["present_position"], int(round(self.position)))
        self.set(ADDR["moving"], 1 if moving else 0)
        spd = self.get(ADDR["moving_speed"]) or 1023
        self.set(
            ADDR["present_speed"],
            (spd | (0 if self.goal >= self.position else 1024)) if moving else 0,
        )

    # writes -------------------------------------------------------------------------
    def write(self, addr: int, data: bytes) -> tuple[int, list[tuple[int, int, bool]]]:
        """Apply a write; return (error bits, [(register address, value, accepted), ...])."""
        end = addr + len(data)
        if not data or addr < 0 or end > TABLE_SIZE:
            return ERR_RANGE, []
        scratch = bytearray(self.table)
        scratch[addr:end] = data
        regs = [a for a, spec in CONTROL_TABLE.items() if a < end and a + spec[1] > addr]
        # A write may cover part of a 2-byte register: its other byte keeps its value.
        error, changes = 0, []
        for a in regs:
            name, size, writable, lo, hi, _ = CONTROL_TABLE[a]
            v = scratch[a] | (scratch[a + 1] << 8 if size == 2 else 0)
            if not writable or (a < EEPROM_END and self.table[ADDR["lock"]]):
                error |= ERR_RANGE
                changes.append((a, v, False))
                continue
            if not lo <= v <= hi:
                error |= ERR_RANGE
                changes.append((a, v, False))
                continue
            if a == ADDR["goal_position"]:
                cw, ccw = self.get(ADDR["cw_angle_limit"]), self.get(ADDR["ccw_angle_limit"])
                wheel = cw == 0 and ccw == 0
                if not wheel and not cw <= v <= ccw:
                    # The servo refuses the goal and reports it in every status packet until a valid
                    # one.
                    self.latched |= ERR_ANGLE
                    error |= ERR_ANGLE
                    changes.append((a, v, False))
                    continue
                self.latched &= ~ERR_ANGLE
                self.goal = float(v)
                self.set(ADDR["torque_enable"], 1)  # writing a goal turns the torque on (AX-12A)
            self.set(a, v)
            changes.append((a, v, True))
        return error, changes


# --------------------------------------------------------------------------- the bus
_BAUD_SPEEDS = {
    getattr(__import__("termios"), f"B{b}"): b
    for b in (
        9600,
        19200,
        38400,
        57600,
        115200,
        230400,
        460800,
        500000,
        576000,
        921600,
        1000000,
        1152000,
        2000000,
        2500000,
        3000000,
        3500000,
        4000000,
    )
    if hasattr(__import__("termios"), f"B{b}")
}


class ServoSim:
    """A chain of emulated AX-12A servos on a pseudo-terminal.

    Parameters
    ----------
    ids : iterable of int
        Servo IDs on the bus.
    faults : Faults, optional
        Fault injection (can be changed later with :meth:`set_faults`).
    time_scale : float
        Simulated seconds per real second for the motion (1 = real time; 10 = moves ten times
        faster).
    positions : dict, optional
        Initial present position per ID (units); default 512 (centre).
    link : str, optional
        Also create a symlink at this path to the pty (e.g. ``/tmp/ttyDXL``).
    check_baud : bool
        A servo answers only when the port's baud rate matches its baud-rate register.
    return_delay : bool
        Honour the return-delay-time register (2 us per unit; 500 us by default).
    on_write : callable, optional
        Called with each logged register write (a dict like the entries of :attr:`log`).
    on_motion : callable, optional
        Called with ``{id: present position (units, float)}`` each time the emulated motion advances
        (every packet): how a simulated world follows the arm (:mod:`simbench.world`). An exception
        in it is kept in :attr:`motion_error`, never raised into the serving thread.
    """

    def __init__(
        self,
        ids: Iterable[int] = (1, 2, 3, 4, 5),
        *,
        faults: Faults | None = None,
        time_scale: float = 1.0,
        positions: dict[int, float] | None = None,
        link: str | None = None,
        check_baud: bool = True,
        return_delay: bool = True,
        on_write=None,
        on_motion=None,
    ):
        self.time_scale = float(time_scale)
        self.servos: dict[int, AX12] = {}
        for i in ids:
            self.servos[int(i)] = AX12(int(i), (positions or {}).get(int(i), 512.0))
        self.faults = faults or Faults()
        self._rng = random.Random(self.faults.seed)
        self.link = link
        self.check_baud = check_baud
        self.return_delay = return_delay
        self.on_write = on_write
        self.on_motion = on_motion
        self.motion_error: BaseException | None = None
        self.log: list[dict] = []
        self.fault_log: list[dict] = []
        self.packets: list[dict] = []
        self.n_replies = 0
        self.n_goal_writes = 0
        self.lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._busy = False  # between reading bytes off the pty and handling them (see drain)
        self.master = self.slave = None
        self._wake: tuple[int, int] | None = None
        self.port_path: str | None = None
        self.t0 = time.monotonic()

    # lifecycle -----------------------------------------------------------------------
    def start(self) -> ServoSim:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo / line editing before a client configures the port
        path = os.ttyname(self.slave)
        if self.link:
            if os.path.islink(self.link):
                os.unlink(self.link)
            os.symlink(path, self.link)
            path = self.link
        self.port_path = path
        self._stop.clear()
        # stop() writes a byte: the serving thread ends at once, not at its next poll
        self._wake = os.pipe()
        self._thread = threading.Thread(target=self._serve, name="servo-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._wake is not None:
            with contextlib.suppress(OSError):
                os.write(self._wake[1], b"x")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self.master, self.slave, *(self._wake or ())):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self.slave = self._wake = None
        if self.link and os.path.islink(self.link):
            os.unlink(self.link)

    def close(self) -> None:
        """Same as :meth:`stop` (the engine closes a run's resources with ``close()``)."""
        self.stop()

    def drain(self, timeout_s: float = 0.5) -> bool:
        """Wait until every byte written to the port so far has been handled (its writes logged);
        False if that took longer than ``timeout_s``. A TX-only packet (a sync write) has no reply
        to wait for, so a log copied right after it can miss it without this."""
        import fcntl
        import struct
        import termios

        end = time.monotonic() + timeout_s
        idle = 0
        while time.monotonic() < end:
            try:
                waiting = struct.unpack(
                    "i", fcntl.ioctl(self.master, termios.FIONREAD, b"\0\0\0\0")
                )[0]
            except (OSError, TypeError):
                return True  # stopped: nothing more will be handled
            # idle twice, 2 ms apart: the kernel hands bytes written to the pty on asynchronously
            idle = idle + 1 if waiting == 0 and not self._busy else 0
            if idle >= 2:
                return True
            time.sleep(0.002)
        return False

    def __enter__(self) -> ServoSim:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # test helpers -------------------------------------------------------------------
    def set_faults(self, **changes) -> None:
        """Change fault settings while running (``sim.set_faults(drop_reply_prob=0.5)``)."""
        with self.lock:
            for k, v in changes.items():
                setattr(self.faults, k, v)

    def writes(
        self, address: int | None = None, dxl_id: int | None = None, accepted: bool | None = None
    ) -> list[dict]:
        """Logged register writes, filtered."""
        with self.lock:
            return [
                e
                for e in self.log
                if (address is None or e["address"] == address)
                and (dxl_id is None or e["id"] == dxl_id)
                and (accepted is None or e["accepted"] == accepted)
            ]

    def register(self, dxl_id: int, name_or_addr: str | int) -> int:
        """Current value of a register of a servo (motion updated first)."""
        with self.lock:
            self._update_all()
            s = self.servos[dxl_id]
            a = ADDR[name_or_addr] if isinstance(name_or_addr, str) else name_or_addr
            return s.get(a)

    def state(self) -> dict[str, dict[str, int]]:
        """Torque, goal, present position and moving flag of every servo (motion updated first)."""
        names = ("torque_enable", "goal_position", "present_position", "moving", "moving_speed")
        return {str(i): {n: self.register(i, n) for n in names} for i in self.servos}

    def positions(self) -> dict[int, int]:
        """Present position (units) of every servo."""
        return {i: self.register(i, "present_position") for i in self.servos}

    # serving ------------------------------------------------------------------------
    def _port_baud(self) -> int | None:
        try:
            import termios

            return _BAUD_SPEEDS.get(termios.tcgetattr(self.slave)[5])
        except Exception:  # noqa: BLE001 - a closed fd while stopping
            return None

    def _serve(self) -> None:
        buf = bytearray()
        t_last_byte = time.monotonic()
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self.master, self._wake[0]], [], [], 0.05)
            except (OSError, ValueError, TypeError):
                return
            if self.master not in r:
                if buf and time.monotonic() - t_last_byte > 0.1:
                    buf.clear()  # an incomplete packet: drop it, like the servo's packet timeout
                continue
            self._busy = True
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                self._busy = False
                continue
            if chunk:
                t_last_byte = time.monotonic()
                buf += chunk
                while True:
                    pkt = self._next_packet(buf)
                    if pkt is None:
                        break
                    self._handle(*pkt)
            self._busy = False

    @staticmethod
    def _next_packet(buf: bytearray):
        """Cut the next complete packet out of ``buf``: (id, instruction, params, checksum_ok) or
        None."""
        while True:
            i = buf.find(b"\xff\xff")
            if i < 0:
                del buf[: -1 if buf.endswith(b"\xff") else len(buf)]
                return None
            del buf[:i]
            if len(buf) >= 3 and buf[2] == 0xFF:  # FF FF FF ...: resync on the next byte
                del buf[0]
                continue
            if len(buf) < 4:
                return None
            length = buf[3]
            if length < 2:
                del buf[:2]
                continue
            total = length + 4
            if len(buf) < total:
                return None
            pkt = bytes(buf[:total])
            del buf[:total]
            ok = checksum(pkt[2:-1]) == pkt[-1]
            return pkt[2], pkt[4], pkt[5:-1], ok

    def _reply(self, servo: AX12, error: int, params: bytes = b"", *, instruction: int) -> None:
        srl = servo.table[ADDR["status_return_level"]]
        if instruction != INST_PING and (srl == 0 or (srl == 1 and instruction != INST_READ)):
            return
        f = self.faults
        self.n_replies += 1
        targeted = (
            (f.only_ids is None or servo.id in f.only_ids)
            and self.n_replies > f.after_replies
            and self.n_goal_writes >= f.after_goal_writes
            and (f.instructions is None or INSTRUCTION_NAMES.get(instruction) in f.instructions)
        )
        if targeted:
            error |= f.alarms.get(servo.id, 0)
            if f.short_replies > 0 and params:
                f.short_replies -= 1
                params = b""
                self.fault_log.append(
                    {
                        "t": round(time.monotonic() - self.t0, 6),
                        "id": servo.id,
                        "fault": "short reply",
                    }
                )
        pkt = bytearray(status_packet(servo.id, error | servo.latched, params))
        t = round(time.monotonic() - self.t0, 6)
        if targeted and (
            f.drop_replies > 0 or (f.drop_reply_prob and self._rng.random() < f.drop_reply_prob)
        ):
            f.drop_replies = max(0, f.drop_replies - 1)
            self.fault_log.append({"t": t, "id": servo.id, "fault": "dropped reply"})
            return
        if targeted and (
            f.corrupt_replies > 0 or (f.corrupt_prob and self._rng.random() < f.corrupt_prob)
        ):
            f.corrupt_replies = max(0, f.corrupt_replies - 1)
            pkt[-1] ^= 0x5A
            self.fault_log.append({"t": t, "id": servo.id, "fault": "corrupt checksum"})
        delay = 2e-6 * servo.table[ADDR["return_delay_time"]] if self.return_delay else 0.0
        if targeted and (f.late_replies > 0 or (f.late_prob and self._rng.random() < f.late_prob)):
            f.late_replies = max(0, f.late_replies - 1)
            delay += f.late_ms / 1000.0
            self.fault_log.append(
                {"t": t, "id": servo.id, "fault": f"late reply ({f.late_ms:g} ms)"}
            )
        if delay:
            time.sleep(delay)
        try:
            os.write(self.master, bytes(pkt))
        except OSError:
            pass

    def _alive(self, dxl_id: int) -> AX12 | None:
        s = self.servos.get(dxl_id)
        if s is None or dxl_id in self.faults.unplugged_ids:
            return None
        if self.check_baud:
            port = self._port_baud()
            want = 2_000_000 / (s.table[ADDR["baud_rate"]] + 1)
            if port is not None and abs(port - want) > 0.03 * want:
                return None  # garbage at the wrong baud rate: the servo hears nothing
        return s

    def _update_all(self) -> None:
        for s in self.servos.values():
            s.jam = self.faults.jammed_at_units.get(s.id)
            s.jam_alarm_s = self.faults.jam_alarm_s
            s.update(self.time_scale)
        if self.on_motion is not None and self.motion_error is None:
            try:
                self.on_motion({i: s.position for i, s in self.servos.items()})
            except Exception as e:  # noqa: BLE001 -- the bus must keep answering; the caller reads it
                self.motion_error = e

    def _log_changes(self, instruction: int, dxl_id: int, changes, error: int) -> None:
        t = round(time.monotonic() - self.t0, 6)
        self.n_goal_writes += sum(1 for a, _v, ok in changes if ok and a == ADDR["goal_position"])
        for a, v, ok in changes:
            self.log.append(
                {
                    "t": t,
                    "instruction": INSTRUCTION_NAMES[instruction],
                    "id": dxl_id,
                    "address": a,
                    "register": CONTROL_TABLE[a][0],
                    "value": v,
                    "accepted": ok,
                    "error": error,
                }
            )
            if self.on_write is not None:
                self.on_write(self.log[-1])

    def _handle(self, dxl_id: int, inst: int, params: bytes, ok: bool) -> None:
        with self.lock:
            self.packets.append(
                {
                    "t": round(time.monotonic() - self.t0, 6),
                    "id": dxl_id,
                    "instruction": INSTRUCTION_NAMES.get(inst, f"0x{inst:02x}"),
                    "checksum_ok": ok,
                }
            )
            self._update_all()
            if dxl_id == BROADCAST_ID:
                targets = [s for i in list(self.servos) if (s := self._alive(i)) is not None]
            else:
                s = self._alive(dxl_id)
                targets = [s] if s is not None else []
            if not ok:
                # A servo answers a corrupted packet addressed to it with the checksum error bit.
                if dxl_id != BROADCAST_ID and targets:
                    self._reply(targets[0], ERR_CHECKSUM, instruction=INST_WRITE)
                return
            if inst == INST_SYNC_WRITE:
                self._sync_write(params)
                return
            for s in targets:
                self._execute(s, inst, params, reply=dxl_id != BROADCAST_ID)

    def _execute(self, s: AX12, inst: int, params: bytes, reply: bool) -> None:
        err, data = 0, b""
        if inst == INST_PING:
            pass
        elif inst == INST_READ:
            err, data = _read(s, params)
        elif inst in (INST_WRITE, INST_REG_WRITE):
            err = self._write(s, inst, params)
        elif inst == INST_ACTION:
            err = self._action(s, inst)
        elif inst == INST_RESET:
            self._reset(s, inst, reply)
            return
        else:
            err = ERR_INSTRUCTION
        if reply:
            self._reply(s, err, data, instruction=inst)
        if inst == INST_WRITE and s.id not in self.servos:  # the ID register was rewritten
            for k, v in list(self.servos.items()):
                if v is s:
                    self.servos.pop(k)
            self.servos[s.id] = s

    def _write(self, s: AX12, inst: int, params: bytes) -> int:
        """WRITE now, or REG_WRITE (held until ACTION); the error byte."""
        if len(params) < 2:
            return ERR_INSTRUCTION
        if inst == INST_WRITE:
            err, changes = s.write(params[0], bytes(params[1:]))
            self._log_changes(inst, s.id, changes, err)
            return err
        if params[0] + len(params) - 1 > TABLE_SIZE:
            return ERR_RANGE
        s.pending = (params[0], bytes(params[1:]))
        s.table[ADDR["registered"]] = 1
        return 0

    def _action(self, s: AX12, inst: int) -> int:
        """ACTION: the write a REG_WRITE held; the error byte."""
        if s.pending is None:
            return ERR_INSTRUCTION
        addr, payload = s.pending
        s.pending = None
        s.table[ADDR["registered"]] = 0
        err, changes = s.write(addr, payload)
        self._log_changes(inst, s.id, changes, err)
        return err

    def _reset(self, s: AX12, inst: int, reply: bool) -> None:
        """RESET: the status reply first, then the factory table (its ID back to 1)."""
        old = s.id
        if reply:
            self._reply(s, 0, instruction=inst)
        s.reset(1)
        if old != 1:
            self.servos.pop(old, None)
            self.servos[1] = s

    def _sync_write(self, params: bytes) -> None:
        if len(params) < 2:
            return
        addr, n = params[0], params[1]
        body = params[2:]
        if n == 0 or len(body) % (n + 1):
            return  # malformed: the servos ignore it (there is no reply to a broadcast)
        for k in range(0, len(body), n + 1):
            s = self._alive(body[k])
            if s is None:
                continue
            err, changes = s.write(addr, bytes(body[k + 1 : k + 1 + n]))
            self._log_changes(INST_SYNC_WRITE, s.id, changes, err)


def _read(s: AX12, params: bytes) -> tuple[int, bytes]:
    """READ: ``(error byte, the bytes read)``."""
    if len(params) != 2:
        return ERR_INSTRUCTION, b""
    addr, n = params
    if addr + n > TABLE_SIZE or n == 0:
        return ERR_RANGE, b""
    return 0, bytes(s.table[addr : addr + n])


# --------------------------------------------------------------------------- CLI
def _ids(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        part = part.strip()
        if "-" in part:
            a, b = part.split("-")
            out += list(range(int(a), int(b) + 1))
        elif part:
            out.append(int(part))
    return out


def _parser() -> argparse.ArgumentParser:
    """``stereograph servo-sim``'s options."""
    ap = argparse.ArgumentParser(
        prog="stereograph servo-sim",
        description="Emulate AX-12A servos (Dynamixel Protocol 1.0) on a pseudo-terminal. "
        "Point any Dynamixel program at the printed port.",
    )
    ap.add_argument(
        "--ids", default="1,2,3,4,5", help="servo IDs, e.g. 1,2,3 or 1-5 (default 1,2,3,4,5)"
    )
    ap.add_argument(
        "--link", default=None, help="also make a symlink to the pty here, e.g. /tmp/ttyDXL"
    )
    ap.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="motion speed-up factor (default 1 = real time)",
    )
    ap.add_argument(
        "--drop-prob", type=float, default=0.0, help="probability of dropping a status packet"
    )
    ap.add_argument(
        "--corrupt-prob", type=float, default=0.0, help="probability of a corrupted status checksum"
    )
    ap.add_argument("--unplugged", default="", help="IDs that do not answer, e.g. 3")
    ap.add_argument("--seed", type=int, default=0, help="random seed of the faults")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    ap.add_argument(
        "--log",
        default=None,
        help="write the command log and the servos' final state (JSON) here when stopping",
    )
    ap.add_argument("--trace", action="store_true", help="print every register write as it arrives")
    return ap


def _print_write(e: dict) -> None:
    """``--trace``: one register write as it arrives."""
    print(
        f"write t={e['t']:.3f} id={e['id']} {e['register']}={e['value']}"
        f"{'' if e['accepted'] else ' REFUSED'}",
        flush=True,
    )


def _write_log(sim: ServoSim, path: str) -> None:
    """``--log``: the command log and the servos' final state, as JSON."""
    with open(path, "w") as f:
        json.dump(
            {
                "writes": sim.log,
                "faults": sim.fault_log,
                "positions": sim.positions(),
                "servos": sim.state(),
            },
            f,
            indent=1,
        )


def cli(argv: list[str] | None = None) -> int:
    """``stereograph servo-sim``: run emulated AX-12A servos on a pseudo-terminal until Ctrl-C."""
    a = _parser().parse_args(argv)
    try:
        ids = _ids(a.ids)
        unplugged = set(_ids(a.unplugged))
    except ValueError:
        print(
            "servo-sim: --ids/--unplugged must be comma-separated integers or ranges, "
            f"got {a.ids!r} / "
            f"{a.unplugged!r}"
        )
        return 2
    if not ids or any(not 0 <= i <= 253 for i in ids):
        print("servo-sim: IDs must be 0-253.")
        return 2
    faults = Faults(
        drop_reply_prob=a.drop_prob,
        corrupt_prob=a.corrupt_prob,
        unplugged_ids=unplugged,
        seed=a.seed,
    )
    stop = threading.Event()
    main = threading.current_thread() is threading.main_thread()
    prev = signal.signal(signal.SIGTERM, lambda *_: stop.set()) if main else None
    try:
        with ServoSim(
            ids,
            faults=faults,
            time_scale=a.time_scale,
            link=a.link,
            on_write=_print_write if a.trace else None,
        ) as sim:
            print(
                f"AX-12A emulator: IDs {','.join(map(str, ids))} on {sim.port_path} "
                f"(Protocol 1.0, 1 Mbps). Ctrl-C to stop.",
                flush=True,
            )
            try:
                stop.wait(a.duration)
            except KeyboardInterrupt:
                pass
            if a.log:
                _write_log(sim, a.log)
            print(
                f"servo-sim: stopped after {len(sim.packets)} packets, {len(sim.log)} "
                "register writes."
            )
    finally:
        if main:
            signal.signal(signal.SIGTERM, prev)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(cli())
