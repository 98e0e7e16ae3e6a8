"""What a servo fault means, in words a person can act on: the message head and the fix.

A failed exchange (:class:`~nodes.actuators._bus.Exchange`) says what came back on each try; the
cause follows from that, not from the request that happened to fail:

========================
=========================================================================== no reply (at ping)
cable, power, ID or baud rate no reply (while moving)   a connector that came loose with the motion,
a supply that sags under load late reply                the USB adapter's latency timer or a slow
bus (the SDK waits ~34 ms) corrupted replies         electrical noise / a bad data line
alarm bits                named: overload (load, obstruction), overheating, input voltage, angle
limit PING yes, READ no         WRITE answered too -> READ replies are lost (not a setting);
                          nothing but PING answered -> status return level 0
========================
===========================================================================
"""

from __future__ import annotations

from nodes.contracts.dynamixel_protocol import (
    ERR_ANGLE,
    ERR_OVERHEAT,
    ERR_OVERLOAD,
    ERR_RANGE,
    ERR_VOLTAGE,
    decode_error,
)

from ._bus import Bus, PortLost, ServoFailure

ADDR_STATUS_RETURN_LEVEL, ADDR_LED = 16, 25

ALARM_HINTS = {
    ERR_OVERLOAD: "overload: the joint is blocked or carries more than the servo can hold — an "
    "obstruction in its "
    "path, the arm or gripper pressing on the table or the object, a heavy load, or a gear that "
    "binds. Clear the path, check with torque off that the joint turns freely by hand, lighten the "
    "load or lower the speed; the AX-12A turns its torque off on this alarm, so turn the power off "
    "and on again once the joint is free.",
    ERR_OVERHEAT: "overheating: the servo is above its temperature limit (address 11, 70 C by "
    "default) — it has "
    "been holding too much load for too long. Let it cool with torque off, then reduce the load "
    "or the time it holds.",
    ERR_VOLTAGE: "input voltage: the supply at the servo is outside its limits (addresses 12/13; "
    "the AX-12A wants "
    "9-12 V). Measure the voltage at the servo while it moves: a weak supply, a too-thin "
    "cable or a "
    "long daisy chain makes it sag.",
    ERR_ANGLE: "angle limit: a goal outside the servo's own CW/CCW angle limits (addresses 6/8) "
    "was written, "
    "possibly by an earlier program (the bit stays set until a valid goal). Compare the "
    "limits with "
    "the arm model's joint limits and zero offsets. To clear the bit, power the servos "
    "off and on, or "
    "write the servo's present position (address 36) to its goal position (address 30) "
    "with Dynamixel "
    "Wizard / RoboPlus.",
    ERR_RANGE: "range: the servo received a value outside a register's range. Re-plan from the "
    "same arm model; "
    "if it persists, report it.",
}
LATE_HINT = (
    "a late reply means the USB serial adapter holds bytes back (its latency timer) or "
    "the bus is slow. "
    "On Linux set the FTDI latency timer to 1 ms: `echo 1 | sudo tee "
    "/sys/bus/usb-serial/devices/ttyUSB0/latency_timer` (or `setserial /dev/ttyUSB0 "
    "low_latency`); on "
    "Windows: Device Manager > the port > Advanced > Latency Timer = 1. Check the "
    "servos' return delay "
    "time (address 5; 0-250 = 0-500 us is fine). If it cannot be changed, let the "
    "actuator wait longer: "
    "--set act.reply_timeout_extra_ms=<the delay>."
)
NOISE_HINT = (
    "corrupted replies are electrical noise or a bad data line: reseat or replace the "
    "daisy-chain cables "
    "(a loose pin garbles bits), keep them short and away from motor power leads, make "
    "sure all servos "
    "and the adapter share ground; a lower baud rate (on every servo and the port) is "
    "more robust. More "
    "retries only hide it."
)
CABLE_HINT = (
    "check servo {sid}'s cable in the daisy chain and the 9-12 V supply, that its ID is "
    "{sid} and its baud "
    "rate {baud} (set both with Dynamixel Wizard / RoboPlus)."
)
MOTION_LOSS_HINT = (
    "a servo that answered before the motion and stopped answering during it: a connector that "
    "came loose as the arm moved, or a supply that sags under load and resets the servo. Check the "
    "daisy-chain connectors at the moving joints and the 9-12 V supply's current rating."
)
SRL0_HINT = (
    "set servo {sid}'s status return level to 1 or 2 (Dynamixel Wizard / RoboPlus, or a "
    "WRITE of 1 to "
    "address 16): the actuator must read positions back to move safely."
)


