"""Pick sequence, the dry-run actuator, and actuator.dynamixel over the emulator (real
dynamixel-sdk)."""

import copy
import json

import numpy as np
import pytest

pytest.importorskip("dynamixel_sdk")

from nodes.actuators._plan import sync_write_packet, waypoint_data  # noqa: E402
from nodes.actuators.dynamixel import DynamixelParams, dynamixel, execute_plan  # noqa: E402
from nodes.actuators.log import LogParams, log  # noqa: E402
from nodes.calibrators.hand_eye import HandEyeParams, hand_eye  # noqa: E402
from nodes.contracts.arm import servo_limits_units  # noqa: E402
from nodes.ik.analytic_3dof import AnalyticParams, analytic_3dof  # noqa: E402
from nodes.ik.arm import ArmParams, build_arm_model  # noqa: E402
from nodes.ik.numeric import NumericParams, numeric  # noqa: E402
from nodes.ik.pick_sequence import PickParams, pick_sequence  # noqa: E402
from simbench.servo_sim import ServoSim, instruction_packet  # noqa: E402
from stereograph.core.api import NodeError, RunContext  # noqa: E402

ARM = build_arm_model(ArmParams())
HE = hand_eye(
    HandEyeParams(mode="given", camera_in_base={"translation_cm": [0, 0, 0], "rpy_deg": [0, 0, 0]})
)["hand_eye"]
# late_window_ms: a missing reply costs 34 ms (the SDK's timeout) + this; short here for speed
FAST = dict(port="sim", sim_time_scale=50.0, poll_interval_s=0.002, retries=2, late_window_ms=100)


def located(x, y, z, **kw):
    return {
        "pair": "p1",
        "found": True,
        "reason": None,
        "x_cm": x,
        "y_cm": y,
        "z_cm": z,
        "frame": "left_camera",
        **kw,
    }


def make_plan(loc=None, **pick):
    t = analytic_3dof(
        AnalyticParams(), arm=ARM, location=loc or located(17.0, 4.0, 2.5), hand_eye=HE
    )["target"]
    return pick_sequence(PickParams(**pick), arm=ARM, target=t)["plan"]


def assert_goals_within_limits(sim):
    lim = servo_limits_units(ARM)
    for e in sim.writes(address=30):
        lo, hi = lim[str(e["id"])]
        assert lo <= e["value"] <= hi, e


# ---------------------------------------------------------------------------- pick sequence
def test_pick_sequence_waypoints():
    plan = make_plan(place_cm=[8.0, -14.0, 2.5], return_home=True)
    names = [w["name"] for w in plan["waypoints"]]
    assert names == [
        "open",
        "above",
        "descend_1",
        "descend_2",
        "grasp",
        "close",
        "lift",
        "place_above",
        "place",
        "release",
        "retreat",
        "home",
    ]
    wp = {w["name"]: w for w in plan["waypoints"]}
    g = [w for w in plan["waypoints"] if w["name"] in ("above", "descend_1", "descend_2", "grasp")]
    assert all(np.allclose(w["tool_cm"][:2], [17.0, 4.0]) for w in g)  # a vertical descent
    assert [w["tool_cm"][2] for w in g] == pytest.approx([8.5, 6.5, 4.5, 2.5])
    assert wp["grasp"]["gripper"] == "open" and wp["close"]["gripper"] == "closed"
    assert wp["close"]["servo_units"]["5"] != wp["grasp"]["servo_units"]["5"]
    assert np.linalg.norm(np.array(plan["grasp_fk_cm"]) - [17.0, 4.0, 2.5]) < 0.1
    lim = servo_limits_units(ARM)
    for w in plan["waypoints"]:
        assert all(lim[k][0] <= v <= lim[k][1] for k, v in w["servo_units"].items())


def test_pick_with_numeric_solver_matches_analytic():
    t = numeric(NumericParams(), arm=ARM, location=located(17.0, 4.0, 2.5), hand_eye=HE)["target"]
    plan_n = pick_sequence(PickParams(), arm=ARM, target=t)["plan"]
    plan_a = make_plan()
    for wa, wn in zip(plan_a["waypoints"], plan_n["waypoints"]):
        assert all(abs(wa["servo_units"][k] - wn["servo_units"][k]) <= 1 for k in wa["servo_units"])


