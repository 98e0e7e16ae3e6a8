"""Ctrl-C / SIGTERM in the middle of a motion ends it safely (issue 11 item 2), through the CLI.

The emulator runs as its own process (``stereograph servo-sim --trace --log``), so what the servos
received and their final state are observed from outside the process that was interrupted. The
pick runs through ``stereograph run`` in a subprocess; the signal is sent once the emulator has
accepted the first goal (the motion is in real time: each waypoint takes about a second).
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("dynamixel_sdk")

from nodes.contracts.arm import joints_to_servo_units, servo_limits_units  # noqa: E402
from nodes.ik.arm import ArmParams, build_arm_model  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "tests" / "plugins" / "fixed_location.py"
CLI = [sys.executable, "-c", "import sys; from stereograph.app.cli import main; sys.exit(main())"]
ARM = build_arm_model(ArmParams())

PIPELINE = f"""
name: stop
plugins: [{PLUGIN}]
nodes:
  loc: {{type: toy.fixed_location}}
  hand_eye:
    type: calibrator.hand_eye
    params: {{mode: given, camera_in_base: {{translation_cm: [0, 0, 0], rpy_deg: [0, 0, 0]}}}}
  arm: {{type: ik.arm}}
  ik:
    type: ik.analytic_3dof
    inputs: {{arm: arm.arm, location: loc.location, hand_eye: hand_eye.hand_eye}}
  pick:
    type: ik.pick_sequence
    params: {{return_home: true}}
    inputs: {{arm: arm.arm, target: ik.target}}
  act:
    type: actuator.dynamixel
    params: {{port: /dev/null, retries: 2}}
    inputs: {{arm: arm.arm, plans: pick.plan}}
"""


def _wait_line(proc, needle: str, timeout_s: float) -> list[str]:
    """Lines of ``proc``'s stdout up to and including the first that contains ``needle``."""
    lines, end = [], time.monotonic() + timeout_s
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if needle in line:
            return lines
    raise AssertionError(f"no {needle!r} from the emulator within {timeout_s} s: {lines[-5:]}")


@pytest.mark.slow
@pytest.mark.parametrize("sig, mode", [(signal.SIGINT, "hold"), (signal.SIGTERM, "rest")])
def test_interrupt_mid_motion_ends_safely(tmp_path, sig, mode):
    link = tmp_path / "ttyDXL"
    sim_log = tmp_path / "sim.json"
    (tmp_path / "stop.yaml").write_text(PIPELINE)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    sim = subprocess.Popen(
        [*CLI, "servo-sim", "--ids", "1-5", "--link", str(link), "--trace", "--log", str(sim_log)],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    run = None
    try:
        _wait_line(sim, "AX-12A emulator", 60)
        run = subprocess.Popen(
            [
                *CLI,
                "run",
                str(tmp_path / "stop.yaml"),
                "--no-cache",
                "--out",
                str(tmp_path / "out"),
                "--set",
                f"act.port={link}",
                "--set",
                f"act.on_interrupt={mode}",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            cwd=ROOT,
        )
        _wait_line(sim, "goal_position", 120)
        time.sleep(0.4)  # mid-way to the first waypoint (about 1 s at 60 deg/s)
        run.send_signal(sig)
        out, err = run.communicate(timeout=60)
        time.sleep(0.3)  # anything still moving would move on now
    finally:
        if run is not None and run.poll() is None:
            run.kill()
        sim.send_signal(signal.SIGTERM)
        sim.communicate(timeout=30)
    assert run.returncode == 130, (out, err)
    assert "during 'open'" in err and "port" in err and "closed" in err, err
    state = json.loads(sim_log.read_text())
    writes, servos = state["writes"], state["servos"]
    lim = servo_limits_units(ARM)
    goals = [w for w in writes if w["register"] == "goal_position"]
    assert all(lim[str(w["id"])][0] <= w["value"] <= lim[str(w["id"])][1] for w in goals)
    assert all(w["accepted"] for w in writes)
    # the first waypoint's goals went out once, then the stop's goals: no later waypoint was started
    first = goals[:5]
    stop_goals = {w["id"]: w["value"] for w in goals[5:]}
    assert len(goals) == 10 and sorted(stop_goals) == [1, 2, 3, 4, 5], goals
    for sid, s in servos.items():
        assert s["torque_enable"] == 1 and s["moving"] == 0, (sid, s)
        assert abs(s["present_position"] - stop_goals[int(sid)]) <= 1
    if mode == "hold":
        # held where it was: short of the first waypoint for the joints that had far to go
        planned = {w["id"]: w["value"] for w in first}
        assert any(abs(planned[i] - stop_goals[i]) > 20 for i in planned), (planned, stop_goals)
        assert "held at the present positions" in err
    else:
        home = {j["name"]: j["home_deg"] for j in ARM["joints"] if j["name"] != "gripper"}
        rest = {int(k): v for k, v in joints_to_servo_units(ARM, home).items()}
        assert all(abs(stop_goals[i] - rest[i]) <= 1 for i in rest) and "rest pose" in err
    saved = json.loads((tmp_path / "out" / "act" / "servo_log_interrupted.json").read_text())
    assert saved["stop"]["action"] == mode and saved["stop"]["port_closed"] is True
    assert saved["stop"]["cause"] == ("SIGTERM" if sig == signal.SIGTERM else "Ctrl-C (SIGINT)")
