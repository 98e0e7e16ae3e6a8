"""``ik.analytic_3dof``: closed-form inverse kinematics of the 3-DOF arm (see
``_solvers.analytic_ik``)."""

from __future__ import annotations

from typing import Literal

from stereograph.api import Field, In, Out, Params, node

from ._target import joint_target, warn_unreachable


class AnalyticParams(Params):
    on_unreachable: Literal["error", "skip"] = Field(
        "error",
        description="error: fail this item; skip: output found=false with the reason (the pick "
        "refuses it).",
    )
    elbow: Literal["up", "down", "auto"] = Field(
        "auto",
        description="Elbow configuration; auto = elbow-up, else elbow-down if up leaves the "
        "joint limits.",
    )
    allow_back: bool = Field(
        True,
        description="Allow reaching backwards over the base (yaw + 180 deg) when the "
        "front poses leave the joint limits.",
    )


@node(
    "ik.analytic_3dof",
    inputs={
        "arm": In("ArmModel"),
        "location": In("Location", description="Located object (per item)."),
        "hand_eye": In("HandEye", description="Left-camera pose in the arm-base frame."),
    },
    outputs={
        "target": Out(
            "JointTarget", description="Joint angles (deg) and servo goals for the object."
        )
    },
    params=AnalyticParams,
    version="1",
)
def analytic_3dof(params: AnalyticParams, arm, location, hand_eye, ctx=None):
    """Closed-form IK: yaw = atan2, planar two-link law of cosines, elbow up/down; 'unreachable'
    errors."""
    solver = {
        "type": "analytic_3dof",
        "params": {"elbow": params.elbow, "allow_back": params.allow_back},
    }
    target = joint_target(arm, location, hand_eye, solver, on_unreachable=params.on_unreachable)
    warn_unreachable(ctx, target)
    return {"target": target}
