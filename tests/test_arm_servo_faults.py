"""Servo faults are named for what they are (issue 11 item 4), on the emulator through the real
dynamixel-sdk.

Each case injects one fault into the emulator and checks the message head, the hint (a jammed joint
gets load/obstruction, not cables), that nothing out of limits was written, and the torque state.
``benchmarks/servo_faults.py`` prints the same cases as a table with the seconds each takes to fail.
"""

import time

import pytest

pytest.importorskip("dynamixel_sdk")

from nodes.actuators.dynamixel import DynamixelParams, execute_plan  # noqa: E402
from nodes.contracts.arm import servo_limits_units  # noqa: E402
from nodes.ik.analytic_3dof import AnalyticParams, analytic_3dof  # noqa: E402
from nodes.ik.arm import ArmParams, build_arm_model  # noqa: E402
from nodes.ik.pick_sequence import PickParams, pick_sequence  # noqa: E402
from simbench.servo_sim import (  # noqa: E402
    ERR_ANGLE,
    ERR_OVERHEAT,
    ERR_OVERLOAD,
    ERR_VOLTAGE,
    Faults,
    ServoSim,
)
from stereograph.core.api import NodeError  # noqa: E402

ARM = build_arm_model(ArmParams())
HE = {"T_base_from_left": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}
FAST = dict(port="sim", sim_time_scale=50.0, poll_interval_s=0.002, retries=2, late_window_ms=100)
IDS = [1, 2, 3, 4, 5]


def make_plan():
    from nodes.calibrators.hand_eye import HandEyeParams, hand_eye

    he = hand_eye(
        HandEyeParams(
            mode="given", camera_in_base={"translation_cm": [0, 0, 0], "rpy_deg": [0, 0, 0]}
        )
    )
    loc = {
        "pair": "p1",
        "found": True,
        "reason": None,
        "x_cm": 17.0,
        "y_cm": 4.0,
        "z_cm": 2.5,
        "frame": "left_camera",
    }
    t = analytic_3dof(AnalyticParams(), arm=ARM, location=loc, hand_eye=he["hand_eye"])["target"]
    return pick_sequence(PickParams(), arm=ARM, target=t)["plan"]


PLAN = make_plan()


def fail(sim, **params):
    """Run the plan on ``sim``; return (NodeError, seconds to fail, torque per servo afterwards)."""
    t0 = time.monotonic()
    with pytest.raises(NodeError) as ei:
        execute_plan(DynamixelParams(**{**FAST, **params}), PLAN, ARM, sim.port_path)
    dt = time.monotonic() - t0
    lim = servo_limits_units(ARM)
    assert all(
        lim[str(e["id"])][0] <= e["value"] <= lim[str(e["id"])][1] for e in sim.writes(address=30)
    )
    return ei.value, dt, {i: sim.register(i, "torque_enable") for i in sim.servos}


def no_goal_written(sim):
    return sim.writes(address=30) == []


# ---------------------------------------------------------------------------- before moving
@pytest.mark.slow
def test_no_reply_names_cable_power_id_baud():
    with ServoSim(IDS, faults=Faults(unplugged_ids={3})) as sim:
        e, dt, torque = fail(sim)
        assert no_goal_written(sim)
    assert e.message.startswith("servo ID 3 did not answer a ping (3 tries: no reply x3")
    assert "not even late" in e.message and "the arm was not moved" in e.message
    assert "cable" in e.hint and "baud rate 1000000" in e.hint and "ID is 3" in e.hint
    assert "Torque: off on [1, 2, 4, 5]; unknown on [3]" in e.message


@pytest.mark.slow
def test_late_reply_names_the_latency_timer_and_the_setting_fixes_it():
    faults = dict(late_replies=10_000, late_ms=70.0, only_ids={3})
    with ServoSim(IDS, faults=Faults(**faults)) as sim:
        e, dt, _ = fail(sim)
        assert no_goal_written(sim)
    assert e.message.startswith("servo 3 answers late: its status packet to the ping came")
    assert "latency_timer" in e.hint and "reply_timeout_extra_ms" in e.hint
    late_ms = float(e.message.split("came ")[1].split(" ms")[0])
    assert 70 <= late_ms < 100
    # the setting the hint names: wait longer and the same servo works
    with ServoSim(IDS, faults=Faults(**faults), time_scale=50.0) as sim:
        out = execute_plan(
            DynamixelParams(**FAST, reply_timeout_extra_ms=200), PLAN, ARM, sim.port_path
        )
        assert out["ok"] and out["retries"] == 0, out["events"]