@pytest.mark.parametrize(
    "loc, pick, match",
    [
        (
            located(None, None, None, found=False, reason="no object in the left image"),
            {},
            "not located.*no object",
        ),
        (located(17.0, 4.0, 2.5, extrapolated=True), {}, "extrapolated"),
        (
            located(17.0, 4.0, 2.5),
            {"workspace_max_cm": [15.0, 20.0, 20.0]},
            "outside the workspace box",
        ),
        # a ball below the table (a hand-eye off in z) is named by its centre, not by the descent
        # point that first crossed the floor ('the descend_2 point [17.00, 4.00, -2.00] cm lies
        # outside ...')
        (
            located(17.0, 4.0, -4.0),
            {},
            r"the grasp point \(the object's centre\) \[17.00, 4.00, -4.00\] cm lies outside",
        ),
        (
            located(17.0, 4.0, 2.5),
            {"place_cm": [40.0, 0.0, 0.0], "workspace_max_cm": [50, 50, 50]},
            "place_above point is unreachable for this arm: distance",
        ),
    ],
)
def test_pick_sequence_refuses(loc, pick, match):
    t = analytic_3dof(AnalyticParams(), arm=ARM, location=loc, hand_eye=HE)["target"]
    with pytest.raises(NodeError, match=match):
        pick_sequence(PickParams(**pick), arm=ARM, target=t)


# ---------------------------------------------------------------------------- dry run
def test_log_dry_run_packets_are_valid_protocol_1():
    plan = make_plan()
    out = log(LogParams(), arm=ARM, plans=plan)["log"]["picks"][0]
    assert out["dry_run"] and len(out["packets_hex"]) == len(plan["waypoints"])
    first = bytes.fromhex(out["packets_hex"][0])
    data = waypoint_data(plan["waypoints"][0])
    params = bytes([30, 4]) + b"".join(
        bytes([i, g & 255, g >> 8, s & 255, s >> 8]) for i, (g, s) in data.items()
    )
    assert first == instruction_packet(0xFE, 0x83, params) == sync_write_packet(data)
    assert len(out["commands"]) == 2 * 5 * len(plan["waypoints"]) and out["seconds"] > 0


def test_plans_outside_limits_are_refused_before_anything_is_sent():
    plan = make_plan()
    bad = copy.deepcopy(plan)
    bad["waypoints"][3]["servo_units"]["4"] = 1020  # beyond the elbow's +140 deg
    with pytest.raises(
        NodeError, match=r"refusing the whole plan: waypoint 'descend_2'.*servo 4 to 1020"
    ):
        log(LogParams(), arm=ARM, plans=bad)
    with ServoSim([1, 2, 3, 4, 5]) as sim:
        with pytest.raises(NodeError, match="refusing the whole plan"):
            execute_plan(DynamixelParams(**FAST), bad, ARM, sim.port_path)
        assert sim.log == [] and sim.packets == []  # not even a ping


# ---------------------------------------------------------------------------- on the emulator
def test_full_pick_on_the_emulator():
    plan = make_plan(place_cm=[8.0, -14.0, 2.5])
    out = dynamixel(DynamixelParams(**FAST), arm=ARM, plans=plan)["log"]["picks"][0]
    assert out["ok"]
    # A fault-free emulator never corrupts or alarms; on a starved machine its thread may answer
    # late (a retry for timing, logged as such), which is the only retry allowed here.
    retried = [e for e in out["events"] if "retry" in e]
    assert len(retried) == out["retries"]
    assert all("late status packet" in e or "no status packet" in e for e in retried), retried
    assert [r["waypoint"] for r in out["reached"]] == [w["name"] for w in plan["waypoints"]]
    assert all(r["max_error_units"] <= 3 for r in out["reached"])
    final = plan["waypoints"][-1]["servo_units"]
    assert all(abs(out["sim"]["final_positions"][k] - v) <= 3 for k, v in final.items())
    writes = out["sim"]["writes"]
    goals = [e for e in writes if e["address"] == 30]
    assert {e["instruction"] for e in goals} == {"SYNC_WRITE"} and all(e["accepted"] for e in goals)
    assert len(goals) == 5 * len(plan["waypoints"])
    lim = servo_limits_units(ARM)
    assert all(lim[str(e["id"])][0] <= e["value"] <= lim[str(e["id"])][1] for e in goals)


