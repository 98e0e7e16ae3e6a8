"""``locator.triangulate``: 3D position of the object from its disparity.

From a rectified left image point (u, v) and disparity d, OpenCV's reprojection matrix Q gives
the point in the *rectified* left frame: [X Y Z W]^T = Q [u v d 1]^T, i.e. Z = f B / (d - (cx1 -
cx2)), X = (u - cx) Z / f, Y = (v - cy) Z / f. It is rotated back to the physical left-camera
frame by R1^T (docs/conventions.md) and, when ``frame: table``, mapped into the table frame by
``T_table_from_left`` (4x4, cm; from params or a wired RigTruth). A disparity that refers to the
sphere's visible surface (``depth_offset_cm`` > 0, from ``disparity.sgbm``) is moved that far along
the viewing ray so that the reported point is the sphere's centre. sigma_z = Z^2 sigma_d / (f B).

Untrustworthy input gives ``found: False`` with the reason (propagated from the segmenter or the
disparity estimator, or a disparity/depth outside the working range); never an exception.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from nodes.contracts.calibration_file import rig_fingerprint
from nodes.contracts.working_range import working_range
from nodes.locators._overlay import location_overlay
from stereograph.api import Field, In, NodeError, Out, Params, PositiveRange, node


class TriangulateParams(Params):
    """Parameters of ``locator.triangulate``."""

    frame: Literal["left_camera", "table"] = Field(
        "left_camera",
        description="Output frame: the physical left camera, or the table (needs a transform).",
    )
    T_table_from_left: list[list[float]] | None = Field(
        None,
        description="4x4 transform from left-camera to table frame (cm); None = take it from "
        "`rig`.",
    )
    working_range_cm: PositiveRange = Field(
        (20.0, 80.0),
        description="Plausible object distance (cm); outside (with 25 % slack) -> not found. Not "
        "set in the pipeline: the disparity estimator's (the segmenter's), from its records.",
    )
    overlay: bool = Field(
        True, description="Draw the labelled left | right overlay (bool); off = no overlay output."
    )


def triangulate_point(
    u_px: float, v_px: float, d_px: float, rectification: dict, depth_offset_cm: float = 0.0
) -> np.ndarray:
    """Point in the physical left-camera frame (cm) from a rectified left point and its disparity.

    Parameters
    ----------
    u_px, v_px : float
        Point in the rectified left image (px).
    d_px : float
        Disparity u_left - u_right (px), > 0.
    rectification : dict
        ``Rectification`` (Q, R1; or f_px, cx_px, cy_px, baseline_cm).
    depth_offset_cm : float
        Move the point this far further along the viewing ray (sphere surface -> centre).

    Returns
    -------
    (3,) float array, cm.
    """
    if rectification.get("Q") is not None:
        X = np.asarray(rectification["Q"], float) @ np.array([u_px, v_px, d_px, 1.0])
        p = X[:3] / X[3]
    else:
        f, B = float(rectification["f_px"]), float(rectification["baseline_cm"])
        z = f * B / d_px
        p = np.array(
            [(u_px - rectification["cx_px"]) * z / f, (v_px - rectification["cy_px"]) * z / f, z]
        )
    if p[2] < 0:  # Q of a rig with the right camera on the other side: flip.
        p = -p
    if depth_offset_cm:
        p = p + depth_offset_cm * p / np.linalg.norm(p)
    R1 = rectification.get("R1")
    if R1 is not None:
        p = np.asarray(R1, float).T @ p
    return p


def sigma_z_cm(z_cm: float, sigma_d_px: float, f_px: float, baseline_cm: float) -> float:
    """Depth uncertainty (cm) from the disparity uncertainty: z^2 sigma_d / (f B)."""
    return float(z_cm**2 * sigma_d_px / (f_px * baseline_cm))


def apply_transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply a 4x4 homogeneous transform to a 3-vector."""
    return T[:3, :3] @ p + T[:3, 3]


def _known_transform(params: TriangulateParams, rig: dict | None) -> np.ndarray | None:
    """T_table_from_left from the params or the wired rig / table frame, whatever the output
    frame."""
    T = (
        params.T_table_from_left
        if params.T_table_from_left is not None
        else (rig or {}).get("T_table_from_left")
    )
    return None if T is None or np.asarray(T).shape != (4, 4) else np.asarray(T, float)


def _transform(params: TriangulateParams, rig: dict | None) -> np.ndarray | None:
    if params.frame != "table":
        return None
    T = params.T_table_from_left
    if T is None and rig is not None:
        T = rig.get("T_table_from_left")  # RigTruth and TableFrame both carry it
    if T is None:
        raise NodeError(
            "locator.triangulate: frame is 'table' but no table transform is known.",
            hint="set `T_table_from_left` (4x4, cm) in its params or wire `rig` to a RigTruth "
            "with one.",
        )
    T = np.asarray(T, float)
    if T.shape != (4, 4):
        raise NodeError(
            f"locator.triangulate: T_table_from_left has shape {T.shape}, expected 4x4.",
            hint="give a 4x4 homogeneous matrix in cm.",
        )
    return T


def _record(pid, split, frame, reason=None, **kw) -> dict:
    rec = {
        "pair": pid,
        "found": reason is None,
        "reason": reason,
        "x_cm": None,
        "y_cm": None,
        "z_cm": None,
        "sigma_z_cm": None,
        "frame": frame,
        "disparity_px": None,
        "u_left_px": None,
        "v_left_px": None,
        "truth_cm": None,
        "split": split,
    }
    rec.update(kw)
    return rec


