"""The arm model: a 3-DOF AX-12A arm (base yaw, shoulder pitch, elbow pitch) plus a gripper servo.

Plain functions on a plain-data ``ArmModel`` dict (what ``ik.arm`` outputs), so that every node and
script shares one forward-kinematics definition.

Frames and angles
-----------------
Arm-base frame: origin on the base yaw axis at the mounting plane, z up, x forward when the yaw
joint is at 0 (see ``docs/conventions.md``). Joint angles (radians inside code, degrees in YAML):

* ``yaw`` (q0): rotation of the whole arm about +z, counter-clockwise seen from above.
* ``shoulder`` (q1): elevation of the upper arm above the horizontal plane (0 = horizontal,
  +90 deg = straight up).
* ``elbow`` (q2): angle of the forearm relative to the upper arm (0 = straight on, positive bends
  the forearm upward).

In the arm's vertical plane (radial coordinate ``r`` along the yaw direction, height ``z``):

* the shoulder axis is at ``(shoulder_offset_cm, base_height_cm)``;
* the elbow is ``upper_arm_cm`` further along direction ``q1``;
* the forearm points along ``phi = q1 + q2``; the tool point (the centre between the gripper
  fingers, where the ball's centre should end up) is ``forearm_cm + tool_along_cm`` along
  ``phi`` and ``tool_normal_cm`` perpendicular to it (towards ``phi + 90 deg``).

Servo units (AX-12A): 0-1023 over 300 deg, so ``units = zero_units + direction * deg * 1023 / 300``.
A joint may be driven by several servos (a doubled shoulder, one mounted mirrored: ``direction
-1``). Moving speed: 1 unit = 0.111 rpm = 0.666 deg/s, 0 = "as fast as possible" (no speed control).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # NumPy is imported by the functions that compute with it: the actuator, which
    # converts joint angles to servo units only, runs a replayed rerun without it
    import numpy as np

UNITS_PER_DEG = 1023.0 / 300.0
"""AX-12A position units per degree (0..1023 spans 300 deg)."""
SPEED_DEG_S_PER_UNIT = 0.111 * 6.0
"""AX-12A moving-speed unit: 0.111 rpm = 0.666 deg/s."""
MAX_POSITION_UNITS = 1023
MAX_SPEED_UNITS = 1023

JOINTS = ("yaw", "shoulder", "elbow")
"""Names of the positioning joints, in chain order."""


# --------------------------------------------------------------------------- unit conversions
def deg_to_units(angle_deg: float, zero_units: float, direction: int) -> int:
    """Servo position (units, rounded) for a joint angle (deg)."""
    return int(round(zero_units + direction * angle_deg * UNITS_PER_DEG))


def units_to_deg(units: float, zero_units: float, direction: int) -> float:
    """Joint angle (deg) for a servo position (units)."""
    return float((units - zero_units) / (direction * UNITS_PER_DEG))


def speed_to_units(speed_deg_s: float) -> int:
    """AX-12A moving-speed value for a joint speed in deg/s (>= 1, since 0 means 'no limit')."""
    return int(min(MAX_SPEED_UNITS, max(1, round(speed_deg_s / SPEED_DEG_S_PER_UNIT))))


# --------------------------------------------------------------------------- model accessors
def joint(model: dict[str, Any], name: str) -> dict[str, Any]:
    """The joint entry ``name`` (``yaw``, ``shoulder``, ``elbow`` or ``gripper``) of an ArmModel."""
    for j in model["joints"]:
        if j["name"] == name:
            return j
    raise KeyError(name)


def limits_rad(model: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits (rad) of the three positioning joints, shape (3,) each."""
    import numpy as np

    lo = np.array([math.radians(joint(model, n)["min_deg"]) for n in JOINTS])
    hi = np.array([math.radians(joint(model, n)["max_deg"]) for n in JOINTS])
    return lo, hi


def geometry(model: dict[str, Any]) -> tuple[float, float, float, float, float, float]:
    """``(base_height, shoulder_offset, upper_arm, forearm+tool_along, tool_normal)`` in cm, and
    reach."""
    L = model["links"]
    a = L["forearm_cm"] + L["tool_along_cm"]
    b = L["tool_normal_cm"]
    return (
        L["base_height_cm"],
        L["shoulder_offset_cm"],
        L["upper_arm_cm"],
        a,
        b,
        L["upper_arm_cm"] + math.hypot(a, b),
    )


def all_servo_ids(model: dict[str, Any]) -> list[int]:
    """Every servo id of the arm (joints then gripper), in chain order."""
    return [s["id"] for j in model["joints"] for s in j["servos"]]