PORT_LOST_HINT = (
    "the USB2Dynamixel / U2D2 was unplugged, lost power or was reset (a loose USB cable "
    "or connector, "
    "an unpowered hub, a USB over-current or a reset: `dmesg | tail` says which), or "
    "another program "
    "(Dynamixel Wizard, another run) opened the same port. Reconnect it (it may come back under "
    "another name: ls /dev/ttyUSB* /dev/ttyACM*), close the other program, and run again."
)
PORT_LOST_MOVING_HINT = (
    "nothing can be sent to the servos any more, not even torque off: switch off their 9-12 V "
    "supply now if the arm must not stay powered in that pose (it then drops what it holds). "
    + PORT_LOST_HINT[0].upper()
    + PORT_LOST_HINT[1:]
)


def alarm_words(error: int) -> str:
    return ", ".join(
        decode_error(error & (ERR_OVERLOAD | ERR_OVERHEAT | ERR_VOLTAGE | ERR_ANGLE | ERR_RANGE))
    )


def alarm_hint(error: int) -> str:
    return " ".join(h for bit, h in ALARM_HINTS.items() if error & bit)


def head_and_hint(e: ServoFailure, *, moving: bool, baud: int) -> tuple[str, str]:
    """The cause (one clause) and the fix for a failed exchange."""
    ex = e.exchange
    if isinstance(e, PortLost):
        return str(e), PORT_LOST_MOVING_HINT if moving else PORT_LOST_HINT
    if ex is None:
        return str(e), "check the adapter and the cables."
    sid, kind = ex.sid, ex.kind
    if kind == "error_bits":
        return (
            f"servo {sid} reports {alarm_words(ex.error)} (alarm bits in its status "
            f"packet to the {ex.what})",
            alarm_hint(ex.error),
        )
    if kind == "late":
        return (
            f"servo {sid} answers late: its status packet to the {ex.what} came "
            f"{ex.late_ms:.0f} ms after the "
            f"request, after dynamixel-sdk had stopped waiting (~34 ms at 1 Mbps) ({ex.summary()})",
            LATE_HINT,
        )
    if kind == "corrupt":
        return (
            f"servo {sid}'s replies to the {ex.what} arrive corrupted ({ex.summary()})",
            NOISE_HINT
            + f" If servo {sid}'s replies alone arrive corrupted, two servos may share ID "
            f"{sid} (their "
            f"status packets collide): connect them one at a time and check their IDs.",
        )
    if moving:
        return f"servo {sid} stopped answering ({ex.what}: {ex.summary()})", MOTION_LOSS_HINT
    return (
        f"servo ID {sid} did not answer a {ex.what} ({ex.summary()}; nothing came back, "
        "not even late)",
        CABLE_HINT.format(sid=sid, baud=baud),
    )


def silent_bus(port: str, ids: list[int], baud: int, echoed: bool = False) -> tuple[str, str]:
    """No servo of the arm answers a PING: the bus, not one servo. ``echoed``: each PING came back
    as itself, byte for byte, and nothing after it (an adapter without echo cancellation)."""
    what = (
        "each came back byte for byte as sent, the adapter's echo, and nothing after it"
        if echoed
        else "nothing came back, not even late"
    )
    return (
        f"no servo answers on {port} at {baud} baud (PING to IDs "
        f"{', '.join(map(str, ids))}: {what})",
        "check that the servos' 9-12 V supply is on, that the adapter's cable reaches "
        "the first servo (a "
        f"USB2Dynamixel's switch on TTL for AX-12s), that the servos run at {baud} baud "
        "and that their IDs are "
        "the arm model's (ik.arm servos' id; Dynamixel Wizard / RoboPlus scans every rate and ID).",
    )


def missing_servo(
    bus: Bus, sid: int, ids: list[int], e: ServoFailure, baud: int
) -> tuple[str, str]:
    """Servo ``sid`` did not answer a PING while others of the arm do: also say which IDs answer on
    the bus (one PING each to 0 .. the arm's highest ID + 8, on this failure path only: ~35 ms per
    silent ID at 1 Mbps). A servo set to another ID -- a new one still at the factory ID 1, one
    renumbered by mistake -- then shows as an ID that answers but is not the arm model's."""
    head, hint = head_and_hint(e, moving=False, baud=baud)
    if e.exchange is None or e.exchange.kind != "no_reply":
        return head, hint
    answering = [i for i in range(min(253, max(ids) + 8) + 1) if i != sid and bus.answers_ping(i)]
    foreign = [i for i in answering if i not in ids]
    head += (
        f"; on {bus.port_path} IDs {', '.join(map(str, answering)) or 'none'} answer "
        f"(0-{min(253, max(ids) + 8)} "
        "pinged)"
    )
    twins = sorted(bus.twins & set(answering))
    if twins:
        head += "; " + "; ".join(f"two servos answer at ID {t}" for t in twins)
        hint = (
            f"if one of the two servos at ID {twins[0]} is the servo the arm model calls "
            f"{sid}, connect it alone "
            f"and set its ID to {sid} (Dynamixel Wizard / RoboPlus). " + hint
        )
    if foreign:
        which = ", ".join(map(str, foreign))
        head += (
            f": ID{'s' if len(foreign) > 1 else ''} {which} "
            f"answer{'' if len(foreign) > 1 else 's'} but "
            f"{'are' if len(foreign) > 1 else 'is'} not in the arm model"
        )
        hint = (
            f"if ID {foreign[0]} is the servo the arm model calls {sid}, set its ID to "
            f"{sid} (Dynamixel Wizard / "
            f"RoboPlus), or give the arm model the IDs your servos have (ik.arm servos' id). "
            + hint
        )
    return head, hint


