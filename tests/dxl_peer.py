"""An independent Protocol 1.0 servo peer on a pseudo-terminal (test helper; not the bundled
emulator).

Written from the Robotis AX-12A e-manual's control table, to behave the ways a real bus can:
status return level 0/1, a return delay time, other models on the same bus, narrow angle limits,
wheel mode, an adapter that echoes what it sends, replies split into pieces, noise around a
packet, a servo that stops short of its goal (compliance margin), slow motion, position jitter,
and a servo set to another baud rate than the port.

    with Peer({1: Servo(), 2: Servo(model=18)}, echo=True) as p:
        ... p.path ...

Run as a script it serves until Ctrl-C: ``python tests/dxl_peer.py --ids 1-5 --link /tmp/ttyPEER``.
"""

from __future__ import annotations

import os
import random
import select
import termios
import threading
import time
import tty
from dataclasses import dataclass, field

# AX-12A control table: address -> (size, default, writable)
TABLE = {
    0: (2, 12, False),
    2: (1, 24, False),
    3: (1, 1, True),
    4: (1, 1, True),
    5: (1, 250, True),
    6: (2, 0, True),
    8: (2, 1023, True),
    11: (1, 70, True),
    12: (1, 60, True),
    13: (1, 140, True),
    14: (2, 1023, True),
    16: (1, 2, True),
    17: (1, 36, True),
    18: (1, 36, True),
    24: (1, 0, True),
    25: (1, 0, True),
    26: (1, 1, True),
    27: (1, 1, True),
    28: (1, 32, True),
    29: (1, 32, True),
    30: (2, 512, True),
    32: (2, 0, True),
    34: (2, 1023, True),
    36: (2, 512, False),
    38: (2, 0, False),
    40: (2, 0, False),
    42: (1, 120, False),
    43: (1, 32, False),
    44: (1, 0, False),
    46: (1, 0, False),
    47: (1, 0, True),
    48: (2, 32, True),
}
BAUD_REG = {
    1: 1_000_000,
    3: 500_000,
    4: 400_000,
    7: 250_000,
    9: 200_000,
    16: 115200,
    34: 57600,
    103: 19200,
    207: 9600,
}
TERMIOS_BAUD = {
    getattr(termios, f"B{b}"): b
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
    )
}
E_ANGLE, E_RANGE, E_CHECKSUM, E_INSTRUCTION = 2, 8, 16, 64


def cks(b) -> int:
    return (~sum(b)) & 0xFF


@dataclass
class Servo:
    model: int = 12
    srl: int = 2  # status return level
    return_delay: int = 0  # register 5 (2 us per unit)
    cw: int = 0
    ccw: int = 1023
    position: float = 512.0
    short_by: int = 0  # stops this many units before the goal (compliance)
    speed_factor: float = 1.0  # < 1: slower than the speed register says
    jitter: int = 0  # +- units of noise on present position
    baud_reg: int = 1
    torque: int = 0
    regs: dict = field(default_factory=dict)

    def setup(self, sid):
        for a, (n, d, _) in TABLE.items():
            self.set(a, n, d)
        self.set(0, 2, self.model)
        self.set(3, 1, sid)
        self.set(4, 1, self.baud_reg)
        self.set(5, 1, self.return_delay)
        self.set(6, 2, self.cw)
        self.set(8, 2, self.ccw)
        self.set(16, 1, self.srl)
        self.set(24, 1, self.torque)
        self.set(30, 2, int(self.position))
        self.set(36, 2, int(self.position))

    def set(self, a, n, v):
        for i in range(n):
            self.regs[a + i] = (int(v) >> (8 * i)) & 0xFF

    def get(self, a, n):
        return sum(self.regs.get(a + i, 0) << (8 * i) for i in range(n))


