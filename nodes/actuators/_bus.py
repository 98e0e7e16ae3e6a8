"""One Protocol 1.0 exchange at a time with the real dynamixel-sdk, checked, retried and classified.

Every request goes out through ``PacketHandler(1.0).txRxPacket``; what comes back is judged here
rather than trusted: a status packet must come from the servo asked and have the length the
request implies. dynamixel-sdk 4.1 does not check that — a late status packet of an earlier request
that arrives after its ``clearPort()`` is taken as the answer, and its ``ping`` / ``read2ByteTxRx``
then index a too-short parameter list and raise ``IndexError``. Here such a reply, and any exception
the SDK raises while parsing one, is a *corrupted reply*: retried, counted, and named if it
persists.

Each try ends in one of five outcomes (:class:`Try`): ``ok``, ``no_reply`` (not one byte, not even
within ``late_window_ms`` after the SDK gave up), ``late`` (a valid status packet that came after
the SDK's reply timeout — an adapter latency timer or a slow bus), ``corrupt`` (bad checksum,
incomplete, wrong length or ID, the servo's own checksum/instruction error bit) and ``error_bits``
(a status packet with a hardware alarm: overload, overheating, input voltage, angle limit, range —
never retried: the servo is telling the truth). Listening after a timeout also drains a late reply,
so it cannot be mistaken for the answer to the next request.
"""

from __future__ import annotations

import contextlib
import errno
import time
from dataclasses import dataclass, field

from nodes.contracts.dynamixel_protocol import (
    ERR_ANGLE,
    ERR_CHECKSUM,
    ERR_INSTRUCTION,
    ERR_OVERHEAT,
    ERR_OVERLOAD,
    ERR_RANGE,
    ERR_VOLTAGE,
    INST_PING,
    INST_READ,
    INST_WRITE,
    INSTRUCTION_NAMES,
    checksum,
    decode_error,
)
from stereograph.api import NodeError

from ._plan import ADDR_GOAL, REGISTER_NAMES

# what pyserial raises when the port itself fails: SerialException is an OSError; tcflush raises
# termios.error
try:
    import termios

    PORT_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # Windows
    PORT_ERRORS = (OSError,)

# s after a PING's reply to listen for a second one (two servos on one ID; ~0.1 ms at 1 Mbps)
TWIN_WINDOW_S = 0.005
HARD_ERRORS = ERR_VOLTAGE | ERR_ANGLE | ERR_OVERHEAT | ERR_RANGE | ERR_OVERLOAD
SOFT_ERRORS = ERR_CHECKSUM | ERR_INSTRUCTION  # the servo got a damaged packet: send it again
ADDR_TORQUE = 24


@dataclass
class Try:
    """The outcome of one request/reply exchange."""

    outcome: str  # ok | no_reply | late | corrupt | error_bits
    detail: str = ""
    late_ms: float | None = None
    error: int = 0
    echo_like: bool = False  # the status packet was the request byte for byte (an adapter's echo?)


@dataclass
class Exchange:
    """All tries of one request (a request is retried up to ``retries`` times)."""

    sid: int
    instruction: str
    what: str
    tries: list[Try] = field(default_factory=list)

    @property
    def kind(self) -> str:
        """``no_reply`` | ``late`` | ``corrupt`` | ``error_bits`` — what the failed tries say
        together."""
        kinds = {t.outcome for t in self.tries}
        # any corrupted try means noise; any late one, latency
        for k in ("error_bits", "corrupt", "late"):
            if k in kinds:
                return k
        return "no_reply"

    @property
    def late_ms(self) -> float | None:
        lates = [t.late_ms for t in self.tries if t.late_ms is not None]
        return max(lates) if lates else None

    @property
    def echo_like(self) -> bool:
        return any(t.echo_like for t in self.tries)

    @property
    def error(self) -> int:
        return next((t.error for t in self.tries if t.outcome == "error_bits"), 0)

    def summary(self) -> str:
        """``3 tries: no reply, late reply (61 ms), ...``"""
        words: list[list] = []  # [word, count]: repeats collapsed ("no reply x4")
        for t in self.tries:
            if t.outcome == "late":
                w = f"late reply ({t.late_ms:.0f} ms)"
            elif t.outcome == "corrupt":
                w = f"corrupted reply ({t.detail})"
            elif t.outcome == "error_bits":
                w = ", ".join(decode_error(t.error))
            else:
                w = "no reply"
            if words and (
                words[-1][0] == w or (t.outcome == "late" and words[-1][0].startswith("late"))
            ):
                words[-1][1] += 1
                if t.outcome == "late":
                    words[-1][0] = (
                        f"late replies ({min(x.late_ms for x in self.tries if x.late_ms):.0f}-"
                        f"{self.late_ms:.0f} ms)"
                    )
            else:
                words.append([w, 1])
        return f"{len(self.tries)} tries: " + "; ".join(
            w if n == 1 else f"{w} x{n}" for w, n in words
        )


