"""actuator.dynamixel against an independent Protocol 1.0 peer (``tests/dxl_peer.py``), not the
bundled emulator.

The peer is written from the AX-12A control table and behaves as real buses can: servo settings the
emulator's defaults never show, other models on the bus, an adapter that echoes what it sends.
"""

import pytest

pytest.importorskip("dynamixel_sdk")

from dxl_peer import Peer, Servo  # noqa: E402
from test_arm_servo_faults import ARM, PLAN  # noqa: E402

from nodes.actuators.dynamixel import DynamixelParams, execute_plan  # noqa: E402
from stereograph.core.api import NodeError  # noqa: E402

FAST = dict(poll_interval_s=0.002, retries=2, late_window_ms=100)


def servos(**kw):
    return {i: Servo(**kw) for i in range(1, 6)}


def refused(peer, **params):
    with pytest.raises(NodeError) as ei:
        execute_plan(DynamixelParams(port=peer.path, **{**FAST, **params}), PLAN, ARM, peer.path)
    return ei.value


def no_goal_written(peer):
    return all(a > 31 or a + len(d) <= 30 for _, _, a, d in peer.log)


def test_a_servo_in_wheel_mode_is_refused_before_anything_is_written():
    s = servos()
    s[1].cw = s[1].ccw = 0  # wheel mode: a moving speed would make the yaw joint turn without end
    with Peer(s, time_scale=20) as p:
        e = refused(p)
        assert (
            "servo 1 is in wheel (endless turn) mode" in e.message
            and "arm was not moved" in e.message
        )
        assert "CCW angle limit 1023" in e.hint
        assert no_goal_written(p) and all(sv.get(24, 1) == 0 for sv in p.servos.values())


@pytest.mark.parametrize(
    "model, words", [(29, "an MX-28 (0-4095 over 360 deg)"), (999, "not a model this actuator")]
)
def test_a_servo_whose_positions_mean_other_angles_is_refused(model, words):
    s = servos()
    # an MX-28 in Protocol 1.0 counts 4096 units per turn: unit 205 is 18 deg, not 60
    s[4].model = model
    with Peer(s, time_scale=20) as p:
        e = refused(p)
        assert (
            f"servo 4 reports model number {model}, {words}" in e.message
            and "arm was not moved" in e.message
        )
        assert "ID 4" in e.hint and no_goal_written(p)


def test_other_models_with_ax12_units_drive_the_arm():
    s = servos()
    s[2].model, s[5].model = 18, 44  # AX-18A, AX-12W
    with Peer(s, time_scale=20) as p:
        log = execute_plan(DynamixelParams(port=p.path, **FAST), PLAN, ARM, p.path)
        assert log["ok"] and any("model number 18 (AX-18A)" in e for e in log["events"])


def test_an_adapter_that_echoes_what_it_sends_drives_the_arm():
    # A half-duplex adapter without echo cancellation: dynamixel-sdk takes the echo of a PING for a
    # status packet with the input-voltage bit, that of a READ for one with the angle-limit bit.
    with Peer(servos(srl=1), echo=True, time_scale=20) as p:
        log = execute_plan(DynamixelParams(port=p.path, **FAST), PLAN, ARM, p.path)
        assert log["ok"] and any("echoes every packet" in e for e in log["events"])
        assert all(r["max_error_units"] <= 3 for r in log["reached"])


@pytest.mark.parametrize(
    "present, words",
    [([2, 3, 4, 5], "servo ID 1 did not answer a ping"), ([], "no servo answers on")],
)
@pytest.mark.slow
def test_missing_servos_behind_an_echoing_adapter_are_named_not_voltage_alarms(present, words):
    with Peer({i: Servo() for i in present}, echo=True, time_scale=20) as p:
        e = refused(p)
        assert e.message.startswith(words) and "voltage" not in e.message + e.hint, e.message
        assert no_goal_written(p)


@pytest.mark.slow
def test_a_joint_that_settled_short_is_said_once_it_is_still_not_after_the_whole_timeout():
    # (the default timeout is 1.5 x the move's planned time + 1 s per waypoint: a servo that had
    # stopped 5 units short, moving flag 0, was waited for that long before the same message)
    with Peer(servos(short_by=5), time_scale=20) as p:
        e = refused(p)  # the default timeout
        assert "[5, 5] units from their goals" in e.message, e.message
        assert "stopped there (moving flag 0, not moving for 0.3 s past the move's" in e.message, (
            e.message
        )
        assert "act.tolerance_units=5" in e.hint
        # torque off, as after the timeout
        assert all(sv.get(24, 1) == 0 for sv in p.servos.values())


def test_a_joint_that_settles_a_few_units_short_is_named_with_the_tolerance_to_set():
    # Real AX-12s under load stop within their compliance margin: 5 units short, moving flag 0.
    with Peer(servos(short_by=5), time_scale=20) as p:
        e = refused(p, move_timeout_s=0.4)
        assert (
            "[5, 5] units from their goals" in e.message
            and "stopped there (moving flag 0)" in e.message
        )
        assert (
            "act.tolerance_units=5" in e.hint
            and "compliance" in e.hint
            and "obstruction" not in e.hint
        )
        # torque off after a failed move, as documented
        assert all(sv.get(24, 1) == 0 for sv in p.servos.values())


@pytest.mark.parametrize(
    "max_torque, words", [(1023, "alarm shutdown"), (0, "max torque (address 14) is 0")]
)
def test_a_servo_with_a_torque_limit_of_0_is_refused_before_anything_is_written(max_torque, words):
    # An AX-12A sets its torque limit (address 34) to 0 on an alarm shutdown (overload, overheating)
    # and loads it from max torque (address 14) at power-on: such a joint cannot move. The other
    # joints went to the first waypoint, then the move timed out and torque was turned off on the
    # whole arm.
    with Peer(servos(), time_scale=20) as p:
        p.servos[4].set(34, 2, 0)
        p.servos[4].set(14, 2, max_torque)
        e = refused(p)
        assert (
            "servo 4's torque limit (address 34) is 0" in e.message
            and "arm was not moved" in e.message
        ), e.message
        assert words in e.hint and "address 34" in e.hint, e.hint
        assert no_goal_written(p)


def test_two_servos_on_one_id_are_refused_before_anything_is_written():
    # A sixth servo left at ID 5 (a spare, the factory ID of a new one renumbered by mistake): both
    # answer every request, one after the other, and a goal for ID 5 would move both.
    with Peer(servos(), twins={5}, time_scale=20) as p:
        e = refused(p)
        assert e.message.startswith("two servos answer at ID 5"), e.message
        assert "arm was not moved" in e.message and "one at a time" in e.hint, (e.message, e.hint)
        assert no_goal_written(p)


@pytest.mark.slow
def test_a_missing_id_whose_servo_shares_another_id_is_named():
    # The shoulder's two servos both set to ID 3: ID 2 is silent, ID 3 answers twice.
    s = servos()
    del s[2]
    with Peer(s, twins={3}, time_scale=20) as p:
        e = refused(p)
        assert e.message.startswith("servo ID 2 did not answer a ping"), e.message
        assert "two servos answer at ID 3" in e.message and "set its ID to 2" in e.hint, (
            e.message,
            e.hint,
        )
        assert no_goal_written(p)
    # ID 3 missing, ID 2 doubled: the twins are met first, and named
    s = servos()
    del s[3]
    with Peer(s, twins={2}, time_scale=20) as p:
        e = refused(p)
        assert e.message.startswith("two servos answer at ID 2"), e.message
        assert no_goal_written(p)
