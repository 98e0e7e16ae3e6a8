"""``ik.pick_sequence``: a located, solved object -> the joint-space waypoints of a pick (and
place).

PickPlan (per item)::

    {"pair": str, "refused": bool, "reason": str | None, "split": str | None, "arm": str,
     "hint": str | None,                   # refused plans only: the fix (also appended to the
                                           # reason)
     "target_base_cm": [x, y, z], "truth_base_cm": [x, y, z] | None,
     "solver": {...},                      # the IK solver of the JointTarget, reused for every
                                           # waypoint
     "servo_ids": [int, ...],              # every servo the plan drives, chain order
     "grasp_index": int,                   # index of the waypoint that closes the gripper on the
                                           # object
     "grasp_fk_cm": [x, y, z],             # tool point of the quantised servo goals at the grasp
     "workspace_cm": {"min": [x, y, z], "max": [x, y, z]},   # the box every waypoint was checked
                                                             # against
     "table_check": {"height_above_table_cm": float, "radius_cm": float | None, "tolerance_cm":
     float,
                     "table": str},        # the ball's centre vs one radius above the table (see
                                           # _check_table)
     "waypoints": [{"name": str,           # open, above, descend_k, grasp, close, lift,
                                           # place_above, ...
                    "gripper": "open" | "closed",
                    "tool_cm": [x, y, z],  # tool-point target, arm-base frame
                    "joints_deg": {"yaw", "shoulder", "elbow", "gripper": float},
                    "servo_units": {str(id): int},      # goal positions (AX-12A units)
                    "speed_units": {str(id): int}}, ...]}  # moving speeds (1 unit = 0.666 deg/s)

Speeds are scaled per waypoint so that every joint arrives at the same time (the largest move runs
at the arm's ``max_speed_deg_s``).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from nodes.contracts.arm import (
    JOINTS,
    all_servo_ids,
    fk,
    joint,
    joints_to_servo_units,
    quantize_joints_deg,
    speed_to_units,
)
from stereograph.api import Field, In, NodeError, Out, Params, node

from ._solvers import Unreachable, _candidates, analytic_ik, configuration
from ._target import ARM_HINT, solve, unreachable_hint, unreachable_reason


class PickParams(Params):
    approach_height_cm: float = Field(
        6.0, ge=0, le=100, description="Height above the object to approach from (cm)."
    )
    lift_height_cm: float = Field(
        8.0, ge=0, le=100, description="Height to lift the object by (cm)."
    )
    descend_steps: int = Field(
        3,
        ge=1,
        le=50,
        description="Straight-line waypoints of the vertical descent (1 = one move).",
    )
    place_cm: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Where to put the object down (arm-base frame, cm); none = hold it.",
    )
    return_home: bool = Field(False, description="End with a move back to the home pose.")
    workspace_min_cm: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Lower corner of the allowed workspace box (arm-base frame, cm); default "
        "[-reach, -reach, 0].",
    )
    workspace_max_cm: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Upper corner of the workspace box (cm); default [reach, reach, base_height "
        "+ reach].",
    )
    refuse_extrapolated: bool = Field(
        True,
        description="Refuse a location that a compensator flagged as "
        "extrapolated (outside its training range).",
    )
    object_radius_cm: float | None = Field(
        None,
        gt=0,
        le=100,
        description="The ball's radius (cm) for the table check (its centre must be a radius "
        "above the table); default the location's, i.e. the segmenter's "
        "object.radius_cm.",
    )
    table_sigmas: float = Field(
        3.0,
        ge=0,
        le=20,
        description="How many standard deviations of the located height (the location's "
        "sigma_z_cm and the hand-eye fit's RMS residual, combined) the ball's centre may "
        "lie below one radius above the table before the pick is refused (count).",
    )
    table_tolerance_cm: float | None = Field(
        None,
        ge=0,
        le=10,
        description="Extra allowance below one radius above the table (cm), added to table_sigmas' "
        "share; default a quarter of the ball's radius (a grasp that much low still "
        "closes on the ball: what is refused is a location off by more, the ball inside "
        "the table). Raise it to the accuracy of a hand-measured hand-eye (mode given), "
        "which the run cannot know.",
    )
    speed_deg_s: float | None = Field(
        None,
        gt=0,
        le=680,
        description="Speed of the largest joint move (deg/s); default the arm's.",
    )
    on_refuse: Literal["error", "skip"] = Field(
        "error",
        description="error: a refused target fails this item; skip: output a plan with "
        "refused=true, "
        "no waypoints and the reason (the actuators never move for it).",
    )


def _refuse(target, why: str, hint: str) -> NodeError:
    return NodeError(
        f"refusing to move the arm for {target.get('pair')}: {why.rstrip('.')}.", hint=hint
    )


# one straight vertical move: one arm configuration
_PICK = ("above", "descend", "grasp", "close", "lift")
_PLACE = ("place_above", "place", "release", "retreat")


def _segment(name: str) -> str:
    return "pick" if name.split("_")[0] in _PICK else "place"


def _solve_in_one_configuration(
    model: dict, points: list, target: dict, q_home: np.ndarray
) -> dict[str, np.ndarray]:
    """Joint angles of every point, the points of each straight move (the pick's descent and lift,
    the place) in one arm configuration: solved one by one, two of them may fall on different
    branches (the preferred pose leaves a joint limit near the table), and the arm would swing --
    180 deg over the base -- between two points 2 cm apart. Such a move is re-solved in one
    configuration, else refused."""
    solver, at = target["solver"], dict(points)
    out: dict[str, np.ndarray] = {}
    q_prev = q_home
    for name, pt in points:
        try:
            out[name] = q_prev = solve(model, pt, solver, q_init=q_prev)
        except Unreachable as e:
            raise _refuse(
                target, f"the {name} point is {unreachable_reason(e)}", unreachable_hint(e)
            ) from e
    for seg in ("pick", "place"):
        names = [n for n, _ in points if _segment(n) == seg]
        confs = {n: configuration(model, at[n], out[n]) for n in names}
        if _compatible(list(confs.values())):
            continue
        fixed = None
        if solver["type"] == "analytic_3dof":
            kw = dict(solver.get("params") or {})
            for cand in _candidates(kw.get("elbow", "auto"), kw.get("allow_back", True)):
                try:
                    fixed = {n: analytic_ik(model, at[n], config=cand) for n in names}
                    break
                except Unreachable:
                    continue
        if fixed is None:
            a, b = next(
                (
                    (m, n)
                    for i, m in enumerate(names)
                    for n in names[i + 1 :]
                    if not _compatible([confs[m], confs[n]])
                ),
                (names[0], names[-1]),
            )
            raise _refuse(
                target,
                f"no single arm configuration reaches every point of the {seg} within the joint "
                f"limits: {a} is reached {_words(confs[a])}, {b} {_words(confs[b])}, and the arm "
                "would swing between them",
                "widen the joint limits in the arm model if the "
                "hardware allows it, or move the object",
            )
        out.update(fixed)
    return out


def _compatible(confs: list[tuple[int, int]]) -> bool:
    """One configuration: one branch, and one elbow side where the arm is not stretched (elbow
    0)."""
    return len({c[0] for c in confs}) <= 1 and len({c[1] for c in confs if c[1] != 0}) <= 1


def _words(conf: tuple[int, int]) -> str:
    return ("in front" if conf[0] > 0 else "backwards over the base") + (
        "" if conf[1] == 0 else f", elbow {'up' if conf[1] < 0 else 'down'}"
    )


def _check_table(params: PickParams, target: dict, p: np.ndarray, floor_cm: float) -> dict:
    """Refuse a ball whose centre lies less than one radius above the table: the ball would be
    inside the table, so the location is wrong (hand-eye or table frame off in z, a wrong radius, a
    compensation fitted on other truth) and the fingers would be driven into the table. The
    workspace box limits the tool point only.

    The table is the table frame's z = 0 when the hand-eye places the arm base in it, else the
    workspace box's floor (``workspace_min_cm`` z; by default the base's mounting plane, z = 0). The
    tolerance is the location's own uncertainty: ``table_sigmas`` x sqrt(sigma_z_cm^2 + hand-eye
    RMS^2), plus ``table_tolerance_cm``. Without a known radius only the centre itself is checked
    (radius 0).

    Returns
    -------
    dict
        The plan's ``table_check`` record.
    """
    h = target.get("height_above_table_cm")
    table = "the table frame's z = 0, placed by the hand-eye's base_in_table"
    if h is None:
        h, table = (
            float(p[2] - floor_cm),
            f"the workspace floor z = {floor_cm:g} cm (arm-base frame)",
        )
    r = (
        params.object_radius_cm
        if params.object_radius_cm is not None
        else target.get("object_radius_cm")
    )
    sz, he = target.get("sigma_z_cm") or 0.0, target.get("hand_eye_rms_cm") or 0.0
    sigma = math.hypot(sz, he)
    # (the located height's sigma alone is too tight: on pick.yaml the hand-eye left heights up to 5
    # sigma low)
    extra = (
        params.table_tolerance_cm if params.table_tolerance_cm is not None else 0.25 * (r or 0.0)
    )
    tol = params.table_sigmas * sigma + extra
    if h < (r or 0.0) - tol:
        size = (
            f"less than its radius {r:.2f} cm by {r - h:.2f} cm"
            if r
            else "below the table (its radius is not known)"
        )
        parts = [f"sigma_z {sz:.3f} cm"] + ([f"hand-eye RMS {he:.3f} cm"] if he else [])
        raise _refuse(
            target,
            f"the ball's centre is located {h:.2f} cm above the table ({table}), {size}, more "
            f"than the {tol:.2f} cm allowed ({params.table_sigmas:g} x {sigma:.3f} cm: "
            f"{', '.join(parts)}"
            + (f"; + table_tolerance_cm {extra:.2f}" if extra else "")
            + "): the ball would be inside the table, so the location is wrong and the fingers "
            "would hit the table",
            "check the hand-eye transform's z (calibrator.hand_eye: base_in_table's "
            "height, or the fitted "
            "pairs), the table frame (the board lying flat on the table; without one, "
            "workspace_min_cm's z "
            "is the table), and the ball's radius (the segmenter's object.radius_cm, "
            "pick.object_radius_cm); "
            "a compensation fitted on another truth shifts z too. If the hand-eye was "
            "measured by hand, set "
            "table_tolerance_cm to its accuracy",
        )
    return {
        "height_above_table_cm": float(h),
        "radius_cm": None if r is None else float(r),
        "tolerance_cm": float(tol),
        "table": table,
    }


def plan_pick(params: PickParams, model: dict, target: dict) -> dict:
    """Plan the pick of a solved target (pure function; see the module docstring for the result)."""
    _refuse_untrusted(params, target)
    lo, hi = _workspace(params, model)
    p = np.asarray(target["target_base_cm"], float)
    points = _tool_points(params, p)
    q_home = np.radians([joint(model, n)["home_deg"] for n in JOINTS])
    _check_in_box(target, fk(model, q_home), points, lo, hi)
    table_check = _check_table(params, target, p, float(lo[2]))
    solved = _solve_in_one_configuration(model, points, target, q_home)
    waypoints = _waypoints(params, model, points, solved)
    _add_servo_goals(params, model, waypoints)
    gi = next(i for i, w in enumerate(waypoints) if w["name"] == "grasp")
    return {
        "pair": target.get("pair"),
        "refused": False,
        "reason": None,
        "split": target.get("split"),
        "arm": model["name"],
        "target_base_cm": [float(v) for v in p],
        "location_cm": target.get("location_cm"),
        "sigma_z_cm": target.get("sigma_z_cm"),
        "frame": target.get("frame"),
        "truth_base_cm": target.get("truth_base_cm"),
        "solver": target["solver"],
        "servo_ids": all_servo_ids(model),
        "grasp_index": gi,
        "grasp_fk_cm": waypoints[gi]["fk_cm"],
        # the box this plan was checked against
        "workspace_cm": {"min": lo.tolist(), "max": hi.tolist()},
        "table_check": table_check,
        "waypoints": waypoints,
    }


def _refuse_untrusted(params: PickParams, target: dict) -> None:
    """Refuse a target the arm must not move on: unreachable, not located, or extrapolated
    beyond the compensation (when ``refuse_extrapolated``)."""
    if target.get("unreachable"):
        # located, but out of this arm's reach or joint limits (ik on_unreachable: skip)
        raise _refuse(
            target,
            target.get("reason") or "unreachable for this arm",
            target.get("hint") or f"{ARM_HINT}.",
        )
    if not target.get("found") or target.get("target_base_cm") is None:
        raise _refuse(
            target,
            f"the object was not located ({target.get('reason') or 'found: false'})",
            "check the segmentation of this scene; the arm never moves on a failed localisation.",
        )
    if params.refuse_extrapolated and target.get("extrapolated"):
        why = "; ".join(target.get("outside_range") or [])
        raise _refuse(
            target,
            "its location is extrapolated beyond the compensation model's training range"
            + (f" ({why})" if why else ""),
            "collect training scenes that cover this distance, or set refuse_extrapolated: false.",
        )


def _workspace(params: PickParams, model: dict) -> tuple[np.ndarray, np.ndarray]:
    """The workspace box, cm (base frame): the params', else the arm's reach above the table."""
    reach = model["reach_cm"]
    h0 = model["links"]["base_height_cm"]
    lo = np.array(
        params.workspace_min_cm if params.workspace_min_cm is not None else [-reach, -reach, 0.0]
    )
    hi = np.array(
        params.workspace_max_cm
        if params.workspace_max_cm is not None
        else [reach, reach, h0 + reach]
    )
    return lo, hi


def _tool_points(params: PickParams, p: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The tool's named points, in order: above, the descent, grasp, close, lift (and the place
    moves), cm."""
    up = np.array([0.0, 0.0, 1.0])
    points = [("above", p + params.approach_height_cm * up)]
    for k in range(1, params.descend_steps):
        f = k / params.descend_steps
        points.append((f"descend_{k}", p + (1 - f) * params.approach_height_cm * up))
    points += [("grasp", p), ("close", p), ("lift", p + params.lift_height_cm * up)]
    if params.place_cm is not None:
        pl = np.asarray(params.place_cm, float)
        points += [
            ("place_above", pl + params.approach_height_cm * up),
            ("place", pl),
            ("release", pl),
            ("retreat", pl + params.approach_height_cm * up),
        ]
    return points