class ServoFailure(Exception):
    """A request failed after the bounded retries, or a servo reported an alarm.

    ``exchange`` holds every try, so the message can name the cause (see ``_diagnose.py``).
    """

    def __init__(self, message: str, exchange: Exchange | None = None):
        super().__init__(message)
        self.exchange = exchange


class PortLost(ServoFailure):
    """The serial port itself stopped working (an adapter unplugged or reset, another program on the
    port): every read and write raises. Not a servo fault: nothing more can be sent on this port."""


class Bus:
    """dynamixel-sdk Protocol 1.0 calls with bounded, classified retries and a command log.

    Parameters
    ----------
    port_path : str
        Serial device (or the emulator's pty).
    baud : int
        Baud rate (bit/s).
    retries : int
        Re-sends after a missing, late or corrupted reply (count).
    t0 : float
        ``time.monotonic()`` of the run start, for the log's times.
    late_window_ms : float
        After the SDK's reply timeout, keep listening this long (ms) for a late status packet.
    reply_timeout_extra_ms : float
        Added to the SDK's reply timeout (ms): the setting for an adapter that answers late.
    """

    def __init__(
        self,
        port_path: str,
        baud: int,
        retries: int,
        t0: float,
        late_window_ms: float = 250.0,
        reply_timeout_extra_ms: float = 0.0,
    ):
        from dynamixel_sdk import PacketHandler

        self.port_path, self.baud, self.retries, self.t0 = port_path, baud, retries, t0
        self.late_window_s = late_window_ms / 1000.0
        self.port = _port_class()(port_path)
        self.port.extra_ms = float(reply_timeout_extra_ms)
        self.ph = PacketHandler(1.0)
        self.commands: list[dict] = []
        self.events: list[str] = []
        self.n_retries = 0
        self.waypoint = "setup"
        self.answered: dict[int, set[str]] = {}  # servo -> instructions it has answered correctly
        self.status_level: dict[int, int] = {}  # servo -> status return level read at setup
        # Servos pinged, identified and whose own CW/CCW limits (units) were read on this open port;
        # a bus kept open across the cycles of a run skips that setup until a fault clears it.
        self.limits: dict[int, tuple[int, int]] = {}
        self.n_plans = 0  # plans started on this bus (begin)
        # the adapter echoes what it sends (seen once: a copy of a request, then a reply)
        self.echoes = False
        # why the port stopped working (PortLost), until it is opened again
        self.lost: str | None = None
        # IDs whose PING got two status packets: two servos share the ID
        self.twins: set[int] = set()

    def begin(self, t0: float) -> None:
        """Start the log of a new plan on a bus kept open (``ctx.resource``): commands, events and
        retries are per plan; what was learnt about the servos (``limits``) is kept."""
        self.t0 = t0
        self.n_plans += 1
        self.commands, self.events = [], []
        self.n_retries = 0
        self.waypoint = "setup"

    @property
    def is_open(self) -> bool:
        return bool(getattr(self.port, "is_open", False))

    # ------------------------------------------------------------------------- port
    def open(self) -> None:
        self.lost = None
        try:
            ok = self.port.openPort()
        except Exception as e:  # noqa: BLE001 - pyserial raises SerialException subclasses of OSError
            err = getattr(e, "errno", None)
            text = str(e)
            if err == errno.EACCES or "Permission denied" in text:
                hint = (
                    "add yourself to the dialout group (sudo usermod -aG dialout $USER, "
                    "then log in again) "
                    f"or check the permissions of {self.port_path}."
                )
            elif err == errno.ENOENT or "No such file" in text or "could not open" in text:
                hint = (
                    "plug in the USB2Dynamixel / U2D2 and check the device name (ls "
                    "/dev/ttyUSB* /dev/ttyACM*); "
                    "use port: sim to run on the emulator."
                )
            else:
                hint = "check the adapter and that no other program has the port open."
            raise NodeError(
                f"cannot open serial port {self.port_path}: {text}", hint=hint, lasting=True
            ) from None
        if not ok or not self.port.setBaudRate(self.baud):
            with contextlib.suppress(Exception):
                self.port.closePort()
            raise NodeError(
                f"cannot set serial port {self.port_path} to {self.baud} baud.",
                hint="use a rate the SDK supports (AX-12A default 1000000; also 57600, "
                "115200, ...).",
                lasting=True,
            )

    def close(self) -> None:
        """Close the port and forget the setup (a reopened port is checked again); never raises."""
        self.limits.clear()
        self.twins.clear()
        self.answered.clear()
        self.status_level.clear()
        with contextlib.suppress(Exception):
            self.port.closePort()

    def recover(self) -> None:
        """Make the port usable after an exchange was cut short (an exception, Ctrl-C): clear the
        SDK's busy flag and drain a reply still on its way, so it is not read as the next answer."""
        self.port.is_using = False
        with contextlib.suppress(Exception):
            self._drain(0.04)

    @contextlib.contextmanager
    def _port_io(self):
        """Turn a failure of the port itself (pyserial's SerialException / OSError, termios.error)
        into :class:`PortLost`; once lost, fail at once without touching the port again."""
        if self.lost is not None:
            raise PortLost(f"the serial port {self.port_path} stopped working ({self.lost})")
        try:
            yield
        except PORT_ERRORS as e:
            self.port.is_using = False
            # termios.error's str is its args tuple: "(5, 'Input/output error')"
            words = e.args[1] if len(e.args) == 2 and isinstance(e.args[1], str) else str(e)
            self.lost = words or type(e).__name__
            raise PortLost(
                f"the serial port {self.port_path} stopped working ({self.lost})"
            ) from None

    def _t(self) -> float:
        return round(time.monotonic() - self.t0, 6)

    # ------------------------------------------------------------------------- one exchange
    def _drain(self, seconds: float) -> bytes:
        """Read whatever arrives during ``seconds``."""
        got = bytearray()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            got += bytes(self.port.readPort(64))
            time.sleep(0.0005)
        return bytes(got)

    def _listen_late(
        self, sid: int, t_sent: float, n_data: int, window_s: float | None = None
    ) -> tuple[float | None, int]:
        """After a timeout: the delay (ms) of a status packet from ``sid`` that arrives within the
        late window (or ``window_s``; None if none), and how many bytes came at all."""
        got = bytearray()
        want = 6 + n_data
        end = t_sent + (self.late_window_s if window_s is None else window_s)
        t_byte = 0.0
        while time.monotonic() < end:
            chunk = self.port.readPort(64)
            if not chunk and got and time.monotonic() - t_byte > 0.01:
                break  # bytes came, then 10 ms of silence: garbage, not a late packet on its way
            if chunk:
                t_byte = time.monotonic()
                got += bytes(chunk)
                i = got.find(b"\xff\xff")
                if i >= 0 and len(got) >= i + want:
                    pkt = got[i : i + want]
                    if pkt[2] == sid and pkt[3] == n_data + 2 and checksum(pkt[2:-1]) == pkt[-1]:
                        late_ms = (time.monotonic() - t_sent) * 1000.0
                        self._drain(0.002)  # anything glued behind it
                        return late_ms, len(got)
            else:
                time.sleep(0.0005)
        return None, len(got)

    def _once(self, sid: int, inst: int, params: list[int], n_data: int) -> tuple[Try, list[int]]:
        with self._port_io():
            return self._once_io(sid, inst, params, n_data)

    def _once_io(
        self, sid: int, inst: int, params: list[int], n_data: int
    ) -> tuple[Try, list[int]]:
        from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS

        tx = [0] * (6 + len(params))
        tx[2], tx[3], tx[4] = sid, len(params) + 2, inst
        tx[5 : 5 + len(params)] = params
        t_sent = time.monotonic()
        try:
            rx, comm, err = self.ph.txRxPacket(self.port, tx)
        except PORT_ERRORS:
            raise  # the port itself, not the reply: PortLost (_once)
        except Exception as e:  # noqa: BLE001 - the SDK choking on a malformed reply is a corrupted reply
            self.port.is_using = False
            self._drain(0.005)
            return Try("corrupt", f"the SDK could not parse it: {type(e).__name__}"), []
        echo_like = False
        if comm == COMM_SUCCESS and list(rx) == tx:
            rx, comm, err, echo_like = self._after_echo(rx, comm, err, n_data)
        if comm == COMM_SUCCESS:
            if len(rx) != 6 + n_data or rx[2] != sid:
                # typically the late reply of an earlier request, arriving after the SDK's
                # clearPort()
                self._drain(0.005)
                return Try(
                    "corrupt",
                    f"{len(rx)} bytes from ID {rx[2] if len(rx) > 2 else '?'}, expected "
                    f"{6 + n_data} from ID {sid}",
                ), []
            if err & HARD_ERRORS:
                return (
                    Try("error_bits", ", ".join(decode_error(err)), error=err, echo_like=echo_like),
                    list(rx[5 : 5 + n_data]),
                )
            if err & SOFT_ERRORS:
                return Try(
                    "corrupt",
                    f"the servo reported {', '.join(decode_error(err & SOFT_ERRORS))}: "
                    f"it received a damaged packet",
                ), []
            return Try("ok"), list(rx[5 : 5 + n_data])
        if comm == COMM_RX_TIMEOUT:
            late_ms, n_bytes = self._listen_late(sid, t_sent, n_data)
            if late_ms is not None:
                return Try("late", f"arrived after {late_ms:.0f} ms", late_ms=late_ms), []
            return (Try("no_reply"), []) if n_bytes == 0 else (Try("corrupt", "garbage bytes"), [])
        if comm == COMM_RX_CORRUPT:  # a whole packet with a bad checksum, or a truncated one
            self._drain(0.005)
            return Try("corrupt", "bad checksum or incomplete"), []
        self.port.is_using = False
        return Try("corrupt", self.ph.getTxRxResult(comm)), []

    def _after_echo(
        self, rx: list[int], comm: int, err: int, n_data: int
    ) -> tuple[list[int], int, int, bool]:
        """The SDK took a copy of the request as its reply: a half-duplex adapter without echo
        cancellation hears its own bytes on the line (a PING's echo reads as an input-voltage alarm,
        a READ's as an angle-limit alarm). The servo's reply follows the echo: read it. If nothing
        follows on a bus not yet seen echoing, the packet was the servo's own (a reply can equal
        its request byte for byte) and stands, flagged (the last item) as possibly an echo after
        all."""
        from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS

        self.port.setPacketTimeout(6 + n_data)
        rx2, comm2 = self.ph.rxPacket(self.port)
        if comm2 == COMM_RX_TIMEOUT and not self.echoes:
            return rx, comm, err, True
        if not self.echoes:
            self.echoes = True
            self.events.append(
                f"{self._t():.3f}s {self.waypoint}: the adapter on {self.port_path} echoes every "
                f"packet it sends (no echo cancellation); the echoes are skipped"
            )
        return rx2, comm2, (rx2[4] if comm2 == COMM_SUCCESS and len(rx2) > 4 else 0), False

    def request(self, sid: int, inst: int, params: list[int], n_data: int, what: str) -> list[int]:
        """Send one instruction and return the reply's parameters, retrying missing, late and
        corrupted replies.

        Raises
        ------
        ServoFailure
            After ``retries + 1`` tries without a valid reply, or at once on a hardware alarm bit.
        """
        ex = Exchange(sid, INSTRUCTION_NAMES.get(inst, str(inst)), what)
        for attempt in range(self.retries + 1):
            t, data = self._once(sid, inst, params, n_data)
            ex.tries.append(t)
            if t.outcome == "ok":
                self.answered.setdefault(sid, set()).add(ex.instruction)
                return data
            if t.outcome == "error_bits":
                self.answered.setdefault(sid, set()).add(ex.instruction)
                raise ServoFailure(f"servo {sid} reported {t.detail} during {what}", ex)
            if attempt < self.retries:
                self.n_retries += 1
                self.events.append(
                    f"{self._t():.3f}s {self.waypoint}: {what} on servo {sid}: "
                    f"{_TRY_WORDS[t.outcome]}{' (' + t.detail + ')' if t.detail else ''}; retry "
                    f"{attempt + 1}/{self.retries}"
                )
        raise ServoFailure(
            f"servo {sid} did not answer {what} correctly after {len(ex.tries)} tries "
            f"({ex.summary()})",
            ex,
        )

    # ------------------------------------------------------------------------- instructions
    def ping(self, sid: int) -> None:
        """A lone PING. (The SDK's Protocol 1 ``ping`` also READs the model number; kept apart here
        so that a lost READ reply is not blamed on the PING, nor the other way round.)"""
        self.request(sid, INST_PING, [], 0, "ping")
        self._twin_reply(sid)

    def _twin_reply(self, sid: int) -> None:
        """After a good reply to a PING: does a second status packet from ``sid`` follow within a
        few ms? Then two servos share the ID (set to it by mistake, a spare left on the bus) and
        answer one after the other (different return delay times); a goal for that ID would move
        both. dynamixel-sdk reads only the first packet and its next ``clearPort()`` discards the
        second: nothing else would notice."""
        with self._port_io():
            late_ms, _ = self._listen_late(sid, time.monotonic(), 0, window_s=TWIN_WINDOW_S)
        if late_ms is not None:
            self.twins.add(sid)

    def answers_ping(self, sid: int) -> bool:
        """One PING, no retry, never raises: whether ``sid`` answers at all (a diagnosis)."""
        return self.probe_ping(sid).outcome in ("ok", "error_bits")

    def probe_ping(self, sid: int) -> Try:
        """One PING, no retry, never raises: what came back (a diagnosis)."""
        try:
            t = self._once(sid, INST_PING, [], 0)[0]
            if t.outcome == "ok":
                self._twin_reply(sid)
            return t
        except PortLost:
            raise
        except Exception as e:  # noqa: BLE001 - a diagnosis must not fail
            self.port.is_using = False
            return Try("corrupt", f"{type(e).__name__}")

    def read(self, sid: int, addr: int, n: int, what: str) -> int:
        """Read ``n`` bytes (1, 2 or 4) at ``addr`` as one little-endian value."""
        data = self.request(sid, INST_READ, [addr, n], n, what)
        return int.from_bytes(bytes(data), "little")

    def write_checked(self, sid: int, addr: int, data: list[int], what: str) -> None:
        """WRITE that expects a reply (status return level 2)."""
        self.request(sid, INST_WRITE, [addr, *data], 0, what)

    def sync_write(self, data: dict[int, tuple[int, int]]) -> None:
        from dynamixel_sdk import DXL_HIBYTE, DXL_LOBYTE, GroupSyncWrite

        g = GroupSyncWrite(self.port, self.ph, ADDR_GOAL, 4)
        for sid, (goal, speed) in data.items():
            g.addParam(
                sid, [DXL_LOBYTE(goal), DXL_HIBYTE(goal), DXL_LOBYTE(speed), DXL_HIBYTE(speed)]
            )
            self._log("SYNC_WRITE", sid, 30, goal)
            self._log("SYNC_WRITE", sid, 32, speed)
        with self._port_io():
            comm = g.txPacket()
        if comm != 0:
            raise ServoFailure(
                f"sync write failed on {self.port_path}: {self.ph.getTxRxResult(comm)}"
            )

    def _log(self, instruction: str, sid: int, addr: int, value: int) -> None:
        self.commands.append(
            {
                "t_s": self._t(),
                "waypoint": self.waypoint,
                "instruction": instruction,
                "id": int(sid),
                "address": addr,
                "register": REGISTER_NAMES.get(addr, str(addr)),
                "value": int(value),
            }
        )

    def torque_off(self, ids: list[int]) -> list[str]:
        """Torque off everywhere: one broadcast (needs no reply), then each servo once more and read
        back where it answers READs; never raises. Returns notes on servos not confirmed off."""
        from dynamixel_sdk import BROADCAST_ID

        lost = [f"torque could not be turned off: the serial port {self.port_path} stopped working"]
        if self.lost is not None:
            return lost
        self.recover()
        notes = []
        with contextlib.suppress(Exception), self._port_io():
            self._log("WRITE", BROADCAST_ID, ADDR_TORQUE, 0)
            self.ph.write1ByteTxOnly(self.port, BROADCAST_ID, ADDR_TORQUE, 0)
        for sid in ids:
            if self.lost is not None:
                return lost
            try:
                self._log("WRITE", sid, ADDR_TORQUE, 0)
                t_sent = time.monotonic()
                with self._port_io():
                    self.ph.write1ByteTxOnly(self.port, sid, ADDR_TORQUE, 0)
                self.port.is_using = False
                if self.status_level.get(sid, 2) >= 2:
                    # It answers WRITEs too (the AX-12's default): take that status packet off the
                    # line, or the read-back below would read it as its own reply and call a healthy
                    # servo faulty.
                    self._listen_late(sid, t_sent, 0, window_s=min(self.late_window_s, 0.05))
                t, data = self._once(sid, INST_READ, [ADDR_TORQUE, 1], 1)
                if t.outcome not in ("ok", "error_bits"):
                    notes.append(
                        f"servo {sid}: not confirmed ({_TRY_WORDS[t.outcome]} to the read-back)"
                    )
                elif data and data[0] != 0:
                    notes.append(f"servo {sid}: torque still on")
            except Exception as e:  # noqa: BLE001 - best effort while failing
                self.port.is_using = False
                notes.append(f"servo {sid}: {e}")
        return lost if self.lost is not None else notes

    def torque_state(self, ids: list[int]) -> dict[int, int | None]:
        """Torque enable (0/1) of each servo, None where it cannot be read; one try each, never
        raises."""
        out: dict[int, int | None] = {}
        for sid in ids:
            if self.lost is not None:
                out[sid] = None
                continue
            try:
                t, data = self._once(sid, INST_READ, [ADDR_TORQUE, 1], 1)
                out[sid] = data[0] if t.outcome in ("ok", "error_bits") and data else None
            except Exception:  # noqa: BLE001 - a diagnosis must not fail
                self.port.is_using = False
                out[sid] = None
        return out


def _port_class():
    """dynamixel-sdk's PortHandler whose reply timeout can be lengthened (``extra_ms``)."""
    from dynamixel_sdk import PortHandler

    class Port(PortHandler):
        extra_ms = 0.0

        def setPacketTimeout(self, packet_length):  # noqa: N802 - the SDK's name
            super().setPacketTimeout(packet_length)
            self.packet_timeout += self.extra_ms

    return Port


_TRY_WORDS = {
    "ok": "ok",
    "no_reply": "no status packet",
    "late": "late status packet",
    "corrupt": "corrupted status packet",
    "error_bits": "alarm bits",
}
