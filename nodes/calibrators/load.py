"""Loader nodes: a calibration, a hand-eye transform or a table frame fitted by an earlier pipeline.

``calibrator.load`` reads a stereo calibration from

* the JSON a run writes (``<run>/<calibrator>/calibration.json``, with its ``.npz`` if any),
* an OpenCV FileStorage file (``.yml`` / ``.yaml`` / ``.xml``; the names of OpenCV's
  ``stereo_calib`` sample, ``M1 D1 M2 D2 R T``; what every calibrator here exports as
  ``opencv.yml``), or
* the left camera's ROS ``camera_info`` YAML, with ``right_path`` the right camera's.

An OpenCV file may come in two parts (``stereo_calib`` writes ``intrinsics.yml`` and
``extrinsics.yml``): ``path`` and ``right_path`` are then read together.

``calibrator.load_hand_eye`` and ``calibrator.load_table_frame`` read the ``HandEye`` /
``TableFrame`` JSON a run wrote. Given a ``calibration`` input, they refuse a file made for
another rig (image size, focal length, baseline), naming both files. Each node's cache key
follows the content of the files it reads, so editing a file reruns what depends on it, and
nothing else is recomputed.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nodes.calibrators._calib_io import (
    MAX_PRINCIPAL_OFFSET,
    calibration_outputs,
    read_opencv,
    read_ros,
    read_ros_pair,
)
from nodes.contracts.calibration_export import EXPORT_OUTPUTS
from nodes.contracts.calibration_file import (
    ArtifactLoadParams,
    array_keys,
    artifact_kind,
    artifact_reads,
    check_rig,
    read_artifact,
    resolve_path,
    with_npz,
)
from stereograph.api import Field, In, NodeError, Out, Params, PathField, data_file, node

__all__ = ["load", "load_hand_eye", "load_table_frame", "read_calibration_file"]

_CAL_ARRAYS = ("K1", "D1", "K2", "D2", "R", "T_cm", "T_table_from_left")


def _is_opencv_storage(path: Path) -> bool:
    data = path.read_bytes()
    head = data[:64].lstrip()
    # OpenCV 4 writes "%YAML:1.0", OpenCV 5 "%YAML 1.2" + "!!opencv-matrix" tags; ROS files have
    # neither.
    return (
        head.startswith(b"%YAML:")
        or head.startswith(b"<?xml")
        or head.startswith(b"<opencv_storage")
        or b"!!opencv-matrix" in data
    )


def read_calibration_file(
    path: Path,
    right_path: Path | None = None,
    cm_per_unit: float | None = None,
    image_size=None,
    label: str = "calibrator.load",
    max_principal_offset: float = MAX_PRINCIPAL_OFFSET,
) -> dict:
    """A ``StereoCalibration`` from a run's JSON, an OpenCV FileStorage file or two ROS camera_info
    files.

    Raises
    ------
    NodeError
        Missing file, wrong kind of file, or missing entries; the message names the file.
    """
    for p in (path, right_path):
        if p is not None:
            data_file(p, "a calibration file", label)
    suffix = path.suffix.lower()
    if suffix == ".json" and not (
        _is_opencv_storage(path) or b'"opencv-matrix"' in path.read_bytes()
    ):
        cal, fmt = _read_run_json(path, label, cm_per_unit), "json"
    else:
        cal, fmt = _read_foreign(
            path, right_path, cm_per_unit, image_size, label, max_principal_offset
        )
    if image_size is not None and list(cal["image_size"]) != [int(v) for v in image_size]:
        raise NodeError(
            f"{label}: {path} is for {cal['image_size'][0]}x{cal['image_size'][1]} px images, but "
            f"image_size says {image_size[0]}x{image_size[1]}.",
            hint="remove image_size, or give the calibration of these cameras",
        )
    why = calibration_values_problem(cal)
    if why:
        raise NodeError(
            f"{label}: {path}{' and ' + str(right_path) if right_path else ''}: {why}.",
            hint="give the calibration file of these cameras as the calibration tool wrote it; "
            "calibrate again if it was edited or damaged",
        )
    cal["method"] = f"loaded/{fmt}" + (f" ({cal['method']})" if cal.get("method") else "")
    cal["source_file"] = str(path) + (f" + {right_path}" if right_path else "")
    return cal


def _read_run_json(path: Path, label: str, cm_per_unit: float | None) -> dict:
    """A calibration a run wrote (``calibration.json``), in cm (``cm_per_unit`` converts one made
    in board squares)."""
    art = read_artifact(path, label, "StereoCalibration", "<run>/<calibrator>/calibration.json")
    if artifact_kind(art) != "a StereoCalibration":
        raise NodeError(
            f"{label}: {path} holds {artifact_kind(art)}, not a StereoCalibration.",
            hint="give a calibration file: <run>/<calibrator>/calibration.json, an OpenCV "
            "FileStorage .yml/.xml, or a ROS camera_info pair",
        )
    cal = array_keys(art, _CAL_ARRAYS, f"{label}: {path}")
    if cm_per_unit is None and cal.get("length_unit", "cm") == "squares":
        # (refused as the same calibration's opencv.yml and ROS files are: one rule for the
        # three formats)
        raise NodeError(
            f"{label}: cannot use {path}: its lengths are in board squares "
            "(calibrated without a "
            "square size): the unit of T is one square; give cm_per_unit = the "
            "square's size in cm.",
            hint="set cm_per_unit to the board's square size in cm",
        )
    if cm_per_unit is not None:
        unit = cal.get("length_unit", "cm")
        if unit == "cm":
            raise NodeError(
                f"{label}: {path} is in cm already; cm_per_unit would scale it again.",
                hint="remove cm_per_unit (it converts a calibration made in board squares)",
            )
        cal["T_cm"] = np.asarray(cal["T_cm"], float) * float(cm_per_unit)  # squares -> cm
        if cal.get("T_table_from_left") is not None:
            cal["T_table_from_left"] = np.asarray(cal["T_table_from_left"], float).copy()
            cal["T_table_from_left"][:3, 3] *= float(cm_per_unit)
        cal["length_unit"] = "cm"
    return cal


def _read_foreign(
    path: Path,
    right_path: Path | None,
    cm_per_unit: float | None,
    image_size,
    label: str,
    max_principal_offset: float,
) -> tuple[dict, str]:
    """``(calibration, "ros" | "opencv")`` from two ROS camera_info files or OpenCV FileStorage
    files; NodeError naming the files for anything else."""
    ros = None
    if not _is_opencv_storage(path) and path.suffix.lower() in (".yml", ".yaml"):
        try:
            ros = read_ros(path)
        except ValueError:
            ros = None
    try:
        if ros is None and right_path is not None and not _is_opencv_storage(right_path):
            raise NodeError(
                f"{label}: {path} is an OpenCV FileStorage file but {right_path} is not.",
                hint="right_path is the right camera's ROS camera_info (with a ROS "
                "`path`) or the "
                "second OpenCV file (stereo_calib's extrinsics.yml beside intrinsics.yml)",
            )
        if ros is not None:
            if right_path is None:
                raise NodeError(
                    f"{label}: {path} is a ROS camera_info file (one camera); the "
                    "right camera's "
                    "is needed too.",
                    hint="set right_path to the right camera's camera_info YAML",
                )
            cal = read_ros_pair(path, right_path, cm_per_unit)
            fmt = "ros"
        else:
            cal = read_opencv(
                path,
                cm_per_unit,
                image_size,
                extra=right_path,
                max_principal_offset=max_principal_offset,
            )
            fmt = "opencv"
    # (OpenCV's parser on a malformed file: cv2.error, or
    except (ValueError, cv2.error, SystemError) as exc:
        # SystemError "returned a result with an exception set")
        exc = str(exc).strip().splitlines()[-1] if not isinstance(exc, ValueError) else exc
        raise NodeError(
            f"{label}: cannot use {path}{' and ' + str(right_path) if right_path else ''}: {exc}.",
            hint="give OpenCV stereo_calib names (M1 D1 M2 D2 R T) with `unit` and "
            "image_width / "
            "image_height in the file or cm_per_unit / image_size in the params, or a ROS "
            "camera_info pair",
        ) from None
    return cal, fmt


# a camera's image side; beyond, a mistyped or hostile size (an allocation of exabytes)
MAX_IMAGE_SIDE_PX = 32768


MAX_CALIBRATION_VALUE = 1e6  # distortion coefficients, baseline (cm: 10 km)


def calibration_values_problem(cal: dict) -> str | None:
    """What makes a loaded calibration unusable, in words, or None: the numbers are checked for what
    they mean at load, not deep inside a later node (a zero focal length divided by in the live
    loop)."""
    size = cal.get("image_size")
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError, OverflowError):
        return f"image_size {size!r} is not two whole numbers"
    if not (0 < w <= MAX_IMAGE_SIDE_PX and 0 < h <= MAX_IMAGE_SIDE_PX):
        return f"image_size {w}x{h} px is not a camera's (each side 1 to {MAX_IMAGE_SIDE_PX} px)"
    for name in ("K1", "K2"):
        K = np.asarray(cal.get(name), float)
        if K.shape != (3, 3) or not np.isfinite(K).all():
            return f"{name} is not a finite 3x3 camera matrix"
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            return f"{name}'s focal lengths ({K[0, 0]:g}, {K[1, 1]:g} px) are not positive"
        # (a focal length of 1000 image widths is a field of view under 0.06 degrees; the bounds
        # also keep later products clear of overflow)
        largest = np.abs(K).max()
        if largest > 1000.0 * max(w, h):
            return f"{name} holds {largest:g} px: not a camera matrix of {w}x{h} px images"
    for name in ("D1", "D2"):
        D = np.asarray(cal.get(name), float).ravel()
        if D.size not in (4, 5, 8, 12, 14) or not np.all(np.abs(D) <= MAX_CALIBRATION_VALUE):
            return (
                f"{name} has {D.size} distortion coefficients (OpenCV's models have 4, 5, 8, "
                f"12 or 14, finite and within +-{MAX_CALIBRATION_VALUE:g})"
            )
    R = np.asarray(cal.get("R"), float)
    if not _is_rotation(R, atol=1e-3) or not np.linalg.det(R) > 0:
        return "R is not a rotation (a finite 3x3 matrix with R R^T = I and det +1)"
    T = np.asarray(cal.get("T_cm"), float).ravel()
    longest = np.abs(T).max() if T.size == 3 else 0.0
    if not np.isfinite(longest) or not longest > 1e-6:
        return "the baseline T is zero or not three finite numbers: the two cameras would be one"
    if longest > MAX_CALIBRATION_VALUE:
        return f"the baseline T ({longest:g} in the file's length unit) is not a stereo rig's"
    return None


def _is_rotation(R: np.ndarray, atol: float) -> bool:
    """A 3x3 matrix with R R^T = I within ``atol``. Entries beyond +-1, which no rotation has (NaN
    and infinities too), are refused before the product: 1e308 in a file would overflow it, and
    NumPy's warning would reach the user's terminal beside the refusal."""
    return (
        R.shape == (3, 3)
        and bool(np.all(np.abs(R) <= 1 + atol))
        and np.allclose(R @ R.T, np.eye(3), atol=atol)
    )


class LoadParams(Params):
    path: str = PathField(
        ...,
        description="Calibration file, relative to the pipeline file: a run's calibration.json, "
        "an OpenCV FileStorage .yml/.yaml/.xml, or the left camera's ROS "
        "camera_info YAML.",
    )
    right_path: str | None = PathField(
        None,
        description="The right camera's ROS camera_info YAML (with a ROS `path`), "
        "or a second OpenCV file read with the first (stereo_calib's "
        "extrinsics.yml beside intrinsics.yml).",
    )
    cm_per_unit: float | None = Field(
        None,
        gt=0,
        description="Centimetres per unit of T in an OpenCV file (0.1 for mm, 100 for m, the "
        "square "
        "size in cm for a file in squares); default: the file's `unit` entry. For a run's "
        "calibration.json made without a square size: the square's size in cm. For a ROS "
        "camera_info pair: default 100 (metres); the square's size in cm for a pair "
        "written without a square size (its first line says so).",
    )
    image_size: tuple[int, int] | None = Field(
        None,
        description="Image width, height (px), for OpenCV files that do not state it "
        "(stereo_calib's do "
        "not); checked against the file's when both exist, else against the principal points.",
    )
    max_principal_offset: float = Field(
        MAX_PRINCIPAL_OFFSET,
        gt=0,
        le=0.5,
        description="With image_size given for a file that has none: the farthest a principal "
        "point may lie from "
        "the centre of images of that size (fraction of the width / height); farther -> "
        "refused as the "
        "wrong size.",
    )


def _load_reads(params: LoadParams, pipeline_dir: Path) -> list[Path]:
    return with_npz([resolve_path(p, pipeline_dir) for p in (params.path, params.right_path) if p])


@node(
    "calibrator.load",
    outputs={
        "calibration": Out("StereoCalibration", save=True, description="The loaded calibration."),
        **EXPORT_OUTPUTS,
    },
    params=LoadParams,
    version="1",
    reads=_load_reads,
)
def load(params: LoadParams, ctx=None) -> dict:
    """Load a stereo calibration file (run JSON, OpenCV FileStorage, or a ROS camera_info pair)."""
    pdir = ctx.pipeline_dir if ctx is not None else Path.cwd()
    right = resolve_path(params.right_path, pdir) if params.right_path else None
    cal = read_calibration_file(
        resolve_path(params.path, pdir),
        right,
        params.cm_per_unit,
        params.image_size,
        max_principal_offset=params.max_principal_offset,
    )
    return calibration_outputs(cal, ctx)


# --------------------------------------------------------------------------- hand-eye, table frame
def _load_matrix_artifact(
    params: ArtifactLoadParams,
    ctx,
    calibration,
    label: str,
    kind: str,
    made_by: str,
    key: str,
    arrays: tuple[str, ...],
) -> dict:
    path = resolve_path(params.path, ctx.pipeline_dir if ctx is not None else Path.cwd())
    art = read_artifact(path, label, kind, made_by)
    if artifact_kind(art) != f"a {kind}":
        raise NodeError(
            f"{label}: {path} holds {artifact_kind(art)}, not a {kind}.",
            hint=f"give the file a run wrote for it: {made_by}",
        )
    art = array_keys(art, arrays, f"{label}: {path}")
    T = art[key]
    if (
        T.shape != (4, 4)
        or not _is_rotation(T[:3, :3], atol=1e-6)
        or not np.allclose(T[3], [0, 0, 0, 1])
    ):
        raise NodeError(
            f"{label}: {key} in {path} is not a rigid 4x4 transform.",
            hint=f"give the file a run wrote for it: {made_by}",
        )
    if np.linalg.det(T[:3, :3]) < 0:  # orthonormal, yet a mirror: every target would land mirrored
        raise NodeError(
            f"{label}: {key} in {path} is a mirror image, not a rotation (its determinant "
            "is -1): a "
            "left-handed frame, or one axis flipped by hand.",
            hint=f"give the file a run wrote for it ({made_by}), or fix the flipped axis",
        )
    check_rig(
        label,
        art.get("rig"),
        path,
        calibration,
        params.rig_tolerance,
        ctx.warn if ctx is not None else None,
    )
    art["source_file"] = str(path)
    return art


_CAL_IN = {
    "calibration": In(
        "StereoCalibration",
        optional=True,
        description="The rig's calibration: the file must be made for it (size, f, baseline).",
    )
}


@node(
    "calibrator.load_hand_eye",
    inputs=_CAL_IN,
    outputs={
        "hand_eye": Out("HandEye", description="Left-camera pose in the arm-base frame, as fitted.")
    },
    params=ArtifactLoadParams,
    version="1",
    reads=artifact_reads,
)
def load_hand_eye(params: ArtifactLoadParams, calibration=None, ctx=None) -> dict:
    """Load a hand-eye transform a run fitted (<run>/<node>/hand_eye.json), checked against the
    rig."""
    return {
        "hand_eye": _load_matrix_artifact(
            params,
            ctx,
            calibration,
            "calibrator.load_hand_eye",
            "HandEye",
            "<run>/<hand-eye node>/hand_eye.json",
            "T_base_from_left",
            ("T_base_from_left", "T_base_from_table", "T_base_from_left_truth"),
        )
    }


@node(
    "calibrator.load_table_frame",
    inputs=_CAL_IN,
    outputs={
        "table_frame": Out(
            "TableFrame", description="T_table_from_left (cm), as fitted from the board."
        )
    },
    params=ArtifactLoadParams,
    version="1",
    reads=artifact_reads,
)
def load_table_frame(params: ArtifactLoadParams, calibration=None, ctx=None) -> dict:
    """Load a table frame a run found (<run>/<node>/table_frame.json), checked against the rig."""
    return {
        "table_frame": _load_matrix_artifact(
            params,
            ctx,
            calibration,
            "calibrator.load_table_frame",
            "TableFrame",
            "<run>/<table-frame node>/table_frame.json",
            "T_table_from_left",
            ("T_table_from_left",),
        )
    }
