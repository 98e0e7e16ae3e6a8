"""``calibrator.hand_eye``: the pose of the (physical) left camera in the arm-base frame.

HandEye artifact::

    {"T_base_from_left": 4x4 (cm)         # X_base = T @ [X_left, 1]
     "T_base_from_table": 4x4 | None      # when the arm base is placed in the table frame
     "method": "given" | "pairs" | "rig" | "located",
     "n_pairs": int,                      # point pairs used by a fit (0 otherwise)
     "residual_cm": {"rms": float, "max": float, "per_pair": [float, ...]} | None,
     "T_base_from_left_truth": 4x4 | None,  # from the rig's ground truth, when known (for scoring)
     "rig": {"image_size", "fx_px", "baseline_cm"} | None}  # the rig it was made for, when known

Modes:

* ``given``: ``T_base_from_left`` from YAML (``camera_in_base``: translation + roll/pitch/yaw).
* ``pairs``: a rigid least-squares fit (Kabsch / Umeyama, no scale) of >= 3 point pairs: an object
  located by the cameras (left-camera frame, cm) and the same point reached by the arm
  (arm-base frame, cm), given inline or in a CSV file.
* ``rig``: composed from ``T_table_from_left`` and the arm base's pose in the table frame
  (``base_in_table``): the wired ``table_frame`` (a board lying on the table,
  ``calibrator.table_frame``: a real bench) when there is one, else the rig's ground truth (exact,
  for synthetic rigs).
* ``located``: the realistic calibration on a synthetic rig: every found training location (camera
  measurement, errors included) paired with where the arm would touch that ball (its true centre
  in the arm-base frame), then fitted as in ``pairs``.
"""

from __future__ import annotations

import csv
import math
from typing import Literal

import numpy as np
from pydantic import model_validator

from stereograph.api import Field, In, NodeError, Out, Params, PathField, data_file, node


# --------------------------------------------------------------------------- library
def pose_matrix(translation_cm, rpy_deg) -> np.ndarray:
    """4x4 homogeneous transform from a translation (cm) and roll/pitch/yaw (deg, applied x then y
    then z).

    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
    """
    r, p, y = (math.radians(float(a)) for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = np.asarray(translation_cm, float)
    return T


def invert_pose(T) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    T = np.asarray(T, float)
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def transform_points(T, X) -> np.ndarray:
    """Apply a 4x4 transform to points ``X`` of shape (3,) or (N, 3)."""
    X = np.asarray(X, float)
    return X @ np.asarray(T, float)[:3, :3].T + np.asarray(T, float)[:3, 3]


def fit_rigid(src, dst, with_scale: bool = False) -> tuple[np.ndarray, float]:
    """Least-squares rigid transform (Kabsch / Umeyama) mapping ``src`` points onto ``dst``.

    Parameters
    ----------
    src, dst : array_like, shape (N, 3), N >= 3
        Corresponding points (cm), e.g. camera measurements and arm positions.
    with_scale : bool
        Also fit a uniform scale (Umeyama's similarity); a rigid transform when false.

    Returns
    -------
    T : ndarray, shape (4, 4)
        ``dst ~= T @ src`` (the rotation part is a proper rotation, det = +1, times the scale).
    scale : float

    Raises
    ------
    ValueError
        Fewer than 3 pairs or points (nearly) on a line, which leave the rotation undetermined.
    """
    src = np.asarray(src, float).reshape(-1, 3)
    dst = np.asarray(dst, float).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise ValueError(f"need >= 3 point pairs of equal count, got {len(src)} and {len(dst)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    S, D = src - mu_s, dst - mu_d
    sv = np.linalg.svd(S, compute_uv=False)
    if sv[1] <= 1e-6 * max(sv[0], 1e-12):
        raise ValueError(
            "the camera points lie (nearly) on a line, so the rotation about it is undetermined"
        )
    U, sig, Vt = np.linalg.svd(D.T @ S / len(src))
    E = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])  # no reflections
    R = U @ E @ Vt
    scale = float(np.trace(np.diag(sig) @ E) / (S**2).sum(1).mean()) if with_scale else 1.0
    T = np.eye(4)
    T[:3, :3] = scale * R
    T[:3, 3] = mu_d - scale * R @ mu_s
    return T, scale


