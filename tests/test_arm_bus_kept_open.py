"""actuator.dynamixel with the port kept open across plans (the cycles of ``--repeat``; issue 11,
latency).

The setup (PING, model, status return level, angle limits) runs once per open port; a later plan
writes its first goal after one position read per servo; any fault or interrupt closes the port
and the next plan sets up again. SIGTERM raised by the engine is named SIGTERM, and the emulator's
log copied after an interrupt ends with the stop's goals.
"""

import json
import os
import signal
import threading

import pytest

pytest.importorskip("dynamixel_sdk")

from test_arm_actuator import ARM, FAST, make_plan  # noqa: E402

from nodes.actuators.dynamixel import DynamixelParams, _run, dynamixel, execute_plan, open_bus  # noqa: E402
from nodes.contracts.arm import servo_limits_units  # noqa: E402
from simbench.servo_sim import ServoSim  # noqa: E402
from stereograph.core.api import NodeError, RunContext  # noqa: E402
from stereograph.core.calls import close_resources  # noqa: E402

IDS = [1, 2, 3, 4, 5]


def _instructions(sim: ServoSim, start: int) -> list[str]:
    return [p["instruction"] for p in sim.packets[start:]]


@pytest.mark.slow
def test_setup_once_per_open_port_and_again_after_a_fault():
    params = DynamixelParams(**FAST)
    plan = make_plan()
    with ServoSim(IDS, time_scale=50.0) as sim:
        bus = open_bus(params, sim.port_path)
        try:
            first = execute_plan(params, plan, ARM, sim.port_path, bus)
            # one PING per servo, plus any the bus retried after a late reply (this machine may be
            # loaded)
            ping_retries = sum(": ping on servo " in e and "retry" in e for e in first["events"])
            assert (
                first["ok"]
                and _instructions(sim, 0).count("PING") == 5 + ping_retries
                and bus.is_open
            )
            n = len(sim.packets)
            log = execute_plan(params, plan, ARM, sim.port_path, bus)
            sent = _instructions(sim, n)
            # the second plan: one READ (present position) per servo, then the first goal
            pre = sent[: sent.index("SYNC_WRITE")]
            # a late reply on this loaded machine
            retried = sum(" setup: " in e for e in log["events"])
            assert log["ok"] and "PING" not in sent and pre == ["READ"] * (5 + retried), (
                pre,
                log["events"],
            )
            assert bus.is_open and log["commands"][0]["waypoint"] != "setup"
            # servo 3 unplugged between plans: refused before anything is written, port closed
            sim.set_faults(unplugged_ids={3})
            n, goals = len(sim.packets), len(sim.writes(address=30))
            with pytest.raises(
                NodeError,
                match=r"servo ID 3 did not answer a read of the present position.*the arm "
                r"was not moved.*left on by this run's earlier picks",
            ):
                execute_plan(params, plan, ARM, sim.port_path, bus)
            assert len(sim.writes(address=30)) == goals and "SYNC_WRITE" not in _instructions(
                sim, n
            )
            assert not bus.is_open and not bus.limits
            # plugged in again: the next plan reopens the port and checks every servo again
            sim.set_faults(unplugged_ids=set())
            n = len(sim.packets)
            assert execute_plan(params, plan, ARM, sim.port_path, bus)["ok"]
            assert _instructions(sim, n).count("PING") == 5
        finally:
            bus.close()


def test_the_engine_keeps_the_emulator_and_the_port_for_the_run(tmp_path):
    ctx = RunContext("act", None, tmp_path / "act", tmp_path, resources={})
    plan = make_plan()
    first = dynamixel(DynamixelParams(**FAST), arm=ARM, plans=plan, ctx=ctx)["log"]["picks"][0]
    sim, bus = (
        ctx.resources["act:emulator"],
        next(v for k, v in ctx.resources.items() if k.startswith("act:bus")),
    )
    second = dynamixel(DynamixelParams(**FAST), arm=ARM, plans=plan, ctx=ctx)["log"]["picks"][0]
    assert first["ok"] and second["ok"] and first["port"] == second["port"]
    assert [c["instruction"] for c in second["commands"]][0] == "SYNC_WRITE"
    assert len(second["sim"]["writes"]) < len(sim.log)  # this plan's writes only
    close_resources(ctx.resources)  # what the engine does at the end of the run
    assert not bus.is_open and sim.master is None


def test_sigterm_from_the_engine_is_named_and_the_emulator_log_ends_with_the_hold(tmp_path):
    """``stereograph run --repeat`` turns SIGTERM into ``KeyboardInterrupt("SIGTERM")``."""

    def engine_handler(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    fired = threading.Event()

    def on_write(entry):  # in the emulator's thread: the first goal accepted, the arm moves
        if entry["register"] == "goal_position" and not fired.is_set():
            fired.set()
            threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGTERM)).start()

    prev = signal.signal(signal.SIGTERM, engine_handler)
    ctx = RunContext("act", None, tmp_path / "act", tmp_path)
    try:
        with ServoSim(IDS, time_scale=2.0, on_write=on_write) as sim:
            with pytest.raises(KeyboardInterrupt):
                _run(
                    DynamixelParams(**{**FAST, "sim_time_scale": 2.0}),
                    make_plan(),
                    ARM,
                    sim.port_path,
                    sim,
                    ctx,
                )
    finally:
        signal.signal(signal.SIGTERM, prev)
    saved = json.loads((tmp_path / "act" / "servo_log_interrupted.json").read_text())
    assert saved["stop"]["cause"] == "SIGTERM" and saved["stop"]["action"] == "hold"
    goals = [w for w in saved["sim"]["writes"] if w["register"] == "goal_position"]
    # the emulator's log, copied after it drained, ends with the hold's goals
    assert {str(w["id"]): w["value"] for w in goals[-5:]} == saved["stop"]["goals"]
    limits = servo_limits_units(ARM)
    assert all(limits[str(w["id"])][0] <= w["value"] <= limits[str(w["id"])][1] for w in goals)


@pytest.mark.slow
def test_each_failed_motion_of_a_run_keeps_its_own_log(tmp_path):
    # (in a --repeat loop every mid-motion failure wrote act/servo_log_failed.json, so an earlier
    # cycle's message named a file that by then held a later cycle's commands)
    ctx = RunContext("act", None, tmp_path / "act", tmp_path, resources={})
    params = DynamixelParams(**FAST)
    try:
        assert dynamixel(params, arm=ARM, plans=make_plan(), ctx=ctx)["log"]["ok"]
        sim = ctx.resources["act:emulator"]
        paths = []
        for pair in ("c2", "c3"):
            # servo 4 goes silent once the plan's first goals are written: a failure during the
            # motion
            sim.set_faults(
                only_ids={4},
                drop_replies=params.retries + 1,
                after_goal_writes=sim.n_goal_writes + 5,
            )
            plan = {**make_plan(), "pair": pair}
            with pytest.raises(NodeError, match=r"servo 4 stopped answering") as err:
                dynamixel(params, arm=ARM, plans=plan, ctx=ctx)
            paths.append(err.value.message.rsplit(" are in ", 1)[1].rstrip("."))
        assert [p.rsplit("/", 1)[1] for p in paths] == [
            "servo_log_failed.json",
            "servo_log_failed_2.json",
        ]
        assert [json.loads(open(p).read())["pair"] for p in paths] == ["c2", "c3"]
    finally:
        close_resources(ctx.resources)