class Peer:
    def __init__(
        self,
        servos: dict[int, Servo],
        *,
        echo=False,
        split=False,
        trailing_garbage=b"",
        leading_noise=b"",
        time_scale=1.0,
        seed=0,
        twins=(),
    ):
        self.servos = servos
        # IDs set on two servos: each status packet comes twice, one after the other (servos with
        # different return delay times; the same delay would make them collide into garbage on a
        # real bus)
        self.twins = set(twins)
        self.echo, self.split = echo, split
        self.trailing, self.leading = trailing_garbage, leading_noise
        self.time_scale = time_scale
        self.rng = random.Random(seed)
        self.log: list[tuple] = []  # (instruction, id, addr, bytes)
        self.lock = threading.Lock()
        for sid, s in servos.items():
            s.setup(sid)
        self._stop = threading.Event()

    def __enter__(self):
        return self.start()

    def __exit__(self, *a):
        self.stop()

    def start(self, link: str | None = None):
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        if link:
            if os.path.lexists(link):
                os.unlink(link)
            os.symlink(self.path, link)
        self._last = time.monotonic()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()
        return self

    def stop(self):
        self._stop.set()
        self.thread.join(2)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    # ---------------------------------------------------------------- motion
    def _advance(self):
        now = time.monotonic()
        dt = (now - self._last) * self.time_scale
        self._last = now
        for s in self.servos.values():
            # torque off, or a torque limit of 0: no force at all
            if not s.get(24, 1) or not s.get(34, 2):
                s.set(46, 1, 0)
                continue
            speed = s.get(32, 2) & 0x3FF
            rpm = 114.0 if speed == 0 else 0.111 * speed
            ups = rpm * 6.0 * 1023.0 / 300.0 * s.speed_factor
            cw, ccw = s.get(6, 2), s.get(8, 2)
            # wheel mode: speed register is a turn rate, position just wraps
            if cw == 0 and ccw == 0:
                s.set(46, 1, 1 if speed & 0x3FF else 0)
                continue
            goal = s.get(30, 2)
            target = (
                goal - s.short_by
                if goal > s.position
                else goal + s.short_by
                if goal < s.position
                else goal
            )
            if abs(goal - s.position) <= s.short_by:
                target = s.position
            d = target - s.position
            step = min(abs(d), ups * dt)
            s.position += step if d > 0 else -step
            s.set(46, 1, 1 if abs(target - s.position) > 0.5 else 0)
            s.set(36, 2, int(round(s.position)))

    # ---------------------------------------------------------------- bytes
    def _baud_ok(self, s: Servo) -> bool:
        try:
            port = TERMIOS_BAUD.get(termios.tcgetattr(self.master)[4])
        except termios.error:
            return True
        return port is None or port == BAUD_REG.get(s.get(4, 1))

    def _send(self, pkt: bytes, delay_s: float):
        if delay_s:
            time.sleep(delay_s)
        data = self.leading + pkt + self.trailing
        if len(pkt) > 2 and pkt[2] in self.twins:
            data += pkt
        if self.split:
            for i in range(0, len(data), 3):
                os.write(self.master, data[i : i + 3])
                time.sleep(0.0015)
        else:
            os.write(self.master, data)

    def _status(self, sid, err, params=b""):
        body = bytes([sid, len(params) + 2, err]) + bytes(params)
        return b"\xff\xff" + body + bytes([cks(body)])

    def _serve(self):
        buf = bytearray()
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self.master], [], [], 0.01)
            except (OSError, ValueError):
                return
            with self.lock:
                self._advance()
            if not r:
                continue
            try:
                chunk = os.read(self.master, 256)
            except OSError:
                return
            if self.echo:
                os.write(self.master, chunk)
            buf += chunk
            while True:
                i = buf.find(b"\xff\xff")
                if i < 0:
                    buf.clear()
                    break
                del buf[:i]
                if len(buf) < 4:
                    break
                n = buf[3] + 4
                if len(buf) < n:
                    break
                pkt = bytes(buf[:n])
                del buf[:n]
                with self.lock:
                    self._handle(pkt)

    def _handle(self, pkt: bytes):
        sid, inst, params = pkt[2], pkt[4], pkt[5:-1]
        if cks(pkt[2:-1]) != pkt[-1]:
            if sid in self.servos and self._baud_ok(self.servos[sid]):
                self._send(self._status(sid, E_CHECKSUM), 0)
            return
        if sid == 0xFE:
            if inst == 0x83:  # SYNC_WRITE
                addr, n = params[0], params[1]
                for k in range(2, len(params), n + 1):
                    tid = params[k]
                    if tid in self.servos and self._baud_ok(self.servos[tid]):
                        self._write(
                            self.servos[tid], tid, addr, params[k + 1 : k + 1 + n], "SYNC_WRITE"
                        )
            elif inst == 0x03:
                for tid, s in self.servos.items():
                    if self._baud_ok(s):
                        self._write(s, tid, params[0], params[1:], "WRITE")
            return
        s = self.servos.get(sid)
        if s is None or not self._baud_ok(s):
            return
        srl = s.get(16, 1)
        delay = s.get(5, 1) * 2e-6
        err = 0
        if inst == 0x01:
            self._send(self._status(sid, 0), delay)
        elif inst == 0x02:
            addr, n = params[0], params[1]
            self._advance()
            data = bytearray(s.get(addr + i, 1) for i in range(n))
            if s.jitter and addr == 36 and n >= 2:
                v = max(0, min(1023, s.get(36, 2) + self.rng.randint(-s.jitter, s.jitter)))
                data[0], data[1] = v & 0xFF, v >> 8
            if srl >= 1:
                self._send(self._status(sid, 0, data), delay)
        elif inst == 0x03:
            err = self._write(s, sid, params[0], params[1:], "WRITE")
            if srl >= 2:
                self._send(self._status(sid, err), delay)
        else:
            if srl >= 2:
                self._send(self._status(sid, E_INSTRUCTION), delay)

    def _write(self, s: Servo, sid, addr, data, how) -> int:
        self.log.append((how, sid, addr, bytes(data)))
        err = 0
        for i, b in enumerate(data):
            a = addr + i
            base = next((k for k, (n, _, _) in TABLE.items() if k <= a < k + n), None)
            if base is None or not TABLE[base][2]:
                err |= E_RANGE
                continue
            if a in (30, 31):
                continue
            s.regs[a] = b
        if addr <= 30 < addr + len(data) and addr <= 31 < addr + len(data):
            goal = data[30 - addr] | (data[31 - addr] << 8)
            cw, ccw = s.get(6, 2), s.get(8, 2)
            if cw == ccw == 0:
                pass
            elif not cw <= goal <= ccw:
                err |= E_ANGLE
            else:
                s.set(30, 2, goal)
                s.set(24, 1, 1)  # writing a goal turns torque on
        if addr <= 24 < addr + len(data):
            s.set(24, 1, data[24 - addr])
        return err

    def goals(self, sid):
        return [
            d[30 - a] | (d[31 - a] << 8)
            for how, i, a, d in self.log
            if i == sid and a <= 30 and a + len(d) >= 32
        ]


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", default="1-5")
    ap.add_argument("--link")
    ap.add_argument("--echo", action="store_true")
    ap.add_argument("--split", action="store_true")
    ap.add_argument("--garbage", action="store_true")
    ap.add_argument("--noise", action="store_true")
    ap.add_argument("--srl", type=int, default=2)
    ap.add_argument("--delay", type=int, default=0, help="return delay register")
    ap.add_argument("--model", type=str, default="", help="id:model,...")
    ap.add_argument("--limits", type=str, default="", help="id:cw:ccw,...")
    ap.add_argument("--short", type=int, default=0)
    ap.add_argument("--slow", type=float, default=1.0)
    ap.add_argument("--jitter", type=int, default=0)
    ap.add_argument("--baudreg", type=int, default=1)
    ap.add_argument("--time-scale", type=float, default=1.0)
    a = ap.parse_args()
    lo, _, hi = a.ids.partition("-")
    ids = range(int(lo), int(hi or lo) + 1)
    servos = {
        i: Servo(
            srl=a.srl,
            return_delay=a.delay,
            short_by=a.short,
            speed_factor=a.slow,
            jitter=a.jitter,
            baud_reg=a.baudreg,
        )
        for i in ids
    }
    for m in filter(None, a.model.split(",")):
        i, v = m.split(":")
        servos[int(i)].model = int(v)
    for m in filter(None, a.limits.split(",")):
        i, c, w = m.split(":")
        servos[int(i)].cw, servos[int(i)].ccw = int(c), int(w)
    p = Peer(
        servos,
        echo=a.echo,
        split=a.split,
        trailing_garbage=b"\x00\x13" if a.garbage else b"",
        leading_noise=b"\xff" if a.noise else b"",
        time_scale=a.time_scale,
    ).start(a.link)
    print(f"peer on {p.path}" + (f" ({a.link})" if a.link else ""), flush=True)
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        p.stop()
