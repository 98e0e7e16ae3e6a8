"""The serial port vanishes under the actuator (a USB2Dynamixel unplugged, a USB reset, a hub that
loses power): on a peer whose pseudo-terminal closes mid-run (``tests/dxl_peer.py``), not the
emulator.

pyserial then raises ``SerialException`` ("device reports readiness to read but returned no data")
or ``OSError`` (EIO) from every read and write. That is neither a servo fault nor a bug in the node:
the run must stop with a NodeError naming the port and the fix, must not claim to have turned
torque off (nothing can be sent any more), and must keep the log of what was sent.
"""

import os
import threading

import pytest

pytest.importorskip("dynamixel_sdk")

from dxl_peer import Peer, Servo  # noqa: E402
from test_arm_servo_faults import ARM, PLAN  # noqa: E402

from nodes.actuators.dynamixel import DynamixelParams, execute_plan  # noqa: E402
from stereograph.core.api import NodeError  # noqa: E402

FAST = dict(poll_interval_s=0.002, retries=2, late_window_ms=100)


class VanishingPeer(Peer):
    """Five AX-12As whose adapter disappears ``delay_s`` after the ``after_sync``-th sync write (0:
    after the ``after_replies``-th status packet)."""

    def __init__(self, after_sync=0, after_replies=0, delay_s=0.03, **kw):
        super().__init__({i: Servo() for i in range(1, 6)}, time_scale=20, **kw)
        self.after_sync, self.after_replies, self.delay_s = after_sync, after_replies, delay_s
        self.n_sync = self.n_replies = 0

    def _write(self, s, sid, addr, data, how):
        r = super()._write(s, sid, addr, data, how)
        if how == "SYNC_WRITE" and sid == 5:
            self.n_sync += 1
            if self.n_sync == self.after_sync:
                threading.Timer(self.delay_s, self.vanish).start()
        return r

    def _send(self, pkt, delay_s):
        super()._send(pkt, delay_s)
        self.n_replies += 1
        if self.n_replies == self.after_replies:
            self.vanish()

    def vanish(self):
        self._stop.set()
        try:
            os.close(self.master)
        except OSError:
            pass


def test_the_port_lost_mid_motion_is_named_not_a_bug_and_torque_is_not_claimed_off():
    with VanishingPeer(after_sync=2) as p:
        with pytest.raises(NodeError) as ei:
            execute_plan(DynamixelParams(port=p.path, **FAST), PLAN, ARM, p.path)
    e = ei.value
    assert f"serial port {p.path} stopped working" in e.message, e.message
    assert (
        "Torque was turned off" not in e.message and "torque could not be turned off" in e.message
    ), e.message
    assert "unplugged" in e.hint and "supply" in e.hint, e.hint
    assert e.lasting  # a --repeat loop must not reopen a port and move the arm by itself
    assert e.partial_log["ok"] is False and e.partial_log["commands"]


def test_the_port_lost_before_moving_is_named_and_nothing_was_written():
    with VanishingPeer(after_replies=3) as p:  # PING 1, its model number, PING 2: then gone
        with pytest.raises(NodeError) as ei:
            execute_plan(DynamixelParams(port=p.path, **FAST), PLAN, ARM, p.path)
        assert all(a > 31 or a + len(d) <= 30 for _, _, a, d in p.log)
    e = ei.value
    assert (
        f"serial port {p.path} stopped working" in e.message
        and "the arm was not moved" in e.message
    ), e.message
    assert "corrupted" not in e.message and "noise" not in e.hint, (e.message, e.hint)
