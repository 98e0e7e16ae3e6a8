"""pipelines/pick.yaml through the engine: synthetic rig -> ... -> IK -> pick on the emulated
servos."""

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dynamixel_sdk")

from stereograph.core.runner import run_pipeline  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_pick_pipeline_end_to_end(tmp_path):
    r = run_pipeline(
        ROOT / "pipelines" / "pick.yaml",
        overrides=["rig.n_scenes=24", "rig.n_views=10", "act.sim_time_scale=20"],
        cache_dir=tmp_path / "cache",
        out_dir=tmp_path / "out",
    )
    assert r.ok, {n: (rep.status, rep.error) for n, rep in r.reports.items() if rep.error}
    summary = r.outputs("act", "summary")
    (pick,) = summary["picks"]
    assert pick["ok"] and set(pick["grasp_servo_goals"]) == {"1", "2", "3", "4", "5"}
    assert pick["servo_commands"] > 0 and len(pick["object_base_cm"]) == 3
    log = r.outputs("act", "log")
    assert log["ok"] and log["picks"][0]["sim"]["writes"]
    assert (tmp_path / "out" / "act").exists()
    plans = r.outputs("pick", "plan") if r.outputs("pick", "plan") else {}
    for plan in plans.values():
        if not plan.get("refused") and plan.get("truth_base_cm") is not None:
            assert np.linalg.norm(np.subtract(plan["grasp_fk_cm"], plan["truth_base_cm"])) < 0.5


def test_actuator_refuses_when_nothing_is_pickable():
    from nodes.actuators._plan import Selection, select_plans
    from stereograph.core.api import NodeError

    plans = {
        "a": {
            "pair": "a",
            "refused": True,
            "reason": "the object was not located",
            "waypoints": [],
        },
        "b": {"pair": "b", "refused": False, "split": "train", "waypoints": [{}]},
    }
    with pytest.raises(NodeError, match="no pick plan to execute.*not located"):
        select_plans(plans, Selection(split="test"))
    chosen, skipped = select_plans(plans, Selection(split="all"))
    assert [p["pair"] for p in chosen] == ["b"] and skipped["a"].startswith("refused")


@pytest.mark.slow
def test_a_refused_calibration_check_moves_no_arm(tmp_path):
    """pick.yaml reads its rectification through rectifier.check: a refused check skips everything
    downstream, the actuator included (here refused by a threshold no real rig meets)."""
    from stereograph.core.runner import run_pipeline

    root = Path(__file__).resolve().parents[1]
    res = run_pipeline(
        root / "pipelines" / "pick.yaml",
        [
            "rig.n_scenes=16",
            "rig.n_views=10",
            "check.warn_dy_px=0.00001",
            "check.refuse_dy_px=0.00002",
        ],
        cache_dir=tmp_path / "c",
        out_dir=tmp_path / "o",
    )
    st = res.status
    assert st["check"] == "failed" and "a camera moved" in res.reports["check"].error
    assert st["act"] == "skipped" and st["segment"] == "skipped"
    assert not (res.out_dir / "act").exists()