def residuals_cm(T, src, dst) -> np.ndarray:
    """Distances (cm) between ``T @ src`` and ``dst``, per pair."""
    return np.linalg.norm(transform_points(T, src) - np.asarray(dst, float), axis=1)


# --------------------------------------------------------------------------- params
class Pose(Params):
    """A rigid pose: translation (cm) and roll/pitch/yaw (deg, R = Rz @ Ry @ Rx)."""

    translation_cm: list[float] = Field(
        [0.0, 0.0, 0.0], min_length=3, max_length=3, description="Translation (cm)."
    )
    rpy_deg: list[float] = Field(
        [0.0, 0.0, 0.0],
        min_length=3,
        max_length=3,
        description="Roll, pitch, yaw (deg) about x, y, z, applied in that order.",
    )


class PointPair(Params):
    """One calibration pair."""

    camera_cm: list[float] = Field(
        ...,
        min_length=3,
        max_length=3,
        description="Object position located by the cameras (left-camera frame, cm).",
    )
    arm_cm: list[float] = Field(
        ...,
        min_length=3,
        max_length=3,
        description="The same point reached by the arm's tool point (arm-base frame, cm).",
    )


class HandEyeParams(Params):
    mode: Literal["given", "pairs", "rig", "located"] = Field(
        "given",
        description="given: camera_in_base; pairs: fit pairs/pairs_file; rig: exact from the rig "
        "truth "
        "and base_in_table; located: fit located training balls to their true positions.",
    )
    camera_in_base: Pose | None = Field(
        None, description="mode given: left-camera pose in the arm-base frame."
    )
    base_in_table: Pose | None = Field(
        None,
        description="Arm-base pose in the table frame (modes rig, located; "
        "also lets table-frame locations be used).",
    )
    pairs: list[PointPair] = Field(
        default_factory=list, description="mode pairs: >= 3 point pairs (cm)."
    )
    pairs_file: str | None = PathField(
        None,
        description="mode pairs: CSV with header cam_x,cam_y,cam_z,arm_x,arm_y,arm_z "
        "(cm), relative to the pipeline file.",
    )
    split: Literal["train", "test", "all"] = Field(
        "train", description="mode located: which items to fit on."
    )
    max_residual_cm: float = Field(
        1.0, gt=0, description="Refuse a fit whose RMS residual exceeds this (cm)."
    )

    @model_validator(mode="after")
    def _check_mode(self):
        # What each mode needs from the YAML is checked here, so `stereograph validate` reports it
        # (exit 2).
        if self.mode == "given" and self.camera_in_base is None:
            raise ValueError(
                "mode given needs camera_in_base: {translation_cm: [x, y, z], rpy_deg: [r, p, y]} "
                "(or use mode pairs with measured point pairs)"
            )
        if self.mode == "pairs" and not self.pairs_file and len(self.pairs) < 3:
            raise ValueError(
                f"mode pairs got {len(self.pairs)} point pairs and no pairs_file; >= 3 pairs "
                "(camera_cm, arm_cm) or a pairs_file are needed"
            )
        if self.mode in ("rig", "located") and self.base_in_table is None:
            raise ValueError(
                f"mode {self.mode} needs base_in_table (the arm base's pose in the table frame); "
                "or use mode given / pairs"
            )
        return self