@pytest.mark.slow
def test_dropped_replies_are_retried():
    plan = make_plan()
    with ServoSim([1, 2, 3, 4, 5], time_scale=50.0) as sim:
        sim.set_faults(drop_reply_prob=0.1, seed=3)
        out = execute_plan(DynamixelParams(**{**FAST, "retries": 5}), plan, ARM, sim.port_path)
        drops = [e for e in out["events"] if "no status packet" in e]
        assert out["ok"] and len(sim.fault_log) > 0
        # every dropped reply was retried; a retry without a drop can only be the loaded machine's
        # own delay (a late reply, or one later than the late window: also "no status packet")
        assert len(drops) >= len(sim.fault_log) and out["retries"] >= len(sim.fault_log)
        assert all(
            "no status packet" in e or "late status packet" in e
            for e in out["events"]
            if "retry" in e
        )
        assert_goals_within_limits(sim)


@pytest.mark.parametrize("fault", ["drop_replies", "corrupt_replies"])
def test_persistent_fault_mid_motion_turns_torque_off(fault, tmp_path):
    plan = make_plan()
    with ServoSim([1, 2, 3, 4, 5], time_scale=50.0) as sim:
        # servo 4 answers the whole setup, then goes bad once the first goal was accepted
        sim.set_faults(**{fault: 1000}, only_ids={4}, after_goal_writes=1)
        with pytest.raises(NodeError) as ei:
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        msg = str(ei.value)
        assert (
            "during waypoint 'open'" in msg and "3 tries" in msg and "Torque was turned off" in msg
        )
        if fault == "drop_replies":
            assert (
                "servo 4 stopped answering" in msg and "connector that came loose" in ei.value.hint
            )
        else:
            assert "servo 4's replies to the read-back of the goal position arrive corrupted" in msg
            assert "noise" in ei.value.hint
        assert all(sim.register(i, "torque_enable") == 0 for i in (1, 2, 3, 4, 5))
        # the healthy servos' torque-off is confirmed: their status packets to the WRITE are not
        # taken for replies to the read-back (they were: "servo 1: not confirmed (corrupted status
        # packet ...)")
        assert not any(f"servo {i}: not confirmed" in msg for i in (1, 2, 3, 5)), msg
        assert ei.value.partial_log["ok"] is False
        assert_goals_within_limits(sim)


@pytest.mark.slow
def test_missing_servo_fails_before_any_write(tmp_path):
    plan = make_plan()
    ctx = RunContext("act", "p1", tmp_path, tmp_path)
    with pytest.raises(
        NodeError, match=r"servo ID 3 did not answer a ping.*not moved.*check servo 3's cable"
    ):
        dynamixel(
            DynamixelParams(**FAST, sim_faults={"unplugged_ids": [3]}), arm=ARM, plans=plan, ctx=ctx
        )
    with ServoSim([1, 2, 4, 5]) as sim:  # servo 3 absent altogether
        with pytest.raises(NodeError, match="servo ID 3"):
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        assert sim.log == []


@pytest.mark.slow
def test_a_servo_set_to_another_id_is_named_with_the_ids_that_answer():
    # servo 3 of the arm was renumbered 6 (or a new one left at another ID): "did not answer" alone
    # sent people to check a cable that was fine
    plan = make_plan()
    with ServoSim([1, 2, 4, 5, 6], time_scale=50.0) as sim:
        with pytest.raises(NodeError) as ei:
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        msg = " ".join(ei.value.message.split())
        assert "servo ID 3 did not answer a ping" in msg, msg
        assert (
            "IDs 1, 2, 4, 5, 6 answer (0-13 pinged): ID 6 answers but is not in the arm model"
            in msg
        ), msg
        assert ei.value.hint.startswith(
            "if ID 6 is the servo the arm model calls 3, set its ID to 3"
        )
        assert sim.log == []  # nothing written, nothing moved
    with ServoSim([1, 2, 4, 5], time_scale=50.0) as sim:  # absent: only the arm's own IDs answer
        with pytest.raises(NodeError) as ei:
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        assert (
            "IDs 1, 2, 4, 5 answer" in ei.value.message
            and "not in the arm model" not in ei.value.message
        )