def test_corrupted_replies_name_noise():
    with ServoSim(IDS, faults=Faults(corrupt_replies=10_000, only_ids={2})) as sim:
        e, dt, _ = fail(sim)
        assert no_goal_written(sim)
    assert e.message.startswith(
        "servo 2's replies to the ping arrive corrupted (3 tries: corrupted reply"
    )
    assert dt < 1.0  # garbage is not waited for as if it were a late reply
    assert "noise" in e.hint and "cable" in e.hint


@pytest.mark.parametrize(
    "bit, word, hint_word",
    [
        (ERR_OVERLOAD, "overload error", "obstruction"),
        (ERR_OVERHEAT, "overheating error", "cool"),
        (ERR_VOLTAGE, "input voltage error", "9-12 V"),
        (ERR_ANGLE, "angle limit error", "angle limits"),
    ],
)
def test_alarm_bits_at_ping_are_named(bit, word, hint_word):
    with ServoSim(IDS, faults=Faults(alarms={4: bit})) as sim:
        e, dt, _ = fail(sim)
        assert no_goal_written(sim)
    assert e.message.startswith(
        f"servo 4 reports {word} (alarm bits in its status packet to the ping)"
    )
    assert "status return level" not in e.message and hint_word in e.hint
    # latched until a valid goal: say how to clear it, or no later run gets past the ping
    if bit == ERR_ANGLE:
        assert "power the servos off and on" in e.hint and "address 30" in e.hint
    assert dt < 1.0  # an alarm is the servo's answer: not retried


@pytest.mark.slow
def test_ping_but_read_replies_lost_is_not_status_return_level_0():
    # the 3 READs of the model number lose their replies; a later READ works
    with ServoSim(IDS, faults=Faults(drop_replies=3, instructions={"READ"}, only_ids={5})) as sim:
        e, dt, _ = fail(sim)
        assert no_goal_written(sim)
    assert e.message.startswith("servo 5 answers PING but lost its replies to 3 READs in a row")
    assert "status return level 2" in e.message and "noise" in e.hint
    # every READ reply lost, but WRITE answered: still not status return level 0
    with ServoSim(
        IDS, faults=Faults(drop_replies=10_000, instructions={"READ"}, only_ids={5})
    ) as sim:
        e, dt, _ = fail(sim)
        # the probe moves nothing
        assert [(w["register"], w["value"]) for w in sim.log] == [("led", 0)]
    assert e.message.startswith("servo 5 answers PING and WRITE but not READ")
    assert "is not 0" in e.message


@pytest.mark.slow
def test_status_return_level_0():
    with ServoSim(IDS) as sim:
        sim.servos[2].table[16] = 0
        e, dt, _ = fail(sim)
        assert no_goal_written(sim)
    assert e.message.startswith("servo ID 2 answers a PING but neither READ nor WRITE")
    assert "status return level (address 16) is 0" in e.message and "address 16" in e.hint


@pytest.mark.slow
def test_torque_left_on_is_reported_and_can_be_turned_off():
    def earlier_run(sim):
        for i in (1, 2, 4, 5):
            sim.servos[i].table[24] = 1

    with ServoSim(IDS, faults=Faults(unplugged_ids={3})) as sim:
        earlier_run(sim)
        e, _, torque = fail(sim)
    assert "Torque: still ON on servos [1, 2, 4, 5] (left on by an earlier run" in e.message
    assert "torque_off_on_failure=true" in e.hint and torque == {1: 1, 2: 1, 3: 0, 4: 1, 5: 1}
    with ServoSim(IDS, faults=Faults(unplugged_ids={3})) as sim:
        earlier_run(sim)
        e, _, torque = fail(sim, torque_off_on_failure=True)
        assert no_goal_written(sim)
    assert (
        "Torque was turned off on servos [1, 2, 3, 4, 5] (torque_off_on_failure: true" in e.message
    )
    assert set(torque.values()) == {0}