def _read_pairs(path) -> tuple[np.ndarray, np.ndarray]:
    data_file(path, "a CSV of camera/arm point pairs", "calibrator.hand_eye")
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        cam = np.array([[float(r[k]) for k in ("cam_x", "cam_y", "cam_z")] for r in rows])
        arm_ = np.array([[float(r[k]) for k in ("arm_x", "arm_y", "arm_z")] for r in rows])
    except FileNotFoundError:
        raise NodeError(
            f"hand-eye pairs file {path} does not exist.",
            hint="fix pairs_file (relative to the pipeline).",
        ) from None
    except (KeyError, ValueError, TypeError) as e:
        raise NodeError(
            f"hand-eye pairs file {path} is not a CSV with numeric columns "
            f"cam_x,cam_y,cam_z,arm_x,arm_y,arm_z ({e}).",
            hint="fix the header / values.",
        ) from e
    return cam.reshape(-1, 3), arm_.reshape(-1, 3)


def _reads(params: HandEyeParams, pipeline_dir):
    from pathlib import Path

    if params.pairs_file:
        p = Path(params.pairs_file).expanduser()
        return [p if p.is_absolute() else Path(pipeline_dir) / p]
    return []


def _truth_T_table_from_left(views):
    truth = (views or {}).get("truth") if isinstance(views, dict) else None
    T = truth.get("T_table_from_left") if truth else None
    return None if T is None else np.asarray(T, float)


def _fit(cam, arm_pts, params: HandEyeParams, source: str):
    try:
        T, _ = fit_rigid(cam, arm_pts)
    except ValueError as e:
        raise NodeError(
            f"hand-eye fit from {source}: {e}.",
            hint="use >= 3 pairs spread over the workspace, not on one line.",
        ) from e
    res = residuals_cm(T, cam, arm_pts)
    rms = float(np.sqrt(np.mean(res**2)))
    if rms > params.max_residual_cm:
        raise NodeError(
            f"hand-eye fit from {source}: RMS residual {rms:.3f} cm > max_residual_cm "
            f"{params.max_residual_cm} cm (worst pair {int(np.argmax(res))}: {res.max():.3f} cm).",
            hint="check that each camera point and arm point are the same physical point, in cm, "
            "in the left-camera and arm-base frames.",
        )
    return T, {"rms": rms, "max": float(res.max()), "per_pair": [float(r) for r in res]}


@node(
    "calibrator.hand_eye",
    inputs={
        "views": In(
            "StereoViews", optional=True, description="For the rig's truth (modes rig, located)."
        ),
        "locations": In(
            "Location", gather=True, optional=True, description="mode located: located balls."
        ),
        "table_frame": In(
            "TableFrame",
            optional=True,
            description="mode rig: the measured table frame (calibrator.table_frame).",
        ),
    },
    outputs={
        "hand_eye": Out("HandEye", save=True, description="Left-camera pose in the arm-base frame.")
    },
    params=HandEyeParams,
    version="1",
    reads=_reads,
)
def hand_eye(params: HandEyeParams, views=None, locations=None, table_frame=None, ctx=None):
    """Left-camera pose in the arm-base frame: given, fitted from point pairs (Kabsch), or from rig
    truth."""
    T_base_from_table, T_truth, T_measured = _rig_poses(params, views, table_frame)
    rig = (table_frame or {}).get("rig") or next(
        (
            loc.get("rig")
            for loc in (locations or {}).values()
            if isinstance(loc, dict) and loc.get("rig")
        ),
        None,
    )
    residual, n_pairs = None, 0
    if params.mode == "given":  # camera_in_base is required by HandEyeParams
        T = pose_matrix(params.camera_in_base.translation_cm, params.camera_in_base.rpy_deg)
    elif params.mode == "pairs":
        cam, arm_pts, source = _given_pairs(params, ctx)
        T, residual = _fit(cam, arm_pts, params, source)
        n_pairs = len(cam)
    elif params.mode == "rig" and T_measured is not None:
        T = T_measured
    else:
        if T_truth is None:
            raise NodeError(
                f"calibrator.hand_eye mode {params.mode} needs the rig's truth "
                "(T_table_from_left on the "
                "views input)"
                + (" or a table_frame" if params.mode == "rig" else "")
                + " and base_in_table.",
                hint="wire table_frame: <calibrator.table_frame>.table_frame (a board on the "
                "table), or "
                "views: <source>.views from a synthetic source, and set base_in_table; or use "
                "mode given / pairs.",
            )
        if params.mode == "rig":
            T = T_truth
        else:
            cam, arm_pts = _located_pairs(params, locations, T_truth)
            T, residual = _fit(np.array(cam), np.array(arm_pts), params, "located training balls")
            n_pairs = len(cam)
    if T_truth is not None and ctx is not None and params.mode != "rig":
        dt = float(np.linalg.norm(T[:3, 3] - T_truth[:3, 3]))
        if dt > 0.5:
            ctx.warn(f"hand-eye vs rig truth: translation differs by {dt:.3f} cm")
    return {
        "hand_eye": {
            "T_base_from_left": T,
            "T_base_from_table": T_base_from_table,
            "method": params.mode,
            "n_pairs": int(n_pairs),
            "residual_cm": residual,
            "T_base_from_left_truth": T_truth,
            "rig": rig,
        }
    }


