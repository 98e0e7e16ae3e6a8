"""``ik.arm``: the arm model (geometry, joint limits, servo mapping) from YAML params.

ArmModel (plain data, what every arm node receives)::

    {"name": str,
     "links": {"base_height_cm", "shoulder_offset_cm", "upper_arm_cm", "forearm_cm",
               "tool_along_cm", "tool_normal_cm"},
     "joints": [{"name": "yaw" | "shoulder" | "elbow" | "gripper",
                 "min_deg", "max_deg", "home_deg": float,
                 "servos": [{"id": int, "zero_units": float, "direction": 1 | -1}, ...],
                 # gripper only:
                 "open_deg", "closed_deg": float}, ...],
     "reach_cm": float,              # upper_arm + |effective forearm|, from the shoulder axis
     "max_speed_deg_s": float,       # joint speed used for the largest move of a waypoint
     "units_per_deg": 3.41, "speed_deg_s_per_unit": 0.666}

See ``nodes/contracts/arm.py`` for the kinematic conventions and ``docs/arm.md`` for an example.
"""

from __future__ import annotations

from typing import Literal

from nodes.contracts.arm import (
    MAX_POSITION_UNITS,
    SPEED_DEG_S_PER_UNIT,
    UNITS_PER_DEG,
    servo_limits_units,
)
from stereograph.api import Field, NodeError, Out, Params, node


class ServoSpec(Params):
    """One AX-12A servo driving a joint."""

    id: int = Field(..., ge=0, le=253, description="Dynamixel ID of the servo (0-253).")
    zero_units: float = Field(
        512.0,
        ge=0,
        le=MAX_POSITION_UNITS,
        description="Servo position (units, 0-1023 over 300 deg) at joint angle 0 deg.",
    )
    direction: Literal[1, -1] = Field(
        1, description="+1 if servo units grow with the joint angle, -1 if mirrored."
    )


class JointSpec(Params):
    """A positioning joint: its servos and limits."""

    servos: list[ServoSpec] = Field(
        ..., min_length=1, description="Servos driving this joint (2 for a doubled joint)."
    )
    min_deg: float = Field(..., ge=-360, le=360, description="Lower joint limit (deg).")
    max_deg: float = Field(..., ge=-360, le=360, description="Upper joint limit (deg).")
    home_deg: float = Field(
        0.0, ge=-360, le=360, description="Rest pose angle (deg); first IK seed for ik.numeric."
    )


class GripperSpec(JointSpec):
    """The gripper servo and its open / closed angles."""

    open_deg: float = Field(40.0, ge=-360, le=360, description="Gripper angle (deg) when open.")
    closed_deg: float = Field(
        0.0, ge=-360, le=360, description="Gripper angle (deg) when closed on the object."
    )


class Links(Params):
    """Link lengths of the chain (see nodes/contracts/arm.py for the exact definition)."""

    base_height_cm: float = Field(
        8.0, ge=0, le=200, description="Height of the shoulder axis above the mounting plane (cm)."
    )
    shoulder_offset_cm: float = Field(
        0.0,
        ge=-50,
        le=50,
        description="Horizontal offset of the shoulder axis from the yaw axis (cm).",
    )
    upper_arm_cm: float = Field(12.0, gt=0, le=200, description="Shoulder axis to elbow axis (cm).")
    forearm_cm: float = Field(
        9.0, gt=0, le=200, description="Elbow axis to the gripper mount (cm)."
    )
    tool_along_cm: float = Field(
        7.0, ge=-50, le=100, description="Gripper mount to the grasp point, along the forearm (cm)."
    )
    tool_normal_cm: float = Field(
        0.0,
        ge=-50,
        le=50,
        description="Grasp point offset perpendicular to the forearm, in the arm plane (cm).",
    )


def _j(ids, lo, hi, home, zero=512.0, dirs=None):
    dirs = dirs or [1] * len(ids)
    zeros = zero if isinstance(zero, list) else [zero] * len(ids)
    return dict(
        servos=[ServoSpec(id=i, zero_units=z, direction=d) for i, z, d in zip(ids, zeros, dirs)],
        min_deg=lo,
        max_deg=hi,
        home_deg=home,
    )


class ArmParams(Params):
    """Arm model parameters. Defaults: a Bioloid-style AX-12A arm with a doubled shoulder (5
    servos)."""

    name: str = Field("ax12a-3dof", description="A label for logs.")
    links: Links = Field(default_factory=Links, description="Link lengths (cm).")
    yaw: JointSpec = Field(
        default_factory=lambda: JointSpec(**_j([1], -150.0, 150.0, 0.0)),
        description="Base yaw joint (deg, about +z).",
    )
    # Upright (90 deg) at servo centre 512 so that the shoulder can swing both ways: 512 - 90*3.41 =
    # 205.
    shoulder: JointSpec = Field(
        default_factory=lambda: JointSpec(
            **_j([2, 3], -15.0, 165.0, 90.0, zero=[205.1, 818.9], dirs=[1, -1])
        ),
        description="Shoulder pitch joint (deg above horizontal).",
    )
    elbow: JointSpec = Field(
        default_factory=lambda: JointSpec(**_j([4], -140.0, 140.0, -90.0)),
        description="Elbow pitch joint (deg relative to the upper arm).",
    )
    gripper: GripperSpec = Field(
        default_factory=lambda: GripperSpec(
            **_j([5], -30.0, 60.0, 40.0), open_deg=40.0, closed_deg=0.0
        ),
        description="Gripper servo (deg).",
    )
    max_speed_deg_s: float = Field(
        60.0, gt=0, le=680, description="Joint speed (deg/s) of the largest move of each waypoint."
    )