def _check_in_box(
    target: dict, home_tool: np.ndarray, points: list, lo: np.ndarray, hi: np.ndarray
) -> None:
    """Refuse a plan whose home pose (``home_tool``, where the first and last moves go) or any
    point leaves the workspace box."""
    if np.any(home_tool < lo - 1e-9) or np.any(home_tool > hi + 1e-9):
        txt = ", ".join(f"{v:.2f}" for v in home_tool)
        raise _refuse(
            target,
            f"the arm's home pose puts the tool at [{txt}] cm, outside the workspace box "
            f"[{', '.join(f'{v:g}' for v in lo)}] .. [{', '.join(f'{v:g}' for v in hi)}] cm (below "
            "the table?)",
            "set the joints' home_deg in the arm model (ik.arm) to a pose above "
            "the table, and check it with the arm unpowered",
        )
    # the object's own centre first: a ball below the table is named as such, not by the first
    # descent point that happens to cross the floor on the way down to it
    for name, pt in sorted(points, key=lambda np_: np_[0] != "grasp"):
        if np.any(pt < lo - 1e-9) or np.any(pt > hi + 1e-9):
            txt = ", ".join(f"{v:.2f}" for v in pt)
            what = "grasp point (the object's centre)" if name == "grasp" else f"{name} point"
            raise _refuse(
                target,
                f"the {what} [{txt}] cm lies outside the workspace box "
                f"[{', '.join(f'{v:g}' for v in lo)}] .. [{', '.join(f'{v:g}' for v in hi)}] cm",
                "move the object, or widen workspace_min_cm / workspace_max_cm if the "
                "space is clear.",
            )