def _given_pairs(params: HandEyeParams, ctx) -> tuple[np.ndarray, np.ndarray, str]:
    """``(camera points, arm points, where from)`` of mode pairs: ``pairs_file`` or ``pairs``,
    cm; at least 3."""
    if params.pairs_file:
        path = ctx.path(params.pairs_file) if ctx else params.pairs_file
        cam, arm_pts = _read_pairs(path)
        source = str(path)
    else:
        cam = np.array([p.camera_cm for p in params.pairs]).reshape(-1, 3)
        arm_pts = np.array([p.arm_cm for p in params.pairs]).reshape(-1, 3)
        source = "pairs"
    if len(cam) < 3:
        raise NodeError(
            f"calibrator.hand_eye mode pairs got {len(cam)} point pairs; >= 3 are needed.",
            hint="add pairs (camera_cm, arm_cm) or a pairs_file.",
        )
    return cam, arm_pts, source


def _located_pairs(
    params: HandEyeParams, locations: dict | None, T_truth: np.ndarray
) -> tuple[list, list]:
    """``(camera points, arm points)`` of mode located: each found ball of the split, where the
    camera saw it and where the rig's truth puts it in the arm's frame; at least 3."""
    cam, arm_pts = [], []
    for item in (locations or {}).values():
        if not item.get("found") or item.get("truth_cm") is None:
            continue
        if params.split != "all" and item.get("split", "train") != params.split:
            continue
        if item.get("frame", "left_camera") != "left_camera":
            raise NodeError(
                f"calibrator.hand_eye mode located needs left-camera locations, got frame "
                f"{item.get('frame')!r} for {item.get('pair')}.",
                hint="wire the locator's left-camera output.",
            )
        cam.append([item["x_cm"], item["y_cm"], item["z_cm"]])
        arm_pts.append(transform_points(T_truth, item["truth_cm"]))
    if len(cam) < 3:
        raise NodeError(
            f"calibrator.hand_eye mode located found {len(cam)} usable "
            f"{params.split} locations "
            "(found, with truth); >= 3 are needed.",
            hint="wire locations: <locator>.location over a source with ground truth, "
            "or use "
            "split: all.",
        )
    return cam, arm_pts


def _rig_poses(
    params: HandEyeParams, views, table_frame
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """``(T_base_from_table, the camera's pose in the base from the rig's truth, from the measured
    table frame)``; each None when what it needs is not given."""
    T_base_from_table = (
        invert_pose(pose_matrix(params.base_in_table.translation_cm, params.base_in_table.rpy_deg))
        if params.base_in_table
        else None
    )
    T_tl = _truth_T_table_from_left(views)
    T_truth = (
        T_base_from_table @ T_tl if (T_tl is not None and T_base_from_table is not None) else None
    )
    T_measured = (
        T_base_from_table @ np.asarray(table_frame["T_table_from_left"], float)
        if (table_frame is not None and T_base_from_table is not None)
        else None
    )
    return T_base_from_table, T_truth, T_measured