def twin_id(port: str, sid: int, ids: list[int]) -> tuple[str, str]:
    """Two status packets came back to one PING of ``sid``: two servos share the ID."""
    return (
        f"two servos answer at ID {sid} on {port} (each PING got two status packets, one "
        "after the other): a "
        f"goal for ID {sid} would move both of them",
        "connect the servos one at a time and give each its own ID (Dynamixel Wizard / "
        "RoboPlus): the arm model "
        f"has IDs {', '.join(map(str, ids))} (ik.arm servos' id); take any servo that is "
        "not the arm's off the "
        f"bus.",
    )


def after_ping(bus: Bus, sid: int, e: ServoFailure, baud: int) -> tuple[str, str]:
    """A servo answered PING, then a READ failed. Tell a lost READ reply from status return level 0.

    With status return level 0 a servo answers PING only; with 1 it answers READ too; with 2 also
    WRITE. So: a later READ that works -> the replies were lost intermittently; a WRITE (of 0 to
    the LED, which moves nothing) that is answered -> the servo replies, but not to READ; nothing
    answered -> status return level 0.
    """
    ex = e.exchange
    if ex is None or ex.kind != "no_reply":
        return head_and_hint(e, moving=False, baud=baud)
    try:
        level = bus.read(sid, ADDR_STATUS_RETURN_LEVEL, 1, "read of the status return level")
    except ServoFailure:
        level = None
    if level is not None:
        return (
            f"servo {sid} answers PING but lost its replies to {len(ex.tries)} READs in a "
            f"row ({ex.what}; "
            f"a later READ worked: status return level {level}) — replies to READ are "
            "lost intermittently",
            NOISE_HINT,
        )
    try:
        bus.write_checked(sid, ADDR_LED, [0], "write of 0 to the LED")
        bus._log("WRITE", sid, ADDR_LED, 0)
        wrote = True
    except ServoFailure:
        wrote = False
    if wrote:
        return (
            f"servo {sid} answers PING and WRITE but not READ ({ex.summary()}): it does "
            "send status packets, "
            f"so its status return level is not 0; its READ replies are lost",
            NOISE_HINT,
        )
    return (
        f"servo ID {sid} answers a PING but neither READ nor WRITE ({ex.summary()}; "
        "nothing came back, not even "
        f"late): its status return level (address 16) is 0, so its position cannot be read back",
        SRL0_HINT.format(sid=sid),
    )


def torque_report(bus: Bus, ids: list[int], turn_off: bool) -> tuple[str, bool]:
    """After a failure before any goal was written: whether torque is still on (from an earlier run
    or another program), and, if ``turn_off``, turn it off. Returns (sentence, torque left on)."""
    if bus.lost is not None:
        return (
            f"Torque: unknown on {ids} (the port stopped working; it is as the servos had "
            "it before this run).",
            False,
        )
    state = bus.torque_state(ids)
    on = [s for s, v in state.items() if v]
    unknown = [s for s, v in state.items() if v is None]
    if turn_off and (on or unknown):
        notes = bus.torque_off(ids)
        text = (
            f"Torque was turned off on servos {ids} (torque_off_on_failure: true; it had "
            "been on on "
            f"{on or 'none'}{', unknown on ' + str(unknown) if unknown else ''}; the arm may sag)"
            + (f" ({'; '.join(notes)})" if notes else "")
            + "."
        )
        return text, bool(notes)
    parts = []
    if on:
        # a port kept open across --repeat cycles
        by = (
            "by this run's earlier picks"
            if bus.n_plans > 1
            else "by an earlier run or another program"
        )
        parts.append(
            f"still ON on servos {on} (left on {by}: those joints hold their pose and stay powered)"
        )
    off = [s for s, v in state.items() if v == 0]
    if off:
        parts.append(f"off on {off}")
    if unknown:
        parts.append(f"unknown on {unknown} (no reply)")
    return ("Torque: " + "; ".join(parts) + ".") if parts else "", bool(on or unknown)