def _waypoints(params: PickParams, model: dict, points: list, solved: dict) -> list[dict]:
    """Open the gripper at home, then each point with its joints and gripper state (then home)."""
    g = joint(model, "gripper")
    grip = {"open": g["open_deg"], "closed": g["closed_deg"]}
    state = {
        "above": "open",
        "grasp": "open",
        "close": "closed",
        "lift": "closed",
        "place_above": "closed",
        "place": "closed",
        "release": "open",
        "retreat": "open",
    }
    home = {n: joint(model, n)["home_deg"] for n in JOINTS}
    waypoints = [
        {
            "name": "open",
            "gripper": "open",
            "tool_cm": None,
            "joints_deg": {**home, "gripper": grip["open"]},
        }
    ]
    for name, pt in points:
        q = solved[name]
        st = state.get(name, "open")
        waypoints.append(
            {
                "name": name,
                "gripper": st,
                "tool_cm": [float(v) for v in pt],
                "joints_deg": {
                    **{n: float(math.degrees(v)) for n, v in zip(JOINTS, q)},
                    "gripper": grip[st],
                },
            }
        )
    if params.return_home:
        waypoints.append(
            {
                "name": "home",
                "gripper": waypoints[-1]["gripper"],
                "tool_cm": None,
                "joints_deg": {**home, "gripper": waypoints[-1]["joints_deg"]["gripper"]},
            }
        )
    return waypoints


