"""The simulated table's physics (simbench.world): grasp, carry, release, push, a missed grasp."""

from __future__ import annotations

from simbench.world import new_world, read_world, step, write_world


def _world(**kw):
    balls = [
        {
            "id": "b1",
            "object": "red",
            "color_bgr": [40, 40, 210],
            "radius_cm": 2.0,
            "center_cm": [10, 0, 2],
        },
        {
            "id": "b2",
            "object": "red",
            "color_bgr": [40, 40, 210],
            "radius_cm": 2.0,
            "center_cm": [10, 8, 2],
        },
    ]
    places = [
        {
            "name": "red_place",
            "object": "red",
            "center_cm": [-10, 0],
            "radius_cm": 3.0,
            "height_cm": 3.0,
        }
    ]
    return new_world(balls, places, grasp_tolerance_cm=1.0, **kw)


def _ball(w, i):
    return next(b for b in w["balls"] if b["id"] == i)


def test_a_ball_grasped_is_carried_and_released_into_its_place():
    w = _world()
    step(w, [10, 0, 10], False)
    step(w, [10.4, 0, 2], False)  # open fingers come down around it: no push
    step(w, [10.4, 0, 2], True)
    assert _ball(w, "b1")["state"] == "held" and w["events"][-1]["what"] == "grasp"
    step(w, [10.4, 0, 12], True)
    assert _ball(w, "b1")["center_cm"] == [10.4, 0, 12]
    step(w, [-10, 0, 5.5], True)
    step(w, [-10, 0, 5.5], False)
    b = _ball(w, "b1")
    assert b["state"] == "placed" and b["place"] == "red_place" and w["events"][-1]["right"]
    assert not [e for e in w["events"] if e["what"] == "push"]


def test_a_gripper_closed_off_the_ball_holds_nothing_and_a_missed_grasp_fault_does_that():
    w = _world()
    step(w, [12.0, 0, 2], False)  # 2 cm off: beside the ball, not around it
    step(w, [12.0, 0, 2], True)
    assert w["events"][-1]["what"] == "closed on nothing" and w["gripper"]["holding"] is None
    w = _world(missed_grasps=1)
    step(w, [10, 0, 10], False)
    step(w, [10, 0, 2], False)
    step(w, [10, 0, 2], True)  # exactly on the centre, but the fault closes 2 cm off
    assert w["events"][-1]["what"] == "closed on nothing" and w["faults"]["missed_grasps"] == 0
    step(w, [10, 0, 10], True)  # lifted with closed fingers beside it: they may nudge it
    step(w, [10, 0, 10], False)
    again = _ball(w, "b1")["center_cm"]  # where looking again finds it
    step(w, again, False)
    step(w, again, True)
    assert w["events"][-1]["what"] == "grasp"


def test_fingers_and_a_carried_ball_push_what_they_sweep_through():
    w = _world()
    step(w, [0, 8, 2.5], True)  # closed fingers sweep along the table through b2
    step(w, [20, 8, 2.5], True)
    pushes = [e for e in w["events"] if e["what"] == "push"]
    assert [e["ball"] for e in pushes] == ["b2"] and pushes[0]["by"] == "fingers"
    assert abs(_ball(w, "b2")["center_cm"][1] - 8) > 2.0  # moved out of the path, sideways
    w = _world()
    step(w, [10, 0, 2], False)
    step(w, [10, 0, 2], True)
    step(w, [10, 8, 3], True)  # the carried ball runs into b2
    assert any(e["what"] == "push" and e["by"] == "carried ball b1" for e in w["events"])


def test_the_world_file_round_trips(tmp_path):
    w = _world()
    write_world(tmp_path / "world.json", w)
    assert read_world(tmp_path / "world.json") == w
