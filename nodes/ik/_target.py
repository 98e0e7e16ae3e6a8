"""Shared by the IK nodes: a located object -> a target in the arm-base frame -> a JointTarget.

JointTarget (per item)::

    {"pair": str, "found": bool, "reason": str | None, "extrapolated": bool,
     "unreachable": bool,                                    # located, but out of this arm's reach
                                                             # / limits
     "hint": str | None,                                     # the fix, when unreachable
     "location_cm": [x, y, z] | None, "frame": str,        # as located (camera or table frame)
     "target_base_cm": [x, y, z] | None,                     # the tool-point target, arm-base frame
     "truth_base_cm": [x, y, z] | None,                      # true ball centre, arm-base frame (rig
                                                             # truth)
     "joints_deg": {"yaw", "shoulder", "elbow": float} | None,
     "servo_units": {str(id): int} | None,                   # goal positions of the joint servos
     "fk_cm": [x, y, z] | None,                              # tool point of the quantised servo
                                                             # goals
     "solver": {"type": "analytic_3dof" | "numeric", "params": {...}},
     "object_radius_cm": float | None,                       # the ball's radius (the segmenter's),
                                                             # when known
     "sigma_z_cm": float | None,                             # the location's depth uncertainty
     "hand_eye_rms_cm": float | None,                        # the hand-eye fit's RMS residual
                                                             # (fitted modes)
     "height_above_table_cm": float | None,                  # the centre's height over the table
                                                             # frame's z = 0,
                                                             #   when the hand-eye places the base
                                                             # in it
     "split": str (copied when present)}
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from nodes.contracts.arm import JOINTS, fk, joints_to_servo_units, quantize_joints_deg
from stereograph.api import NodeError

from ._solvers import Unreachable, analytic_ik, numeric_ik

SOLVERS = {"analytic_3dof": analytic_ik, "numeric": numeric_ik}

ARM_HINT = (
    "check the arm's link lengths (ik.arm `links`), where it stands (calibrator.hand_eye "
    "`base_in_table`) "
    "and the hand-eye transform; if they are right, place the object within the arm's reach"
)


def unreachable_reason(e: Unreachable) -> str:
    """The solver's message as a refusal reason: the object was located, this arm cannot reach
    it."""
    msg = e.message.rstrip(".")
    return (
        "unreachable for this arm" + msg[len("unreachable") :]
        if msg.startswith("unreachable")
        else msg
    )


def unreachable_hint(e: Unreachable) -> str:
    """The fix for an unreachable target: the arm's geometry and placement first, then the solver's
    advice."""
    if "joint limits" in e.message and e.hint:
        return f"{e.hint.rstrip('.')}; or {ARM_HINT}."
    return f"{ARM_HINT}."


def solve(model: dict[str, Any], p, solver: dict[str, Any], q_init=None) -> np.ndarray:
    """Joint angles (rad) for tool point ``p`` (cm, arm-base frame) with the named solver and its
    params."""
    kw = dict(solver.get("params") or {})
    if solver["type"] == "numeric" and q_init is not None:
        kw["q_init"] = q_init
    return SOLVERS[solver["type"]](model, p, **kw)


def _T(hand_eye: dict[str, Any], key: str):
    v = hand_eye.get(key)
    return None if v is None else np.asarray(v, float)


def location_to_base(location: dict[str, Any], hand_eye: dict[str, Any]):
    """The located point and its ground truth (if any) in the arm-base frame (cm).

    Returns
    -------
    (p_base, truth_base) : ndarray (3,) or None each
    """
    frame = location.get("frame", "left_camera")
    if frame == "left_camera":
        T, T_truth = _T(hand_eye, "T_base_from_left"), _T(hand_eye, "T_base_from_left_truth")
    elif frame == "table":
        T = T_truth = _T(hand_eye, "T_base_from_table")
        if T is None:
            raise NodeError(
                f"location {location.get('pair')} is in the table frame but the hand-eye transform "
                "does not place the arm base in the table frame.",
                hint="set base_in_table on calibrator.hand_eye, or wire left-camera locations.",
            )
    else:
        raise NodeError(
            f"location {location.get('pair')} has unknown frame {frame!r}.",
            hint="use 'left_camera' or 'table'.",
        )
    p = None
    if location.get("found") and location.get("x_cm") is not None:
        X = np.array([location["x_cm"], location["y_cm"], location["z_cm"]], float)
        p = T[:3, :3] @ X + T[:3, 3]
    truth = None
    if location.get("truth_cm") is not None and T_truth is not None:
        truth = T_truth[:3, :3] @ np.asarray(location["truth_cm"], float) + T_truth[:3, 3]
    return p, truth


def _num(v) -> float | None:
    return None if v is None else float(v)


def joint_target(
    model: dict[str, Any],
    location: dict[str, Any],
    hand_eye: dict[str, Any],
    solver: dict[str, Any],
    on_unreachable: str = "error",
) -> dict[str, Any]:
    """Build the JointTarget for one located object.

    An unreachable target raises :class:`Unreachable` (``on_unreachable="error"``) or gives
    ``found: false`` with the reason (``"skip"``), which ``ik.pick_sequence`` then refuses.
    """
    p, truth = location_to_base(location, hand_eye)
    T_bt = _T(hand_eye, "T_base_from_table")
    height = None
    # the table frame's z is up out of the table (docs/conventions.md)
    if p is not None and T_bt is not None:
        height = float(np.linalg.solve(T_bt[:3, :3], p - T_bt[:3, 3])[2])
    rms = (hand_eye.get("residual_cm") or {}).get("rms")
    out: dict[str, Any] = {
        "pair": location.get("pair"),
        "found": bool(location.get("found")) and p is not None,
        "reason": location.get("reason"),
        "extrapolated": bool(location.get("extrapolated", False)),
        "outside_range": list((location.get("compensation") or {}).get("outside_range") or []),
        "location_cm": None
        if p is None
        else [float(location[k]) for k in ("x_cm", "y_cm", "z_cm")],
        "frame": location.get("frame", "left_camera"),
        "target_base_cm": None if p is None else [float(v) for v in p],
        "truth_base_cm": None if truth is None else [float(v) for v in truth],
        "unreachable": False,
        "hint": None,
        "joints_deg": None,
        "servo_units": None,
        "fk_cm": None,
        "solver": solver,
        "object_radius_cm": _num(location.get("object_radius_cm")),
        "sigma_z_cm": _num(location.get("sigma_z_cm")),
        "hand_eye_rms_cm": _num(rms),
        "height_above_table_cm": height,
    }
    # (which object, and where it was seen)
    for key in ("split", "object", "merged", "u_left_px", "v_left_px"):
        if key in location:
            out[key] = location[key]
    if p is None:
        out["reason"] = out["reason"] or "object not found"
        return out
    try:
        q = solve(model, p, solver)
    except Unreachable as e:
        if on_unreachable == "error":
            raise
        # found stays false so that nothing downstream moves for it; `unreachable` says why
        # (located, not reachable), which ik.pick_sequence reports instead of "not located".
        out["found"], out["unreachable"] = False, True
        out["reason"], out["hint"] = unreachable_reason(e), unreachable_hint(e)
        return out
    joints_deg = {n: float(math.degrees(v)) for n, v in zip(JOINTS, q)}
    out["joints_deg"] = joints_deg
    out["servo_units"] = joints_to_servo_units(model, joints_deg)
    qq = quantize_joints_deg(model, joints_deg)
    out["fk_cm"] = [float(v) for v in fk(model, np.radians([qq[n] for n in JOINTS]))]
    return out


def warn_unreachable(ctx, target: dict[str, Any]) -> None:
    """Note a skipped unreachable target in the run summary (``on_unreachable: skip``)."""
    if ctx is not None and target.get("unreachable"):
        ctx.warn(f"{target.get('pair')}: {target['reason']}")