@node(
    "locator.triangulate",
    inputs={
        "disparity": In("Disparity", description="Object disparity and left image point."),
        "rectification": In("Rectification", description="Q, R1, f, baseline."),
        "pair": In(
            "RectifiedPair | StereoPair",
            optional=True,
            description="For the ground truth, when it exists.",
        ),
        "rig": In(
            "RigTruth | TableFrame",
            optional=True,
            description="For T_table_from_left when frame is table (the rig's truth, or a table "
            "frame from a "
            "board: calibrator.table_frame / load_table_frame).",
        ),
    },
    outputs={
        "location": Out("Location", description="Object centre (cm) in the chosen frame."),
        "overlay": Out(
            "Image",
            save=True,
            lossy=True,
            description="Rectified left | right with the located point and its epipolar line, "
            "labelled x/y/z, sigma_z or the reason.",
        ),
    },
    params=TriangulateParams,
    version="1",
)
def triangulate(params: TriangulateParams, disparity, rectification, pair=None, rig=None, ctx=None):
    """Triangulate the object's centre: x, y from the left point, z = f B / d, rotated by R1^T."""
    loc = _locate(params, disparity, rectification, pair, rig, ctx)
    if not params.overlay:
        return {"location": loc, "overlay": None}  # nothing saved, nothing logged
    raw = ctx is not None and (ctx.input_types or {}).get("pair") == "StereoPair"
    return {"location": loc, "overlay": location_overlay(loc, disparity, rectification, pair, raw)}


def _locate(params: TriangulateParams, disparity, rectification, pair, rig, ctx) -> dict:
    _check_inputs(disparity, rectification)
    T = _transform(params, rig)
    frame = params.frame
    pid = disparity.get("id") or (ctx.item if ctx else None)
    split = disparity.get("split") or (pair or {}).get("split")
    truth = _truth_in_frame(params, (pair or {}).get("truth"), T, rig)
    # where the segmenter's object colour came from (given, learned): kept beside each result
    # ... and the ball's radius the segmenter looked for (ik.pick_sequence: its centre must be a
    # radius above the table, else the location is wrong)
    seen = {
        k: disparity[k]
        for k in ("color_from", "object_radius_cm", "object", "merged")
        if k in disparity
    }
    if not disparity["found"]:
        return _record(
            pid, split, frame, disparity.get("reason") or "no disparity", truth_cm=truth, **seen
        )
    d = float(disparity["disparity_px"])
    u, v = float(disparity["u_left_px"]), float(disparity["v_left_px"])
    f, B = float(rectification["f_px"]), float(rectification["baseline_cm"])
    # The rig it was measured with travels along, so that a model fitted on it can be checked later.
    base = dict(
        disparity_px=d,
        u_left_px=u,
        v_left_px=v,
        truth_cm=truth,
        rig=rig_fingerprint(rectification),
        **seen,
    )
    if d <= 0:
        return _record(pid, split, frame, f"disparity out of range ({d:.2f} px <= 0)", **base)
    p = triangulate_point(u, v, d, rectification, float(disparity.get("depth_offset_cm") or 0.0))
    z0, z1 = working_range(params, disparity)
    if not (0.75 * z0 <= p[2] <= 1.25 * z1):
        return _record(
            pid,
            split,
            frame,
            f"depth {p[2]:.1f} cm outside the working range {z0:g}-{z1:g} cm",
            **base,
        )
    sz = sigma_z_cm(float(p[2]), float(disparity.get("sigma_disparity_px") or 0.0), f, B)
    if T is not None:
        p = apply_transform(T, p)
    return _record(
        pid,
        split,
        frame,
        None,
        x_cm=float(p[0]),
        y_cm=float(p[1]),
        z_cm=float(p[2]),
        sigma_z_cm=sz,
        method=disparity.get("method"),
        **base,
    )


def _check_inputs(disparity, rectification) -> None:
    """``disparity`` is a Disparity record and ``rectification`` gives f_px and baseline_cm."""
    if not isinstance(disparity, dict) or "found" not in disparity:
        raise NodeError(
            "locator.triangulate: `disparity` is not a Disparity record.",
            hint="wire it to a disparity.* node's `disparity` output.",
        )
    for key in ("f_px", "baseline_cm"):
        if rectification is None or key not in rectification:
            raise NodeError(
                f"locator.triangulate: the Rectification lacks {key!r}.",
                hint="wire `rectification` to rectifier.opencv's output.",
            )


def _truth_in_frame(params: TriangulateParams, t: dict | None, T, rig) -> list[float] | None:
    """The pair's true ball centre in the output frame (``T``: left camera to it, None for the
    left camera), from a left-camera or a table-frame truth; None when it has neither."""
    truth = None
    if t and t.get("center_left_cm") is not None:
        tc = np.asarray(t["center_left_cm"], float)
        truth = (apply_transform(T, tc) if T is not None else tc).tolist()
    elif t and t.get("center_table_cm") is not None:
        # measured on the table only (a ruler on the bench), in the table frame the wired table
        # frame defines
        T_known = T if T is not None else _known_transform(params, rig)
        if T_known is not None:
            tc = np.asarray(t["center_table_cm"], float)
            truth = (
                tc if T is not None else np.linalg.solve(T_known[:3, :3], tc - T_known[:3, 3])
            ).tolist()
    return truth