# --------------------------------------------------------------------------- forward kinematics
def fk(model: dict[str, Any], q: np.ndarray) -> np.ndarray:
    """Tool-point position (cm, arm-base frame) for joint angles ``q`` (rad).

    Parameters
    ----------
    model : dict
        ArmModel.
    q : array_like, shape (3,) or (N, 3)
        ``[yaw, shoulder, elbow]`` in radians.

    Returns
    -------
    ndarray, shape (3,) or (N, 3)
        ``[x, y, z]`` in cm.
    """
    import numpy as np

    h0, r0, l1, a, b, _ = geometry(model)
    q = np.asarray(q, dtype=float)
    q0, q1, q2 = q[..., 0], q[..., 1], q[..., 2]
    phi = q1 + q2
    r = r0 + l1 * np.cos(q1) + a * np.cos(phi) - b * np.sin(phi)
    z = h0 + l1 * np.sin(q1) + a * np.sin(phi) + b * np.cos(phi)
    return np.stack([r * np.cos(q0), r * np.sin(q0), z], axis=-1)


def fk_jacobian(model: dict[str, Any], q: np.ndarray) -> np.ndarray:
    """Jacobian d(tool point)/dq (cm/rad), shape (..., 3, 3), of :func:`fk`."""
    import numpy as np

    h0, r0, l1, a, b, _ = geometry(model)
    q = np.asarray(q, dtype=float)
    q0, q1, q2 = q[..., 0], q[..., 1], q[..., 2]
    phi = q1 + q2
    c0, s0 = np.cos(q0), np.sin(q0)
    r = r0 + l1 * np.cos(q1) + a * np.cos(phi) - b * np.sin(phi)
    dr_dphi = -a * np.sin(phi) - b * np.cos(phi)
    dz_dphi = a * np.cos(phi) - b * np.sin(phi)
    dr1 = -l1 * np.sin(q1) + dr_dphi
    dz1 = l1 * np.cos(q1) + dz_dphi
    J = np.zeros(q.shape[:-1] + (3, 3))
    J[..., 0, 0] = -r * s0
    J[..., 1, 0] = r * c0
    J[..., 0, 1] = dr1 * c0
    J[..., 1, 1] = dr1 * s0
    J[..., 2, 1] = dz1
    J[..., 0, 2] = dr_dphi * c0
    J[..., 1, 2] = dr_dphi * s0
    J[..., 2, 2] = dz_dphi
    return J


# --------------------------------------------------------------------------- servo mapping
def joints_to_servo_units(model: dict[str, Any], joints_deg: dict[str, float]) -> dict[str, int]:
    """Servo goal positions ``{str(id): units}`` for joint angles ``{name: deg}``."""
    out: dict[str, int] = {}
    for name, deg in joints_deg.items():
        for s in joint(model, name)["servos"]:
            out[str(s["id"])] = deg_to_units(deg, s["zero_units"], s["direction"])
    return out


def servo_units_to_joints(model: dict[str, Any], units: dict[str, int]) -> dict[str, float]:
    """Joint angles (deg) from servo positions, using each joint's first servo."""
    out = {}
    for j in model["joints"]:
        s = j["servos"][0]
        if str(s["id"]) in units:
            out[j["name"]] = units_to_deg(units[str(s["id"])], s["zero_units"], s["direction"])
    return out


def servo_limits_units(model: dict[str, Any]) -> dict[str, tuple[int, int]]:
    """Allowed servo position range ``{str(id): (lo, hi)}`` (units) implied by each joint's limits.

    Rounding is inward (a goal inside this range is never outside the joint's limits in degrees by
    more than rounding of the servo itself).
    """
    out = {}
    for j in model["joints"]:
        for s in j["servos"]:
            u1 = s["zero_units"] + s["direction"] * j["min_deg"] * UNITS_PER_DEG
            u2 = s["zero_units"] + s["direction"] * j["max_deg"] * UNITS_PER_DEG
            lo, hi = min(u1, u2), max(u1, u2)
            out[str(s["id"])] = (
                max(0, math.ceil(lo - 1e-9)),
                min(MAX_POSITION_UNITS, math.floor(hi + 1e-9)),
            )
    return out


def quantize_joints_deg(model: dict[str, Any], joints_deg: dict[str, float]) -> dict[str, float]:
    """Joint angles (deg) the servos actually reach after rounding to whole position units."""
    units = joints_to_servo_units(model, joints_deg)
    back = servo_units_to_joints(model, units)
    return {k: back[k] for k in joints_deg}
