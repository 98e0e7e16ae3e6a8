"""ik.pick_sequence refuses a ball whose centre lies less than one radius above the table.

The workspace box limits the tool point only: a location 1 cm above the table for a 2 cm ball (a
hand-eye or table frame off in z, a wrong radius) passed it, and the fingers would have been driven
into the table.
"""

import pytest

from nodes.actuators.log import LogParams, log
from nodes.calibrators.hand_eye import HandEyeParams, hand_eye
from nodes.disparity._common import DisparityParams, finish
from nodes.ik.analytic_3dof import AnalyticParams, analytic_3dof
from nodes.ik.arm import ArmParams, build_arm_model
from nodes.ik.pick_sequence import PickParams, pick_sequence
from nodes.locators.triangulate import TriangulateParams, triangulate
from stereograph.core.api import NodeError

ARM = build_arm_model(ArmParams())
# camera frame = arm-base frame: the location's z is the height over the base's mounting plane (the
# table)
HE = hand_eye(
    HandEyeParams(mode="given", camera_in_base={"translation_cm": [0, 0, 0], "rpy_deg": [0, 0, 0]})
)["hand_eye"]


def ball(z, sigma_z=0.02, radius=2.0, he=HE):
    loc = {
        "pair": "p1",
        "found": True,
        "reason": None,
        "x_cm": 17.0,
        "y_cm": 4.0,
        "z_cm": z,
        "frame": "left_camera",
        "sigma_z_cm": sigma_z,
        "object_radius_cm": radius,
    }
    return analytic_3dof(AnalyticParams(), arm=ARM, location=loc, hand_eye=he)["target"]


def test_a_ball_inside_the_table_is_refused_naming_height_radius_and_causes():
    with pytest.raises(
        NodeError, match=r"located 1\.00 cm above the table .*less than its radius 2\.00 cm"
    ) as e:
        pick_sequence(PickParams(), arm=ARM, target=ball(1.0))
    assert "hand-eye" in e.value.hint and "radius" in e.value.hint and "table frame" in e.value.hint
    # on_refuse: skip -> a refused plan, which the actuator never executes
    plan = pick_sequence(PickParams(on_refuse="skip"), arm=ARM, target=ball(1.0))["plan"]
    assert plan["refused"] and plan["waypoints"] == []
    with pytest.raises(NodeError, match="no pick plan to execute.*inside the table"):
        log(LogParams(), arm=ARM, plans=plan)


def test_the_tolerance_is_the_locations_own_uncertainty():
    exact = PickParams(table_tolerance_cm=0)  # the location's uncertainty alone
    # resting on the table, located 0.05 cm low: within 3 sigma (0.06 cm) -> picked, and the check
    # is recorded
    plan = pick_sequence(exact, arm=ARM, target=ball(1.95, sigma_z=0.02))["plan"]
    assert plan["table_check"]["radius_cm"] == 2.0 and plan["table_check"][
        "tolerance_cm"
    ] == pytest.approx(0.06)
    # 0.1 cm low with the same sigma: refused; with a less certain location (sigma 0.05 cm) it is
    # not
    with pytest.raises(NodeError, match="inside the table"):
        pick_sequence(exact, arm=ARM, target=ball(1.9, sigma_z=0.02))
    assert not pick_sequence(exact, arm=ARM, target=ball(1.9, sigma_z=0.05))["plan"]["refused"]
    # the hand-eye's fit residual counts too, and a documented extra allowance
    he = {**HE, "residual_cm": {"rms": 0.05}}
    assert not pick_sequence(exact, arm=ARM, target=ball(1.9, he=he))["plan"]["refused"]
    assert not pick_sequence(PickParams(table_tolerance_cm=0.2), arm=ARM, target=ball(1.9))["plan"][
        "refused"
    ]
    # by default a quarter of the radius more: a grasp 0.4 cm low still closes on a 2 cm ball, 0.6
    # cm is refused
    plan = pick_sequence(PickParams(), arm=ARM, target=ball(1.6))["plan"]
    assert plan["table_check"]["tolerance_cm"] == pytest.approx(0.56)
    with pytest.raises(NodeError, match=r"0\.56 cm allowed"):
        pick_sequence(PickParams(), arm=ARM, target=ball(1.4))


def test_radius_given_in_the_pick_wins_and_the_table_frame_is_used_when_known():
    # the segmenter looked for 2 cm, the ball is 3 cm: its centre 2 cm up means it is in the table
    with pytest.raises(NodeError, match="less than its radius 3.00 cm"):
        pick_sequence(PickParams(object_radius_cm=3.0), arm=ARM, target=ball(2.0))
    # the arm base stands on a 5 cm riser: base z -3 is 2 cm above the table (ok), base z -4 only 1
    # cm
    he = hand_eye(
        HandEyeParams(
            mode="given",
            camera_in_base={"translation_cm": [0, 0, 0], "rpy_deg": [0, 0, 0]},
            base_in_table={"translation_cm": [0, 0, 5], "rpy_deg": [0, 0, 0]},
        )
    )["hand_eye"]
    box = {"workspace_min_cm": [-28, -28, -10]}
    assert pick_sequence(PickParams(**box), arm=ARM, target=ball(-3.0, he=he))["plan"][
        "table_check"
    ]["height_above_table_cm"] == pytest.approx(2.0)
    with pytest.raises(NodeError, match=r"located 1\.00 cm above the table \(the table frame"):
        pick_sequence(PickParams(**box), arm=ARM, target=ball(-4.0, he=he))


def test_the_segmenters_radius_reaches_the_location():
    seg = {
        "id": "p1",
        "found": True,
        "split": None,
        "object_radius_cm": 2.5,
        "working_range_cm": [20, 80],
    }
    rect = {"f_px": 500.0, "cx_px": 320.0, "cy_px": 240.0, "baseline_cm": 8.0}
    d = finish(seg, 330.0, 250.0, 100.0, 0.05, "centroid", rect, DisparityParams())
    loc = triangulate(TriangulateParams(overlay=False), disparity=d, rectification=rect)["location"]
    assert loc["found"] and loc["object_radius_cm"] == 2.5