def build_arm_model(params: ArmParams) -> dict:
    """Validate the arm parameters and return the ArmModel dict.

    Raises
    ------
    NodeError
        Limits in the wrong order, a home or gripper angle outside its limits, a duplicated servo
        ID, or joint limits that map outside the servo's 0-1023 range.
    """
    joints = []
    seen: dict[int, str] = {}
    for name in ("yaw", "shoulder", "elbow", "gripper"):
        spec: JointSpec = getattr(params, name)
        _check_joint(name, spec, seen)
        j = {
            "name": name,
            "min_deg": float(spec.min_deg),
            "max_deg": float(spec.max_deg),
            "home_deg": float(spec.home_deg),
            "servos": [
                {"id": int(s.id), "zero_units": float(s.zero_units), "direction": int(s.direction)}
                for s in spec.servos
            ],
        }
        if isinstance(spec, GripperSpec):
            j.update(open_deg=float(spec.open_deg), closed_deg=float(spec.closed_deg))
        joints.append(j)
    L = params.links
    links = {k: float(getattr(L, k)) for k in Links.model_fields}
    l2 = ((L.forearm_cm + L.tool_along_cm) ** 2 + L.tool_normal_cm**2) ** 0.5
    if l2 <= 0:
        raise NodeError(
            "arm model: forearm_cm + tool_along_cm and tool_normal_cm give a zero-length forearm.",
            hint="check the link lengths.",
        )
    model = {
        "name": params.name,
        "links": links,
        "joints": joints,
        "reach_cm": float(L.upper_arm_cm + l2),
        "max_speed_deg_s": float(params.max_speed_deg_s),
        "units_per_deg": UNITS_PER_DEG,
        "speed_deg_s_per_unit": SPEED_DEG_S_PER_UNIT,
    }
    model["servo_limits_units"] = {k: list(v) for k, v in servo_limits_units(model).items()}
    return model


def _check_joint(name: str, spec: JointSpec, seen: dict[int, str]) -> None:
    """A joint's limits in order, its home (and gripper) angles within them, its servos' IDs not
    used before (``seen``: ID -> joint, filled) and its limits within each servo's range."""
    if not spec.min_deg < spec.max_deg:
        raise NodeError(
            f"arm model: {name} min_deg {spec.min_deg} is not below max_deg {spec.max_deg}.",
            hint=f"swap or fix {name}.min_deg / {name}.max_deg in the ik.arm params.",
        )
    checks = {"home_deg": spec.home_deg}
    if isinstance(spec, GripperSpec):
        checks.update(open_deg=spec.open_deg, closed_deg=spec.closed_deg)
    for key, v in checks.items():
        if not spec.min_deg <= v <= spec.max_deg:
            raise NodeError(
                f"arm model: {name}.{key} = {v} deg is outside its limits "
                f"[{spec.min_deg}, {spec.max_deg}] deg.",
                hint=f"set {name}.{key} within the limits.",
            )
    for s in spec.servos:
        if s.id in seen:
            raise NodeError(
                f"arm model: servo ID {s.id} is used by both {seen[s.id]} and {name}.",
                hint="give every servo its own Dynamixel ID.",
            )
        seen[s.id] = name
        for lim in (spec.min_deg, spec.max_deg):
            u = s.zero_units + s.direction * lim * UNITS_PER_DEG
            if not -0.5 <= u <= MAX_POSITION_UNITS + 0.5:
                raise NodeError(
                    f"arm model: {name} limit {lim} deg maps to servo {s.id} position "
                    f"{u:.0f} units, outside "
                    f"the AX-12A range 0-1023 (300 deg).",
                    hint=f"narrow {name}'s limits or change the servo's zero_units (the "
                    "servo position at 0 deg).",
                )


def _check_model(params: ArmParams, wired: frozenset[str]) -> None:
    build_arm_model(params)  # its NodeError, said by `stereograph validate` before anything runs


@node(
    "ik.arm",
    outputs={"arm": Out("ArmModel", description="Arm geometry, limits and servo mapping.")},
    params=ArmParams,
    version="1",
    check=_check_model,
)
def arm(params: ArmParams):
    """The arm model: joint chain, link lengths (cm), joint limits (deg) and AX-12A servo
    mapping."""
    return {"arm": build_arm_model(params)}
