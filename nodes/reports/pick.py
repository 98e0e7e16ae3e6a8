"""``report.pick``: the arm drawn at the grasp pose, with the ball and the workspace box, and its
servo table.

A stick figure from forward kinematics (base, shoulder, elbow, tool point; the same geometry as
``ik``'s ``fk``), side view (radial distance vs height, in the arm's plane) and top view (x, y),
for the pick the actuator executed when its ``log`` is wired, else the first plan not refused of the
chosen split (the actuator's own default choice; wiring ``log`` would make the actuator a
non-terminal node, whose summary a run then does not keep). The
ball is drawn at its located centre with its radius, and the true centre when there is one. The
table lists every joint at the grasp: angle (deg), servo ids, goal positions and speeds (AX-12A
units). Refused plans are counted, with their reasons, in the table's title.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from nodes.contracts.arm import geometry
from nodes.contracts.drawing import figure_bgr, load_figures, new_figure
from stereograph.api import Field, In, NodeError, Out, Params, node


class PickReportParams(Params):
    """Parameters of ``report.pick``."""

    ball_radius_cm: float = Field(
        2.0, gt=0, le=50, description="Radius of the ball drawn at the target (cm)."
    )
    split: Literal["test", "train", "all"] = Field(
        "test",
        description="Without a wired log: draw the first plan not refused of this split (name).",
    )


def chain_points(arm: dict, joints_deg: dict) -> np.ndarray:
    """Base, shoulder-column top, shoulder axis, elbow, forearm end and tool point (cm, arm-base
    frame), (6, 3)."""
    h0, r0, l1, a, b, _ = geometry(arm)
    q0, q1, q2 = (math.radians(float(joints_deg[k])) for k in ("yaw", "shoulder", "elbow"))
    phi = q1 + q2
    rz = [(0.0, 0.0), (0.0, h0), (r0, h0), (r0 + l1 * math.cos(q1), h0 + l1 * math.sin(q1))]
    fe = (rz[-1][0] + a * math.cos(phi), rz[-1][1] + a * math.sin(phi))
    rz += [fe, (fe[0] - b * math.sin(phi), fe[1] + b * math.cos(phi))]
    return np.array([[r * math.cos(q0), r * math.sin(q0), z] for r, z in rz])


def arm_figure(arm: dict, plan: dict, params: PickReportParams) -> np.ndarray:
    """Side and top views of the arm at the grasp, with the ball and the workspace box."""
    from matplotlib.patches import Circle

    g = plan["waypoints"][plan["grasp_index"]]
    pts = chain_points(arm, g["joints_deg"])
    target = np.asarray(plan["target_base_cm"], float)
    truth = plan.get("truth_base_cm")
    # the box ik.pick_sequence checked this plan against (absent: not drawn)
    box = plan.get("workspace_cm")
    yaw = math.radians(float(g["joints_deg"]["yaw"]))
    fig = new_figure(8, 4.6)  # 720 px: report.html's figure width, so the text is not scaled down
    fig.set_layout_engine("constrained")
    side, top = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    _draw_side(side, pts, yaw, target, params.ball_radius_cm)
    if box is not None:
        _draw_workspace(side, top, box)
    side.axhline(0, color="k", lw=0.8)
    side.set_xlabel("distance from the base axis, in the arm's plane (cm)")
    side.set_ylabel("height z (cm)")
    side.set_title("side view", fontsize=10)
    side.set_aspect("equal", adjustable="datalim")
    top.plot(pts[:, 0], pts[:, 1], "-o", color="#34495e", lw=3, ms=5)
    top.add_patch(Circle((target[0], target[1]), params.ball_radius_cm, color="#e67e22", alpha=0.6))
    if truth is not None:
        _draw_truth(side, top, truth, yaw)
    top.set_xlabel("x (cm, arm base)")
    top.set_ylabel("y (cm, arm base)")
    top.set_title("top view", fontsize=10)
    top.set_aspect("equal", adjustable="datalim")
    # under the views: inside, it hid the workspace box
    handles, labels = side.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=8, frameon=False)
    fk_pt = plan.get("grasp_fk_cm") or pts[-1].tolist()
    fig.suptitle(
        f"pick {plan.get('pair')}: ball at [{target[0]:.2f}, {target[1]:.2f}, "
        f"{target[2]:.2f}] cm (arm base), "
        f"tool at [{fk_pt[0]:.2f}, {fk_pt[1]:.2f}, {fk_pt[2]:.2f}] cm",
        fontsize=10,
    )
    return figure_bgr(fig)


def _draw_side(side, pts: np.ndarray, yaw: float, target: np.ndarray, radius_cm: float) -> None:
    """The side view: the plane of the arm (radial distance along the yaw direction vs height),
    with the ball and the tool point."""
    from matplotlib.patches import Circle

    radial = pts[:, 0] * math.cos(yaw) + pts[:, 1] * math.sin(yaw)
    side.plot(
        radial, pts[:, 2], "-o", color="#34495e", lw=3, ms=5, label="arm (forward kinematics)"
    )
    t_r = target[0] * math.cos(yaw) + target[1] * math.sin(yaw)
    side.add_patch(
        Circle(
            (t_r, target[2]),
            radius_cm,
            color="#e67e22",
            alpha=0.6,
            label="ball (located)",
        )
    )
    side.plot(
        [pts[-1, 0] * math.cos(yaw) + pts[-1, 1] * math.sin(yaw)],
        [pts[-1, 2]],
        "x",
        color="red",
        ms=10,
        mew=2,
        label="tool point",
    )


def _draw_workspace(side, top, box: dict) -> None:
    """The workspace box ik.pick_sequence checked the plan against, dashed, in both views."""
    from matplotlib.patches import Rectangle

    lo, hi = np.asarray(box["min"], float), np.asarray(box["max"], float)
    side.add_patch(
        Rectangle(
            (lo[0], lo[2]),
            hi[0] - lo[0],
            hi[2] - lo[2],
            fill=False,
            ls="--",
            color="#7f8c8d",
            label="workspace box (x extent)",
        )
    )
    top.add_patch(
        Rectangle(
            (lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, ls="--", color="#7f8c8d"
        )
    )


def _draw_truth(side, top, truth, yaw: float) -> None:
    """The ball's true centre in both views (the side view in the arm's plane at ``yaw``)."""
    top.plot([truth[0]], [truth[1]], "+", color="green", ms=12, mew=2, label="true centre")
    side.plot(
        [truth[0] * math.cos(yaw) + truth[1] * math.sin(yaw)],
        [truth[2]],
        "+",
        color="green",
        ms=12,
        mew=2,
        label="true centre",
    )


def servo_table(arm: dict, plan: dict, n_refused: int, reasons: list[str]) -> dict:
    """Joint / servo table at the grasp, as a *table* value (report.html renders it)."""
    g = plan["waypoints"][plan["grasp_index"]]
    rows = []
    for j in arm["joints"]:
        name = j["name"]
        ids = [s["id"] for s in j["servos"]]
        rows.append(
            [
                name,
                round(float(g["joints_deg"].get(name, float("nan"))), 2),
                f"{j['min_deg']:g} .. {j['max_deg']:g}",
                ", ".join(str(i) for i in ids),
                ", ".join(str(g["servo_units"].get(str(i), "")) for i in ids),
                ", ".join(str(g.get("speed_units", {}).get(str(i), "")) for i in ids),
            ]
        )
    title = f"Joints and servos at the grasp of {plan.get('pair')}"
    if plan.get("target_base_cm") is not None:  # where the ball was: what a person checks first
        x, y, z = (float(v) for v in plan["target_base_cm"])
        title += f": ball at ({x:.2f}, {y:.2f}, {z:.2f}) cm in the arm-base frame"
        if plan.get("sigma_z_cm") is not None:
            title += f", sigma_z {float(plan['sigma_z_cm']):.2f} cm"
    if n_refused:
        title += f"; {n_refused} other plans refused (first: {reasons[0]})"
    return {
        "title": title,
        "columns": [
            "joint",
            "angle (deg)",
            "limits (deg)",
            "servo ids",
            "goal (units)",
            "speed (units)",
        ],
        "rows": rows,
    }


@node(
    "report.pick",
    inputs={
        "arm": In("ArmModel"),
        "plans": In("PickPlan", gather=True),
        "log": In("ServoLog", optional=True, description="Which plan the actuator executed."),
    },
    outputs={
        "arm_figure": Out(
            "Image",
            save=True,
            headline=True,
            description="Arm at the grasp pose: side and top views (cm).",
        ),
        "servo_table": Out(
            "any",
            save=True,
            headline=True,
            description="Joint angles (deg) and servo goals (units) at the grasp (a table).",
        ),
    },
    params=PickReportParams,
    version="2",
    prepare=load_figures,
)
def pick(params: PickReportParams, arm: dict, plans, log: dict | None = None, ctx=None) -> dict:
    """Picture of the arm at the grasp (forward kinematics, side and top views) and its joint /
    servo table."""
    plans = list(plans.values()) if isinstance(plans, dict) else list(plans)
    ok = [p for p in plans if not p.get("refused")]
    refused = [p for p in plans if p.get("refused")]
    executed = {str(p.get("pair")) for p in (log or {}).get("picks", [])}
    in_split = [p for p in ok if params.split == "all" or p.get("split") == params.split]
    chosen = next((p for p in ok if str(p.get("pair")) in executed), (in_split or ok or [None])[0])
    if chosen is None:
        raise NodeError(
            f"no pick to draw: all {len(plans)} plans were refused"
            + (f" (first: {refused[0].get('reason')})" if refused else ""),
            hint="see ik.pick_sequence's reasons in run.json; nothing was picked",
        )
    return {
        "arm_figure": arm_figure(arm, chosen, params),
        "servo_table": servo_table(
            arm, chosen, len(refused), [str(p.get("reason")) for p in refused]
        ),
    }
