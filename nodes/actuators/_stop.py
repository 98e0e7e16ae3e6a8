"""Ending a motion safely when the run is interrupted (Ctrl-C, SIGTERM) or something unexpected
fails.

The arm is mid-way between two checked waypoints; the servos keep going to their last goal unless
told otherwise. Three ways to end (``on_interrupt``):

``hold``        every servo's goal := its present position (torque stays on): the arm stops where
                it is and holds the object.
``rest``        the arm joints go to the arm model's home pose at ``rest_speed_deg_s``, the gripper
                holds where it is (a held ball is not dropped); a second Ctrl-C during that move
                holds instead.
``torque_off``  torque off on every servo: the arm goes limp (it may sag or fall).

Every goal written here is clamped into the joint limits, like every other goal. The hold itself
(a few reads and one sync write, tens of ms) runs with Ctrl-C ignored so that it cannot be cut in
half; SIGINT and SIGTERM, while the arm moves, raise a ``KeyboardInterrupt`` even where the process
inherited them ignored, unless someone else (the engine) already handles them.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time

from ._bus import Bus, ServoFailure
from ._plan import move_seconds

ADDR_POSITION = 36


class Terminated(KeyboardInterrupt):
    """SIGTERM received while the arm moved."""


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def stop_signals_as_interrupt():
    """While the arm moves, SIGINT and SIGTERM raise a ``KeyboardInterrupt`` in the main thread,
    even where the process inherited them ignored or blocked (a job started with ``&`` by a script)
    and nobody else handles them: the default action would kill the process mid-motion, or do
    nothing, leaving the arm going to its last goal with the port open. Handlers someone installed
    are kept."""
    if not _main_thread():
        yield
        return
    prev = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    if prev[signal.SIGTERM] in (signal.SIG_DFL, signal.SIG_IGN, None):

        def _raise(signum, frame):
            raise Terminated("SIGTERM")

        signal.signal(signal.SIGTERM, _raise)
    if prev[signal.SIGINT] in (signal.SIG_IGN, None):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, set(prev))
    try:
        yield
    finally:
        for s, h in prev.items():
            if h is not None:
                signal.signal(s, h)


@contextlib.contextmanager
def uninterruptible():
    """Ignore SIGINT / SIGTERM for the duration (a bounded stop sequence that must not be cut in
    half)."""
    if not _main_thread():
        yield
        return
    prev = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s in prev:
        signal.signal(s, signal.SIG_IGN)
    try:
        yield
    finally:
        for s, h in prev.items():
            signal.signal(s, h)


def _clamp(goal: int, lim: tuple[int, int]) -> int:
    return max(lim[0], min(lim[1], int(goal)))


def hold(bus: Bus, ids: list[int], limits: dict[str, tuple[int, int]], speed_units: int) -> dict:
    """Goal := present position on every servo that answers; returns what was done."""
    with uninterruptible():
        bus.recover()
        bus.waypoint = "stop: hold"
        goals, silent = {}, []
        for sid in ids:
            try:
                pos = bus.read(sid, ADDR_POSITION, 2, "read of the present position")
            except ServoFailure:
                silent.append(sid)
                continue
            goals[sid] = _clamp(pos, limits[str(sid)])
        if goals:
            bus.sync_write({sid: (g, speed_units) for sid, g in goals.items()})
    detail = f"held at the present positions {goals} (units) with torque on"
    if silent:
        detail += (
            f"; servos {silent} did not answer and continue to their last goal (within limits)"
        )
    return {
        "action": "hold",
        "goals": {str(k): v for k, v in goals.items()},
        "silent": silent,
        "detail": detail,
    }


def rest(
    bus: Bus,
    ids: list[int],
    limits: dict[str, tuple[int, int]],
    rest_units: dict[int, int],
    speed_units: int,
    tolerance_units: int,
) -> dict:
    """Arm joints to the rest pose, the others held; a second interrupt during the move holds
    instead. Gives up (and holds) after 1.5 x the expected move time + 2 s."""
    with uninterruptible():
        bus.recover()
        bus.waypoint = "stop: rest"
        present = {
            sid: bus.read(sid, ADDR_POSITION, 2, "read of the present position") for sid in ids
        }
        # the gripper keeps what it holds
        goals = {sid: _clamp(rest_units.get(sid, present[sid]), limits[str(sid)]) for sid in ids}
        data = {sid: (g, speed_units) for sid, g in goals.items()}
        bus.sync_write(data)
    timeout_s = 1.5 * move_seconds(present, data) + 2.0
    t0 = time.monotonic()
    try:
        with stop_signals_as_interrupt():
            return _wait_rest(bus, ids, limits, goals, speed_units, tolerance_units, t0, timeout_s)
    except KeyboardInterrupt:
        out = hold(bus, ids, limits, speed_units)
        out["detail"] = "interrupted again on the way to the rest pose; " + out["detail"]
        return out


def _wait_rest(bus, ids, limits, goals, speed_units, tolerance_units, t0, timeout_s) -> dict:
    while True:
        pos = {
            sid: bus.read(sid, ADDR_POSITION, 2, "read of the present position") for sid in goals
        }
        if all(abs(pos[s] - goals[s]) <= tolerance_units for s in goals):
            return {
                "action": "rest",
                "goals": {str(k): v for k, v in goals.items()},
                "detail": f"moved to the rest pose {goals} (units) and holding it with torque on",
            }
        if time.monotonic() - t0 > timeout_s:
            out = hold(bus, ids, limits, speed_units)
            out["detail"] = (
                f"did not reach the rest pose within {timeout_s:.1f} s; " + out["detail"]
            )
            return out
        time.sleep(0.02)
