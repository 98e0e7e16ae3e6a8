"""pipelines/pick-live.yaml --repeat: successive balls picked from a recorded camera on the emulated servos."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereograph.config import load_pipeline
from stereograph.graph import build_graph
from stereograph.loop import Loop
from stereograph.runner import run_graph

PIPELINE = Path(__file__).resolve().parents[1] / "pipelines" / "pick-live.yaml"
ORDER = ["s000", "s001", "s002", "s003", "s004", "empty000", "s005"]


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """Seven cycles: five balls, a frame without one, then another ball."""
    tmp = tmp_path_factory.mktemp("live")
    doc = load_pipeline(PIPELINE, [f"recording.ids={ORDER}", "act.sim_time_scale=20"])
    loop = Loop(len(ORDER))
    result = run_graph(build_graph(doc), cycles=loop, out_dir=tmp / "run", cache_dir=tmp / "cache")
    return loop, result


def test_five_balls_in_a_row_each_grasped_within_half_a_centimetre(live):
    loop, _ = live
    assert loop.completed and [c.values["cam.pairs"]["id"] for c in loop.cycles] == ORDER
    picked = loop.cycles[:5] + loop.cycles[6:]
    for c in picked:
        assert c.status == "ok", c.line()
        plan, summary = c.values["pick.plan"], c.values["act.summary"]["picks"][0]
        # the grasp point the commanded servo goals put the tool at, against the true ball centre
        err = np.linalg.norm(np.subtract(plan["grasp_fk_cm"], plan["truth_base_cm"]))
        assert err < 0.5, (c.index, err)
        assert summary["ok"] and summary["grasp_servo_goals"] == plan["waypoints"][plan["grasp_index"]]["servo_units"]
        assert c.values["compensate.location"]["sigma_z_cm"] > 0
        assert c.values["cam.pairs"]["skew_ms"] == 0.0
        assert set(c.nodes) >= {"cam", "segment", "locate", "compensate", "ik", "pick", "act"}
    # cycle 1 also loaded the files and recorded the camera; later cycles ran only the live part
    assert "calibration" not in loop.cycles[1].nodes and loop.live[0] == "cam"


def test_a_frame_without_a_ball_moves_nothing_and_the_loop_goes_on(live):
    loop, _ = live
    empty = loop.cycles[5]
    assert empty.status == "failed" and empty.failed_node == "pick"
    assert "not located" in empty.error and "refusing to move the arm" in empty.error
    assert "act" not in empty.nodes or empty.nodes["act"]["status"] == "skipped"  # the servos were never opened
    assert "act.log" not in empty.values
    assert loop.cycles[6].status == "ok"


def test_the_run_folder_has_the_cycle_log_and_the_recording(live):
    loop, result = live
    lines = (result.out_dir / "cycles.jsonl").read_text().splitlines()
    assert len(lines) == len(ORDER)
    assert (result.out_dir / "cam" / "recording" / "left.avi").stat().st_size > 0