def _add_servo_goals(params: PickParams, model: dict, waypoints: list[dict]) -> None:
    """Each waypoint's servo goals and speeds, and the tool position its quantised joints reach."""
    vmax_units = (params.speed_deg_s or model["max_speed_deg_s"]) / model["speed_deg_s_per_unit"]
    prev = None
    for w in waypoints:
        w["servo_units"] = joints_to_servo_units(model, w["joints_deg"])
        # Synchronised motion: each servo's speed in proportion to its travel (in whole units, as
        # the servo moves), so that all arrive together; the first move, from an unknown pose, at
        # full speed.
        travel = {i: abs(u - prev[i]) if prev else 1 for i, u in w["servo_units"].items()}
        tmax = max(travel.values()) or 1
        w["speed_units"] = {
            i: speed_to_units(vmax_units * travel[i] / tmax * model["speed_deg_s_per_unit"])
            for i in w["servo_units"]
        }
        if w["tool_cm"] is not None:
            qq = quantize_joints_deg(model, {n: w["joints_deg"][n] for n in JOINTS})
            w["fk_cm"] = [float(v) for v in fk(model, np.radians([qq[n] for n in JOINTS]))]
        prev = w["servo_units"]


@node(
    "ik.pick_sequence",
    inputs={
        "arm": In("ArmModel"),
        "target": In("JointTarget", description="Solved object (per item)."),
    },
    outputs={
        "plan": Out(
            "PickPlan", save=True, description="Joint-space waypoints with servo goals and speeds."
        )
    },
    params=PickParams,
    version="1",
)
def pick_sequence(params: PickParams, arm, target, ctx=None):
    """Open -> above -> descend -> close -> lift (-> place); refuses failed, extrapolated or
    out-of-box targets, and a ball whose centre is less than one radius above the table."""
    try:
        plan = plan_pick(params, arm, target)
        if ctx is not None and plan["table_check"]["radius_cm"] is None:
            ctx.warn(
                f"{target.get('pair')}: the ball's radius is not known (the location carries no "
                "object_radius_cm and pick.object_radius_cm is not set): only its centre "
                "was checked against "
                "the table"
            )
        return {"plan": plan}
    except NodeError as e:
        if params.on_refuse == "error":
            raise
        # The reason carries its fix: downstream (actuators, reports) shows only the reason.
        reason = e.message.rstrip(".") + (f"; fix: {e.hint.rstrip('.')}" if e.hint else "")
        return {
            "plan": {
                "pair": target.get("pair"),
                "refused": True,
                "reason": reason,
                "hint": e.hint,
                "split": target.get("split"),
                "truth_base_cm": target.get("truth_base_cm"),
                "waypoints": [],
            }
        }
