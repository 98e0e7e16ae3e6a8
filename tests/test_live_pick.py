"""pipelines/pick-live.yaml --repeat: successive balls picked from a recorded camera on the emulated
servos."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereograph.app.loop import Loop
from stereograph.core.config import load_pipeline
from stereograph.core.graph import build_graph
from stereograph.core.runner import run_graph

PIPELINE = Path(__file__).resolve().parents[1] / "pipelines" / "pick-live.yaml"
ORDER = ["s000", "s001", "s002", "s003", "s004", "empty000", "s005"]
DROP = [0.0, 18.0, 4.0]  # arm-base frame, cm

pytestmark = pytest.mark.slow  # (one module fixture: seven pick cycles)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """Seven cycles: five balls, a frame without one, then another ball; each ball put down at a
    drop point."""
    tmp = tmp_path_factory.mktemp("live")
    doc = load_pipeline(
        PIPELINE, [f"recording.ids={ORDER}", "act.sim_time_scale=20", f"pick.place_cm={DROP}"]
    )
    loop = Loop(len(ORDER), save_cycles=True)
    result = run_graph(build_graph(doc), cycles=loop, out_dir=tmp / "run", cache_dir=tmp / "cache")
    return loop, result, tmp


def test_five_balls_in_a_row_each_grasped_within_half_a_centimetre(live):
    loop, _, _ = live
    assert loop.completed and [c.values["cam.pairs"]["id"] for c in loop.cycles] == ORDER
    picked = loop.cycles[:5] + loop.cycles[6:]
    for c in picked:
        assert c.status == "ok", c.line()
        plan, summary = c.values["pick.plan"], c.values["act.summary"]["picks"][0]
        # the grasp point the commanded servo goals put the tool at, against the true ball centre
        err = np.linalg.norm(np.subtract(plan["grasp_fk_cm"], plan["truth_base_cm"]))
        assert err < 0.5, (c.index, err)
        assert (
            summary["ok"]
            and summary["grasp_servo_goals"]
            == plan["waypoints"][plan["grasp_index"]]["servo_units"]
        )
        assert c.values["compensate.location"]["sigma_z_cm"] > 0
        assert c.values["cam.pairs"]["skew_ms"] == 0.0
        assert set(c.nodes) >= {"cam", "segment", "locate", "compensate", "ik", "pick", "act"}
    # the calibration checked on the live pairs
    assert loop.cycles[0].values["gate.health"]["verdict"] == "ok"
    # cycle 1 also loaded the files and recorded the camera; later cycles ran only the live part
    assert "calibration" not in loop.cycles[1].nodes and loop.live[0] == "cam"


def test_a_frame_without_a_ball_moves_nothing_and_the_loop_goes_on(live):
    loop, _, _ = live
    empty = loop.cycles[5]
    assert empty.status == "failed" and empty.failed_node == "pick"
    assert "not located" in empty.error and "refusing to move the arm" in empty.error
    # the servos were never opened
    assert "act" not in empty.nodes or empty.nodes["act"]["status"] == "skipped"
    assert "act.log" not in empty.values
    assert loop.cycles[6].status == "ok"


def test_the_run_folder_has_the_cycle_log_and_the_recording(live):
    loop, result, _ = live
    lines = (result.out_dir / "cycles.jsonl").read_text().splitlines()
    assert len(lines) == len(ORDER)
    assert (result.out_dir / "cam" / "recording" / "left.avi").stat().st_size > 0
    # --save-cycles: each cycle's pair as PNG, and its other live outputs as JSON
    first = result.out_dir / "cycles" / "00001"
    left = cv2.imread(str(first / "cam" / "pairs_left.png"))
    assert left.shape == (480, 640, 3)
    assert json.loads((first / "compensate" / "location.json").read_text())["found"]
    # nothing moved in the empty cycle
    assert not (result.out_dir / "cycles" / "00006" / "act").exists()
    # the ball was carried to the drop point and released there
    reached = json.loads((first / "act" / "log.json").read_text())["picks"][0]["reached"]
    names = [r["waypoint"] for r in reached]
    assert names.index("close") < names.index("place") < names.index("release")


def test_sigint_in_the_middle_of_a_motion_holds_the_arm_and_ends_the_loop(live):
    _, _, tmp = live
    out = tmp / "interrupted"
    # real-time motion (about 6 s a pick), so that the interrupt lands while the arm moves
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(PIPELINE),
        "--repeat",
        "0",
        "--out",
        str(out),
        "--cache-dir",
        str(tmp / "cache"),
        "--set",
        f"recording.ids={ORDER}",
        "--set",
        "act.sim_time_scale=1",
        # (what this test is about is the interrupt: a servo reply that a loaded machine delays
        # past dynamixel-sdk's wait must not end the run first)
        "--set",
        "act.reply_timeout_extra_ms=200",
    ]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(PIPELINE.parents[1])},
    )
    log = out / "cycles.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and not (log.exists() and log.read_text().strip()):
        time.sleep(0.1)
    time.sleep(2.0)  # cycle 2: the camera and the locating take ~0.1 s, the motion ~6 s
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "stopped by an interrupt during cycle 2 (node 'act')" in stdout
    run = json.loads((out / "run.json").read_text())
    assert run["loop"]["interrupted"] and run["loop"]["ok"] == 1
    servo = json.loads((out / "act" / "servo_log_interrupted.json").read_text())
    assert servo["stop"]["action"] == "hold" and servo["stop"]["port_closed"]
    # every goal the emulator received, the hold included, lies within the joint limits
    from nodes.contracts.arm import servo_limits_units
    from nodes.ik.arm import ArmParams, build_arm_model

    limits = servo_limits_units(build_arm_model(ArmParams()))
    sent = [c for c in servo["commands"] if c["register"] == "goal_position"]
    # the last goals sent: the hold
    assert {str(c["id"]): c["value"] for c in sent} == servo["stop"]["goals"]
    writes = [w for w in servo["sim"]["writes"] if w["register"] == "goal_position"] + sent
    assert len(writes) > len(sent)
    for w in writes:
        lo, hi = limits[str(w["id"])]
        assert lo <= w["value"] <= hi


def test_a_motion_that_fails_half_way_ends_the_loop_before_the_arm_moves_again(live):
    """Servo 4 stops answering in the middle of cycle 1's motion: torque goes off and the loop ends
    there -- the next cycle would reopen the port and move the arm as soon as every servo answered
    again, while a person may be at the arm reseating its connector."""
    _, _, tmp = live
    doc = load_pipeline(
        PIPELINE,
        [
            f"recording.ids={ORDER[:3]}",
            "act.sim_time_scale=20",
            "act.sim_faults={drop_reply_prob: 1.0, only_ids: [4], after_goal_writes: 12}",
        ],
    )
    loop = Loop(3)
    result = run_graph(
        build_graph(doc), cycles=loop, out_dir=tmp / "half-way", cache_dir=tmp / "cache"
    )
    assert len(loop.cycles) == 1, [c.line() for c in loop.cycles]
    first = loop.cycles[0]
    assert first.status == "failed" and first.failed_node == "act"
    assert "arm stopped during waypoint" in first.error and "Torque was turned off" in first.error
    assert "a person must see to it" in loop.stopped
    assert not loop.completed and result.reports["act"].status == "failed"
    lines = (result.out_dir / "cycles.jsonl").read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["failed_node"] == "act"
