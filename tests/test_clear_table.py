"""pipelines/clear-table.yaml on the simulated bench: every ball placed by colour, a missed grasp
seen and retried, a ball out of reach reported while the others are cleared, Ctrl-C mid-carry holds
the ball."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stereograph.app.loop import Loop
from stereograph.core.config import load_pipeline
from stereograph.core.graph import build_graph
from stereograph.core.runner import run_graph

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ROOT / "pipelines" / "clear-table.yaml"
FAST = ["act.sim_time_scale=30"]

pytestmark = pytest.mark.slow


def _clear(tmp_path: Path, sets: list[str], name: str) -> tuple[Loop, dict, list[dict]]:
    doc = load_pipeline(PIPELINE, FAST + sets)
    loop = Loop(doc.repeat)
    run_graph(build_graph(doc), cycles=loop, out_dir=tmp_path / name, cache_dir=tmp_path / "cache")
    world = json.loads((tmp_path / name / "bench" / "world.json").read_text())
    cycles = [
        json.loads(line) for line in (tmp_path / name / "cycles.jsonl").read_text().splitlines()
    ]
    return loop, world, cycles


def test_the_default_table_of_four_balls_of_two_colours_is_cleared(tmp_path):
    loop, world, cycles = _clear(tmp_path, [], "default")
    assert (
        loop.stopped
        == "stopped by node 'plan': the table is clear (4 picked and placed, 0 retried)"
    )
    assert loop.completed
    assert len(world["balls"]) == 4 and len({b["object"] for b in world["balls"]}) == 2
    assert all(
        b["state"] == "placed" and b["place"] == f"{b['object']}_place" for b in world["balls"]
    )
    assert not [e for e in world["events"] if e["what"] == "push"]
    grasps = [e for e in world["events"] if e["what"] == "grasp"]
    assert len(grasps) == 4 and max(e["off_cm"] for e in grasps) < 0.5
    assert [c["status"] for c in cycles] == ["ok"] * 5  # four picks, then the look that finds none


def test_a_missed_grasp_is_seen_by_looking_again_and_retried(tmp_path):
    loop, world, cycles = _clear(
        tmp_path,
        [
            "bench.missed_grasps=1",
            "bench.balls=[{object: orange, center_cm: "
            "[4, 14]}, {object: blue, center_cm: [-6, 15]}]",
        ],
        "miss",
    )
    assert [e["what"] for e in world["events"]][0] == "closed on nothing"
    verdicts = [c["values"]["plan.status"]["look_again"] for c in cycles]
    assert verdicts[1]["verdict"] == "retry" and verdicts[2]["verdict"] == "gone"
    assert cycles[-1]["values"]["plan.status"]["retries"] == 1
    assert all(b["state"] == "placed" for b in world["balls"])
    assert loop.stopped.endswith("the table is clear (2 picked and placed, 1 retried)")


def test_a_ball_out_of_reach_is_reported_and_the_others_are_cleared(tmp_path):
    balls = (
        "[{object: orange, center_cm: [4, 14]}, {object: blue, center_cm: [26, 10]}, "
        "{object: blue, center_cm: [-6, 15]}]"
    )
    loop, world, cycles = _clear(tmp_path, [f"bench.balls={balls}"], "reach")
    far = next(b for b in world["balls"] if b["center_cm"][0] == 26)
    assert far["state"] == "table" and [e for e in world["events"] if e["ball"] == far["id"]] == []
    assert all(b["state"] == "placed" for b in world["balls"] if b is not far)
    status = cycles[-1]["values"]["plan.status"]
    assert loop.stopped == (
        "stopped by node 'plan': 1 ball(s) left that cannot be picked (2 picked and placed, "
        "0 retried)"
    )
    (why,) = status["not_pickable"].values()
    assert "reach" in why


def test_ctrl_c_while_carrying_a_ball_holds_the_arm_with_the_ball(tmp_path):
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "stereograph",
            "run",
            str(PIPELINE),
            "--out",
            str(out),
            "--cache-dir",
            str(tmp_path / "cache"),
            "--set",
            "act.sim_time_scale=2",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    world_path = out / "bench" / "world.json"
    deadline = time.time() + 120
    while time.time() < deadline:
        if world_path.exists():
            try:
                if any(e["what"] == "grasp" for e in json.loads(world_path.read_text())["events"]):
                    break
            except (json.JSONDecodeError, OSError):
                pass
        time.sleep(0.05)
    time.sleep(0.3)  # on its way to the bin
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "stopped by an interrupt during cycle 1 (node 'act')" in stdout
    servo = json.loads((out / "act" / "servo_log_interrupted.json").read_text())
    assert servo["stop"]["action"] == "hold"
    world = json.loads(world_path.read_text())
    held = [b for b in world["balls"] if b["state"] == "held"]
    # up in the gripper
    assert len(held) == 1 and world["gripper"]["closed"] and held[0]["center_cm"][2] > 3.0


def test_a_place_on_the_table_in_view_is_checked_and_its_balls_left_there(tmp_path):
    objects = (
        "objects.objects=[{name: orange, radius_cm: 2.0, color_bgr: [20, 120, 245], "
        "drop_place_cm: [-10, -12, "
        "0]}, {name: blue, radius_cm: 2.0, color_bgr: [200, 90, 30], drop_place_cm: "
        "[15.0, -6.0, 3.0]}]"
    )
    balls = (
        "bench.balls=[{object: orange, center_cm: [4, 14]}, {object: orange, center_cm: [-6, 15]}]"
    )
    loop, world, cycles = _clear(tmp_path, [objects, balls], "spot")
    assert all(b["state"] == "placed" and b["place"] == "orange_place" for b in world["balls"])
    verdicts = [c["values"]["plan.status"]["look_again"] for c in cycles[1:]]
    assert [v["verdict"] for v in verdicts] == ["gone", "gone"] and all(
        v["seen_at_place"] for v in verdicts
    )
    # both seen at their place: nothing to pick
    assert cycles[-1]["values"]["plan.status"]["found"] == 0
    assert loop.stopped.endswith("the table is clear (2 picked and placed, 0 retried)")


@pytest.mark.parametrize("seed, n", [(36, 5), (1013, 6)])
def test_touching_balls_of_one_colour_are_each_located_and_cleared(tmp_path, seed, n):
    """(touching balls of one colour merge into one region: in both views, and the two views'
    partial fits took different balls -- benchmarks/clear_table.py's table 36, three blue balls
    touching; or in the right view only, so the left's whole balls had no round partner -- table
    1013. Each left the cluster on the table; both fail with the masked retry turned off)"""
    sets = [f"bench.seed={seed}", f"bench.n_balls=[{n}, {n}]", "bench.touching_fraction=0.4"]
    loop, world, cycles = _clear(tmp_path, sets, "cluster")
    assert all(
        b["state"] == "placed" and b["place"] == f"{b['object']}_place" for b in world["balls"]
    )
    assert max(e["off_cm"] for e in world["events"] if e["what"] == "grasp") < 0.5
    assert not [e for e in world["events"] if e["what"] == "push"]
    assert loop.stopped.endswith(f"the table is clear ({n} picked and placed, 0 retried)")