# ---------------------------------------------------------------------------- during the motion
def test_jammed_joint_overloads_and_gets_a_load_hint():
    # the elbow (servo 4) hits an obstruction on its way to the first waypoint
    start = 512
    goal = PLAN["waypoints"][0]["servo_units"]["4"]
    jam = (start + goal) / 2
    with ServoSim(
        IDS, faults=Faults(jammed_at_units={4: jam}, jam_alarm_s=0.3), time_scale=50.0
    ) as sim:
        e, dt, torque = fail(sim)
        assert abs(sim.register(4, "present_position") - jam) <= 1
    assert (
        "arm stopped during waypoint 'open'" in e.message
        and "servo 4 reports overload error" in e.message
    )
    assert "obstruction" in e.hint and "cable" not in e.hint
    assert set(torque.values()) == {0} and "Torque was turned off" in e.message


def test_stalled_joint_without_alarm_gets_a_load_hint():
    goal = PLAN["waypoints"][0]["servo_units"]["4"]
    with ServoSim(
        IDS, faults=Faults(jammed_at_units={4: (512 + goal) / 2}, jam_alarm_s=1e9), time_scale=50.0
    ) as sim:
        e, dt, torque = fail(sim, move_timeout_s=0.5)
    assert (
        "servos [4] still" in e.message and "obstruction" in e.hint and set(torque.values()) == {0}
    )


def test_overheating_while_moving_is_named():
    with ServoSim(
        IDS, faults=Faults(alarms={2: ERR_OVERHEAT}, after_goal_writes=1), time_scale=50.0
    ) as sim:
        e, dt, torque = fail(sim)
    assert (
        "arm stopped during waypoint 'open'" in e.message
        and "servo 2 reports overheating error" in e.message
    )
    assert "cool" in e.hint and set(torque.values()) == {0}


def test_late_replies_while_moving():
    with ServoSim(
        IDS,
        faults=Faults(late_replies=10_000, late_ms=70.0, only_ids={1}, after_goal_writes=1),
        time_scale=50.0,
    ) as sim:
        e, dt, torque = fail(sim)
    assert "arm stopped during waypoint 'open'" in e.message and "servo 1 answers late" in e.message
    assert "latency_timer" in e.hint and set(torque.values()) == {0}


# ---------------------------------------------------------------------------- interrupted
# in-process
@pytest.mark.slow
def test_ctrl_c_mid_motion_with_torque_off_and_before_moving():
    import os
    import signal
    import threading

    with ServoSim(IDS, time_scale=1.0) as sim:
        threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        with pytest.raises(KeyboardInterrupt) as ei:
            execute_plan(
                DynamixelParams(**{**FAST, "sim_time_scale": 1.0, "on_interrupt": "torque_off"}),
                PLAN,
                ARM,
                sim.port_path,
            )
        stop = ei.value.servo_log["stop"]
        assert stop["action"] == "torque_off" and stop["during"] == "open" and stop["port_closed"]
        assert all(sim.register(i, "torque_enable") == 0 for i in IDS)
    # interrupted while still pinging: nothing written, nothing to stop
    with ServoSim(IDS, faults=Faults(late_replies=10_000, late_ms=400.0)) as sim:
        threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        with pytest.raises(KeyboardInterrupt) as ei:
            execute_plan(
                DynamixelParams(**{**FAST, "late_window_ms": 1000}), PLAN, ARM, sim.port_path
            )
        assert ei.value.servo_log["stop"]["action"] == "none" and sim.log == []


@pytest.mark.slow
def test_second_ctrl_c_on_the_way_to_rest_holds_and_the_node_saves_the_log(tmp_path):
    import json
    import os
    import signal
    import threading

    from nodes.actuators.dynamixel import dynamixel
    from stereograph.core.api import RunContext

    ctx = RunContext("act", None, tmp_path / "act", tmp_path)
    for delay in (0.5, 0.8):  # the second one arrives during the move to the rest pose
        threading.Timer(delay, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    with pytest.raises(KeyboardInterrupt):
        dynamixel(
            DynamixelParams(
                **{**FAST, "sim_time_scale": 1.0, "on_interrupt": "rest", "rest_speed_deg_s": 20}
            ),
            arm=ARM,
            plans=PLAN,
            ctx=ctx,
        )
    saved = json.loads((tmp_path / "act" / "servo_log_interrupted.json").read_text())
    stop = saved["stop"]
    assert stop["action"] == "hold" and stop["detail"].startswith(
        "interrupted again on the way to the rest pose"
    )
    lim = servo_limits_units(ARM)
    assert saved["sim"]["writes"] and all(
        lim[str(w["id"])][0] <= w["value"] <= lim[str(w["id"])][1]
        for w in saved["sim"]["writes"]
        if w["address"] == 30
    )