@pytest.mark.slow
def test_a_bus_where_no_servo_answers_is_named_as_such():
    # (a silent bus -- supply off, adapter unplugged at the servo end -- was "servo ID 1 did not
    # answer a ping")
    plan = make_plan()
    with ServoSim([], time_scale=50.0) as sim:  # nothing on the bus
        with pytest.raises(
            NodeError, match=r"no servo answers on .* at 1000000 baud.*IDs 1, 2, 3, 4, 5"
        ) as ei:
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        assert "supply is on" in ei.value.hint and sim.log == []


def test_servo_angle_limits_are_checked_before_moving():
    plan = make_plan()
    with ServoSim([1, 2, 3, 4, 5]) as sim:
        sim.servos[4].set(6, 300)  # CW limit 300 on servo 4, above the plan's elbow goals
        with pytest.raises(NodeError, match=r"servo 4's own angle limits are 300\.\.1023"):
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        assert sim.log == []


def test_failed_run_writes_partial_log(tmp_path):
    plan = make_plan()
    ctx = RunContext("act", "p1", tmp_path / "act", tmp_path)
    with pytest.raises(NodeError, match="commands sent so far are in"):
        dynamixel(
            DynamixelParams(
                **FAST, sim_faults={"drop_replies": 1000, "only_ids": [2], "after_goal_writes": 1}
            ),
            arm=ARM,
            plans=plan,
            ctx=ctx,
        )
    saved = json.loads((tmp_path / "act" / "servo_log_failed.json").read_text())
    assert saved["ok"] is False and saved["sim"]["writes"] and saved["commands"][-1]["value"] == 0


def test_bad_port_is_a_clear_error():
    with pytest.raises(NodeError, match=r"cannot open serial port /dev/ttyNOPE.*") as ei:
        dynamixel(DynamixelParams(port="/dev/ttyNOPE"), arm=ARM, plans=make_plan())
    assert "ls /dev/ttyUSB*" in ei.value.hint


# ---------------------------------------------------------------------------- servo peers
# configured otherwise
def test_servos_that_reply_only_to_reads_still_work():
    """Many AX-12 buses run with status return level 1 (no status packet after a write)."""
    plan = make_plan()
    with ServoSim([1, 2, 3, 4, 5], time_scale=50.0) as sim:
        for s in sim.servos.values():
            s.table[16] = 1
        out = execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        assert out["ok"]
        assert_goals_within_limits(sim)


@pytest.mark.slow
def test_servos_that_never_reply_to_reads_fail_clearly_before_moving():
    plan = make_plan()
    with ServoSim([1, 2, 3, 4, 5], time_scale=50.0) as sim:
        for s in sim.servos.values():
            s.table[16] = 0  # answers PING only
        with pytest.raises(NodeError) as ei:
            execute_plan(DynamixelParams(**FAST), plan, ARM, sim.port_path)
        assert "status return level" in str(ei.value) or "status return level" in (
            ei.value.hint or ""
        )
        assert sim.writes(address=30) == []  # no goal was ever written


def test_summary_says_why_plans_were_not_picked():
    from nodes.actuators._plan import summary

    skipped = {
        "s001": "max_picks 1 reached",
        "s002": "max_picks 1 reached",
        "s003": "split train",
        "s004": "refused: out of reach (24.1 cm > 23.0 cm); fix: move the arm",
    }
    s = summary([], [], skipped)
    assert s["not_picked"] == 4
    assert s["not_picked_why"] == {"max_picks 1 reached": 2, "split train": 1, "refused": 1}
