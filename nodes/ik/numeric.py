"""``ik.numeric``: damped-least-squares inverse kinematics on the arm's chain (see
``_solvers.numeric_ik_batch``)."""

from __future__ import annotations

from typing import Literal

from stereograph.api import Field, In, Out, Params, node

from ._target import joint_target, warn_unreachable


class NumericParams(Params):
    on_unreachable: Literal["error", "skip"] = Field(
        "error",
        description="error: fail this item; skip: output found=false with the reason (the pick "
        "refuses it).",
    )
    tol_cm: float = Field(
        1e-4, gt=0, le=1.0, description="Convergence tolerance on the tool point (cm)."
    )
    max_iter: int = Field(100, ge=1, le=10000, description="Iterations per seed.")
    damping_cm: float = Field(
        1.0, gt=0, le=1000, description="Initial damping lambda (cm; Jacobian in cm/rad)."
    )
    n_random_seeds: int = Field(
        12, ge=0, le=1000, description="Random restarts after the grid / home seeds."
    )
    seed: int = Field(
        0, ge=0, description="Random seed of the restarts (results are reproducible)."
    )


@node(
    "ik.numeric",
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
    params=NumericParams,
    version="1",
)
def numeric(params: NumericParams, arm, location, hand_eye, ctx=None):
    """Damped-least-squares IK on the arm chain, joint limits by projection, seeded restarts."""
    solver = {"type": "numeric", "params": params.model_dump(exclude={"on_unreachable"})}
    target = joint_target(arm, location, hand_eye, solver, on_unreachable=params.on_unreachable)
    warn_unreachable(ctx, target)
    return {"target": target}
