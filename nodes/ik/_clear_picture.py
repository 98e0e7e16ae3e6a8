"""The clear-table planner's picture of a cycle: the table as the left camera saw it (rectified),
each located ball with its label and place in the order, the refused ones with a short reason, and
the arm (drawn in the pose that grasps the next ball, or at home) projected from the arm-base
frame."""

from __future__ import annotations

import math

import cv2
import numpy as np

from nodes.contracts.arm import JOINTS, fk, geometry, joint
from nodes.contracts.overlay import label_pair
from nodes.contracts.views import pair_views

NEXT_BGR, LATER_BGR, REFUSED_BGR, ARM_BGR = (0, 200, 0), (255, 255, 255), (0, 0, 230), (0, 220, 255)


def arm_points_base(arm: dict, joints_deg: dict[str, float]) -> np.ndarray:
    """Base, shoulder, elbow and tool point (arm-base frame, cm) for joint angles in degrees."""
    h0, r0, l1, _, _, _ = geometry(arm)
    q = np.radians([joints_deg[n] for n in JOINTS])
    yaw = np.array([math.cos(q[0]), math.sin(q[0]), 0.0])
    shoulder = r0 * yaw + [0.0, 0.0, h0]
    elbow = shoulder + l1 * (math.cos(q[1]) * yaw + [0.0, 0.0, math.sin(q[1])])
    return np.array([[0.0, 0.0, 0.0], shoulder, elbow, fk(arm, q)])


def _project(points_base: np.ndarray, hand_eye: dict, rect: dict) -> np.ndarray:
    T = np.linalg.inv(np.asarray(hand_eye["T_base_from_left"], float))
    cam = points_base @ T[:3, :3].T + T[:3, 3]
    r = cam @ np.asarray(rect["R1"], float).T
    uvw = r @ np.asarray(rect["P1"], float)[:, :3].T
    return uvw[:, :2] / uvw[:, 2:3]


def draw_cycle(
    pair: dict,
    rect: dict,
    targets: list[dict],
    status: dict,
    arm: dict,
    hand_eye: dict,
    plan: dict | None,
    raw: bool,
) -> np.ndarray:
    """The cycle's picture (BGR uint8): see the module docstring."""
    view, _ = pair_views(rect, np.asarray(pair["left"]), np.asarray(pair["right"]), raw)
    img = view.full().copy()
    order = {p: k + 1 for k, p in enumerate(status["order"])}
    for t in targets:
        if t.get("u_left_px") is None:
            continue
        u, v = int(round(t["u_left_px"])), int(round(t["v_left_px"]))
        if t["pair"] == status["next"]:
            colour, text = NEXT_BGR, f"1 {t.get('object')} next"
        elif t["pair"] in order:
            colour, text = LATER_BGR, f"{order[t['pair']]} {t.get('object')}"
        else:
            colour, text = (
                REFUSED_BGR,
                f"{t.get('object')}: {(status['not_pickable'].get(t['pair']) or '')[:28]}",
            )
        cv2.circle(img, (u, v), 5, colour, 2)
        cv2.putText(
            img, text, (u + 8, v - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA
        )
    grasp = (
        plan["waypoints"][plan["grasp_index"]]["joints_deg"]
        if plan
        else {n: joint(arm, n)["home_deg"] for n in JOINTS}
    )
    uv = _project(arm_points_base(arm, grasp), hand_eye, rect)
    if np.all(np.isfinite(uv)) and np.all(np.abs(uv) < 1e5):
        pts = np.round(uv).astype(np.int32)
        cv2.polylines(img, [pts], False, ARM_BGR, 3, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, tuple(int(c) for c in p), 4, ARM_BGR, -1)
    la = status.get("look_again") or {}
    detail = (
        f"cycle {status['cycle']}: {status['found']} ball(s) to place, picked {status['picked']}, "
        f"retries {status['retries']}" + (f"; last pick: {la.get('verdict')}" if la else "")
    )
    return label_pair(
        img, pair.get("id"), True, None, detail + ("" if plan else f"; {status.get('why')}")
    )
