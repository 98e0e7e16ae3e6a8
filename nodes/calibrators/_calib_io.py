"""Stereo calibrations as the files users already have: OpenCV FileStorage and ROS ``camera_info``.

* **OpenCV FileStorage** (YAML, or XML when read): the names OpenCV's ``stereo_calib`` sample
  writes -- ``M1 D1 M2 D2`` (intrinsics.yml) and ``R T R1 R2 P1 P2 Q`` (extrinsics.yml) -- in one
  file, plus ``image_width``, ``image_height``, ``unit`` (the unit of ``T`` and of ``P2``'s /
  ``Q``'s lengths: ``cm`` here) and ``rms_px``. Lengths are in the board's unit, as OpenCV's own
  tools write them; OpenCV's sample, with its square size 1, writes them in squares.
* **ROS camera_info** YAML, one per camera (``image_width``, ``image_height``, ``camera_name``,
  ``camera_matrix``, ``distortion_model``, ``distortion_coefficients``, ``rectification_matrix``,
  ``projection_matrix``), lengths in **metres** as ROS expects (only ``projection_matrix``'s
  ``Tx = -fx' B`` of the right camera carries one).

Reading a pair of ROS files back gives the stereo pose exactly: the right camera sits at
``X_r = R2^T (R1 X_l + t)``, ``t = (P2[0,3] / P2[0,0], P2[1,3] / P2[1,1], 0)``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import cv2
import numpy as np

from nodes.calibrators._board import check_overall_rms
from nodes.contracts.calibration_export import export_texts, rectify_params
from stereograph.api import NodeError, parse_yaml_data

__all__ = [
    "CM_PER_UNIT",
    "calibration_outputs",
    "calibration_summary",
    "read_opencv",
    "read_ros",
    "read_ros_pair",
]

#: Centimetres per length unit a calibration file may state.
CM_PER_UNIT = {
    "mm": 0.1,
    "millimeter": 0.1,
    "millimetre": 0.1,
    "cm": 1.0,
    "centimeter": 1.0,
    "centimetre": 1.0,
    "m": 100.0,
    "meter": 100.0,
    "metre": 100.0,
    "in": 2.54,
    "inch": 2.54,
}
# How far a principal point may lie from the image centre, as a fraction of the width / height, when
# the image size is given by hand for a file that does not state it
# (LoadParams.max_principal_offset). A lens's principal point lies within a few % of the centre
# (OpenCV's stereo sample pairs: 3.5 %); a size twice as large puts it at 25 % (a 640x480
# calibration read as 1280x960: (322, 238) against the centre (640, 480)), a 4:3 size for a 16:9
# calibration (1280x960 for 1280x720) at 12.5 %.
MAX_PRINCIPAL_OFFSET = 0.1


def check_principal_points(
    K1, K2, image_size, path: Path, max_offset: float = MAX_PRINCIPAL_OFFSET
) -> None:
    """Refuse an image size given for a file without one when either camera's principal point lies
    far from the centre of images of that size: the size is then almost surely not the calibrated
    one, and every rectification, working range and location made with it would be wrong.

    Raises
    ------
    NodeError
        Naming both principal points, the size given, the size they point to and the limit.
    """
    w, h = (float(v) for v in image_size)
    pp = {side: (float(K[0, 2]), float(K[1, 2])) for side, K in (("left", K1), ("right", K2))}
    off = max(max(abs(cx - w / 2) / w, abs(cy - h / 2) / h) for cx, cy in pp.values())
    if off <= max_offset:
        return
    cx, cy = pp["left"]
    said = "; ".join(f"{side} ({x:.1f}, {y:.1f}) px" for side, (x, y) in pp.items())
    raise NodeError(
        f"{path} does not give its image size, and the image_size given, {w:.0f}x{h:.0f} "
        "px, does not "
        f"fit it: the principal points, {said}, lie {off:.0%} of the image size from its centre "
        f"({w / 2:.0f}, {h / 2:.0f}) px (at most {max_offset:.0%} is plausible). They "
        "point to images of "
        f"about {2 * cx:.0f}x{2 * cy:.0f} px.",
        hint="give image_size as the size of the images this calibration was made from (the "
        "principal "
        "point lies near their centre); if the principal point really is that far off-centre (a "
        "cropped sensor), raise max_principal_offset",
    )


_CRIT = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-10)


def _mean_abs_dy(cal: dict, rect: dict) -> float | None:
    """Mean |v_left - v_right| (px) of the calibration's matched corners after rectification, or
    None."""
    cl, cr = cal.get("corners_left_px") or {}, cal.get("corners_right_px") or {}
    dys = []
    for vid, a in cl.items():
        b = cr.get(vid)
        # (ChArUco views keep matched corners only; others are skipped)
        if b is None or len(a) != len(b):
            continue
        pa = cv2.undistortPoints(
            np.asarray(a, np.float64).reshape(-1, 1, 2),
            np.asarray(cal["K1"], float),
            np.asarray(cal["D1"], float),
            R=rect["R1"],
            P=rect["P1"],
            criteria=_CRIT,
        )
        pb = cv2.undistortPoints(
            np.asarray(b, np.float64).reshape(-1, 1, 2),
            np.asarray(cal["K2"], float),
            np.asarray(cal["D2"], float),
            R=rect["R2"],
            P=rect["P2"],
            criteria=_CRIT,
        )
        dys.append(np.abs(pa.reshape(-1, 2)[:, 1] - pb.reshape(-1, 2)[:, 1]))
    return float(np.concatenate(dys).mean()) if dys else None


def calibration_summary(cal: dict) -> tuple[dict, str]:
    """The facts a person checks first, and the one-line summary the run prints.

    Returns
    -------
    facts : dict
        ``baseline_cm`` (|T|, cm), ``dy_mean_px`` (mean |Δy| of the calibration corners after
        rectification, px; None without corners).
    line : str
        ``"RMS 0.232 px, baseline 8.003 cm, mean |Δy| 0.09 px"``.
    """
    baseline = float(np.linalg.norm(np.asarray(cal["T_cm"], float)))
    dy = _mean_abs_dy(cal, rectify_params(cal)) if cal.get("corners_left_px") else None
    rms = cal.get("rms_px")
    unit = cal.get("length_unit", "cm")
    line = (
        (f"RMS {rms:.4f} px" if rms is not None else "RMS n/a")
        + f", baseline {baseline:.4f} {unit}"
        + (f", mean |Δy| {dy:.3f} px" if dy is not None else ", mean |Δy| n/a (no corners)")
    )
    return {"baseline_cm": baseline, "dy_mean_px": dy}, line


# --------------------------------------------------------------------------- OpenCV FileStorage
MAX_MATRIX_SIDE = 64  # a calibration's matrices are 3x3, 3x4, 4x4 or 1x14 at most
_DT_CHANNELS = re.compile(r"^(\d*)([ucwsifdh])$")


def matrix_node_problem(node) -> str | None:
    """What is wrong with an ``!!opencv-matrix`` node's header, in words, or None.

    OpenCV 5.0.0's ``FileNode.mat()`` trusts ``rows`` / ``cols``: ``cols: -1`` corrupts the heap and
    the process aborts later, so a file from elsewhere is checked before OpenCV reads it.
    """
    rows, cols, sizes, dt, data = (node.getNode(k) for k in ("rows", "cols", "sizes", "dt", "data"))
    # !!opencv-nd-matrix (a 1-D array as OpenCV writes it; XML: one size is a number)
    if not sizes.empty():
        items = [sizes.at(i) for i in range(sizes.size())] if sizes.isSeq() else [sizes]
        if not 1 <= len(items) <= 2 or not all(x.isInt() for x in items):
            return "sizes must be one or two whole numbers"
        dims = [int(x.real()) for x in items]
    elif rows.isInt() and cols.isInt():
        dims = [int(rows.real()), int(cols.real())]
    else:
        return "rows and cols must be whole numbers"
    if not all(1 <= d <= MAX_MATRIX_SIDE for d in dims):
        return (
            f"{'x'.join(map(str, dims))} is not the size of a calibration matrix (each side 1 "
            f"to {MAX_MATRIX_SIDE})"
        )
    m = _DT_CHANNELS.match(dt.string().strip()) if dt.isString() else None
    if m is None:
        return "dt must name an element type (d, f, i, ...)"
    n = math.prod(dims) * int(m.group(1) or 1)
    if not data.isSeq() or data.size() != n:
        return f"data must hold {n} numbers"
    return None


def read_opencv(
    path: Path,
    cm_per_unit: float | None = None,
    image_size=None,
    extra: Path | None = None,
    max_principal_offset: float = MAX_PRINCIPAL_OFFSET,
) -> dict:
    """Read a stereo calibration from an OpenCV FileStorage file (.yml / .yaml / .xml / .json).

    Parameters
    ----------
    path : Path
        The file. Needs ``M1 D1 M2 D2 R T`` (stereo_calib's names; ``K1 K2`` are accepted for
        ``M1 M2``). One file, or intrinsics and extrinsics merged into one.
    cm_per_unit : float, optional
        Centimetres per unit of ``T`` (0.1 for mm, 100 for m, the square size in cm for a file in
        squares). Default: from the file's ``unit`` entry.
    image_size : (w, h), optional
        Pixels; default from ``image_width`` / ``image_height`` (or ``image_size``) in the file.
        Given for a file without a size, it is checked against the principal points
        (:func:`check_principal_points`).
    extra : Path, optional
        A second FileStorage file read with the first (stereo_calib's ``extrinsics.yml`` beside its
        ``intrinsics.yml``); an entry in both is taken from ``path``.
    max_principal_offset : float
        Largest distance of a principal point from the centre of images of a hand-given
        ``image_size`` (fraction of the width / height).

    Returns
    -------
    dict
        A ``StereoCalibration``.

    Raises
    ------
    ValueError
        A missing matrix, unit or image size; the message names what and where.
    """
    stores = [
        cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ) for p in (path, extra) if p is not None
    ]
    try:
        for p, fs in zip((path, extra), stores):
            if not fs.isOpened():
                raise ValueError(
                    f"OpenCV cannot open {p} as a FileStorage file (YAML starting with "
                    "%YAML, or XML "
                    "with <opencv_storage>)"
                )

        def scalar(*names):
            return _fs_scalar(stores, *names)

        got = _matrices(stores)
        cm_per_unit = _cm_per_unit(path, scalar("unit", "units", "length_unit"), cm_per_unit)
        by_hand, image_size = _image_size(stores, image_size)
        rms = scalar("rms_px", "rms")
        rms_px = float(rms.real()) if rms is not None and rms.isReal() else None
        board = _board_entries(scalar)
    finally:
        for fs in stores:
            fs.release()
    if (
        got["K1"].shape != (3, 3)
        or got["K2"].shape != (3, 3)
        or got["R"].size != 9
        or got["T"].size != 3
    ):
        raise ValueError("M1 / M2 / R must be 3x3 and T 3x1")
    # (a 640x480 calibration read as 1280x960 was taken, its principal point at a quarter)
    if by_hand:
        check_principal_points(got["K1"], got["K2"], image_size, path, max_principal_offset)
    return {
        "K1": got["K1"],
        "D1": got["D1"].ravel(),
        "K2": got["K2"],
        "D2": got["D2"].ravel(),
        "R": got["R"].reshape(3, 3),
        "T_cm": got["T"].ravel() * float(cm_per_unit),
        "image_size": [int(image_size[0]), int(image_size[1])],
        "rms_px": rms_px,
        "per_view_rms_px": {},
        "rejected_views": [],
        **({"board": board} if board else {}),
    }


# each StereoCalibration matrix, and the names a FileStorage file may give it
_MATRIX_NAMES = (
    ("K1", ("M1", "K1", "cameraMatrix1")),
    ("D1", ("D1", "distCoeffs1")),
    ("K2", ("M2", "K2", "cameraMatrix2")),
    ("D2", ("D2", "distCoeffs2")),
    ("R", ("R",)),
    ("T", ("T",)),
)


def _matrices(stores: list) -> dict[str, np.ndarray]:
    """K1 D1 K2 D2 R T of a FileStorage file, whatever the names it gives them; ValueError
    naming the missing ones."""
    got = {k: _fs_mat(stores, *names) for k, names in _MATRIX_NAMES}
    missing = [k for k, v in got.items() if v is None]
    if missing:
        raise ValueError(
            f"it lacks {', '.join({'K1': 'M1', 'K2': 'M2'}.get(k, k) for k in missing)} "
            "(stereo_calib's names: M1 D1 M2 D2 from intrinsics.yml, R T from extrinsics.yml; "
            "give both files: path and right_path)"
        )
    return got


def _fs_scalar(stores: list, *names: str):
    """The first non-empty FileStorage node of ``names`` in ``stores`` (the first file first)."""
    return next(
        (node for n in names for fs in stores for node in [fs.getNode(n)] if not node.empty()),
        None,
    )


def _fs_mat(stores: list, *names: str) -> np.ndarray | None:
    """The first of ``names`` that is a matrix (an opencv-matrix or a list of numbers), float64."""
    for n in names:
        node = _fs_scalar(stores, n)
        if node is not None and node.isMap():
            why = matrix_node_problem(node)
            # checked before OpenCV reads it: a bad header corrupts its heap (cols: -1)
            if why:
                raise ValueError(f"{n} is not a valid opencv-matrix: {why}")
            m = node.mat()
            if m is not None:
                return np.asarray(m, np.float64)
        if node is not None and node.isSeq():
            return np.asarray([node.at(i).real() for i in range(node.size())], np.float64)
    return None


def _cm_per_unit(path: Path, u, cm_per_unit: float | None) -> float:
    """Centimetres per unit of T: ``cm_per_unit`` if given (it must agree with the file's ``unit``
    entry ``u``), else from ``u``."""
    unit = u.string().strip().lower() if u is not None and u.isString() else None
    if (
        cm_per_unit is not None
        and unit in CM_PER_UNIT
        and abs(CM_PER_UNIT[unit] - float(cm_per_unit)) > 1e-9
    ):
        # (cm_per_unit won silently: 0.1 on a file in cm made an 8 cm baseline 0.8 cm)
        raise NodeError(
            f"{path} says its lengths are in {unit} (unit: {unit}), but cm_per_unit "
            f"{cm_per_unit:g} "
            f"was given ({CM_PER_UNIT[unit]:g} for {unit}).",
            hint="remove cm_per_unit: it is for files that do not state their unit, or "
            "are in board "
            "squares",
        )
    if cm_per_unit is not None:
        return cm_per_unit
    if unit == "squares":
        raise ValueError(
            "its lengths are in board squares (calibrated without a square size): the unit "
            "of T is one square; give cm_per_unit = the square's size in cm"
        )
    if unit not in CM_PER_UNIT:
        raise ValueError(
            "it does not say the unit of T "
            f"({'unit: ' + repr(unit) if unit else 'no unit entry'};"
            f" known: mm, cm, m, in)"
        )
    return CM_PER_UNIT[unit]


def _image_size(stores: list, image_size) -> tuple[bool, list]:
    """``(given by hand, [w, h])``: the file's own size wins (load.py refuses an image_size param
    that differs from it), else ``image_size``."""
    wn = _fs_scalar(stores, "image_width", "imageWidth")
    hn = _fs_scalar(stores, "image_height", "imageHeight")
    sz = _fs_mat(stores, "image_size", "imageSize")
    if wn is not None and hn is not None:
        return False, [_whole(wn.real(), "image_width"), _whole(hn.real(), "image_height")]
    if sz is not None and sz.size == 2:
        return False, [_whole(v, "image_size") for v in sz.ravel()]
    if image_size is None:
        raise ValueError("it does not give the image size (image_width / image_height)")
    return True, image_size


def _board_entries(scalar) -> dict | None:
    """The board a file of ours records (``board_cols``, ``board_rows``, ``board_square_cm``), or
    None."""
    got = {k: scalar(f"board_{k}") for k in ("cols", "rows", "square_cm")}
    if any(v is None or not (v.isReal() or v.isInt()) for v in got.values()):
        return None
    board = {k: float(v.real()) for k, v in got.items()}
    if not (board["cols"] >= 2 and board["rows"] >= 2 and math.isfinite(board["square_cm"])):
        return None
    return {"cols": int(board["cols"]), "rows": int(board["rows"]), "square_cm": board["square_cm"]}


# --------------------------------------------------------------------------- ROS camera_info
def _check_ros_lens_model(doc: dict, path: Path) -> None:
    """A camera_info's distortion model is OpenCV's standard one (ValueError otherwise: e.g.
    equidistant (fisheye), same YAML shape, other lens model)."""
    model = str(doc.get("distortion_model") or "plumb_bob").strip().lower()
    if model not in _ROS_OPENCV_MODELS:
        raise ValueError(
            f"{path} has distortion_model {doc.get('distortion_model')!r}, which is not OpenCV's "
            f"standard lens model ({' / '.join(_ROS_OPENCV_MODELS)}): its coefficients would "
            "be read with another meaning"
        )


def _ros_image_size(L: dict, Rd: dict, left_path: Path, right_path: Path) -> list[int]:
    """The pair's image size, ``[w, h]`` px: both files must give the same one."""
    size_l = [int(L.get("image_width", 0)), int(L.get("image_height", 0))]
    size_r = [int(Rd.get("image_width", 0)), int(Rd.get("image_height", 0))]
    if size_l != size_r or 0 in size_l:
        raise ValueError(
            f"the image sizes differ or are missing: {left_path} {size_l[0]}x{size_l[1]}, "
            f"{right_path} {size_r[0]}x{size_r[1]}"
        )
    return size_l


def _ros_mat(doc: dict, key: str, shape, path: Path) -> np.ndarray:
    v = doc.get(key)
    data = v.get("data") if isinstance(v, dict) else v
    try:
        a = np.asarray(data, float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.size == 0 or (shape is not None and a.size != int(np.prod(shape))):
        raise ValueError(
            f"{path} has no usable `{key}`" + (f" ({int(np.prod(shape))} numbers)" if shape else "")
        )
    return a.reshape(shape) if shape is not None else a.ravel()


def _whole(v: float, name: str) -> int:
    """An image side from a file: a whole number (ValueError naming the entry for inf, nan, 2.5)."""
    if not math.isfinite(v) or v != int(v):
        raise ValueError(f"{name} is {v!r}, not a whole number of pixels")
    return int(v)


def read_ros(path: Path) -> dict:
    """A ROS camera_info YAML as a dict (``ValueError`` naming the file if it is not one)."""
    try:  # with a pipeline file's bounds: a few hundred bytes of aliases must not ask for gigabytes
        doc = parse_yaml_data(path.read_text(), str(path), "calibrator.load")
    except NodeError as exc:
        raise ValueError(f"{path} is not a YAML file within bounds ({exc.message})") from exc
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path} is not a text file ({exc})") from exc
    if not isinstance(doc, dict) or "camera_matrix" not in doc:
        raise ValueError(f"{path} is not a ROS camera_info file (no camera_matrix)")
    return doc


#: ROS distortion models whose coefficients are OpenCV's (k1 k2 p1 p2 k3 [k4 k5 k6]).
_ROS_OPENCV_MODELS = ("plumb_bob", "rational_polynomial")

_ROS_UNIT_FLAG = re.compile(r"^# projection_matrix lengths are in (\w+)/100, not metres")


def _ros_flagged_unit(path: Path) -> str | None:
    """The unit a camera_info file of ours says its lengths are in when not metres (``squares``),
    else None."""
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            return None
        m = _ROS_UNIT_FLAG.match(line)
        if m:
            return m.group(1)
    return None


def read_ros_pair(left_path: Path, right_path: Path, cm_per_unit: float | None = None) -> dict:
    """A ``StereoCalibration`` from the left and right cameras' ROS camera_info files (metres ->
    cm).

    ``cm_per_unit``: centimetres per unit of the files' lengths (default 100: ROS's metres). A pair
    written from a calibration without a square size says so in a comment (lengths in squares/100):
    it is refused without ``cm_per_unit``, then the square's size in cm.
    """
    flagged = {u for u in (_ros_flagged_unit(left_path), _ros_flagged_unit(right_path)) if u}
    if flagged and cm_per_unit is None:
        raise ValueError(
            f"its lengths are in board {'/'.join(sorted(flagged))} (calibrated without a "
            "square size, "
            "as the files' first line says), not metres; give cm_per_unit = the square's size in cm"
        )
    scale_cm = (
        100.0 if cm_per_unit is None else (100.0 * cm_per_unit if flagged else float(cm_per_unit))
    )
    L, Rd = read_ros(left_path), read_ros(right_path)
    K1, K2 = (
        _ros_mat(L, "camera_matrix", (3, 3), left_path),
        _ros_mat(Rd, "camera_matrix", (3, 3), right_path),
    )
    for doc, p in ((L, left_path), (Rd, right_path)):
        _check_ros_lens_model(doc, p)
    D1 = _ros_mat(L, "distortion_coefficients", None, left_path)
    D2 = _ros_mat(Rd, "distortion_coefficients", None, right_path)
    R1, R2 = (
        _ros_mat(L, "rectification_matrix", (3, 3), left_path),
        _ros_mat(Rd, "rectification_matrix", (3, 3), right_path),
    )
    P1 = _ros_mat(L, "projection_matrix", (3, 4), left_path)
    P2 = _ros_mat(Rd, "projection_matrix", (3, 4), right_path)
    # ROS puts the stereo pair's origin at the left camera: its Tx is 0
    if P1[0, 3] != 0 or P1[1, 3] != 0:
        raise ValueError(
            f"{left_path}'s projection_matrix has a baseline (P[0,3] = {P1[0, 3]:g}): it "
            "is the right "
            "camera's file; `path` is the left camera's camera_info and `right_path` the "
            "right one's"
        )
    size_l = _ros_image_size(L, Rd, left_path, right_path)
    t_m = np.array([P2[0, 3] / P2[0, 0], P2[1, 3] / P2[1, 1], 0.0])
    if not np.any(t_m):
        raise ValueError(
            f"{right_path}'s projection_matrix has no baseline (P[0,3] = 0): is it the "
            "right camera's?"
        )
    R = R2.T @ R1
    T_cm = (R2.T @ t_m) * scale_cm
    return {
        "K1": K1,
        "D1": D1,
        "K2": K2,
        "D2": D2,
        "R": R,
        "T_cm": T_cm,
        "image_size": size_l,
        "rms_px": None,
        "per_view_rms_px": {},
        "rejected_views": [],
    }


# --------------------------------------------------------------------------- calibrator outputs
def _check_left_is_left(cal: dict) -> None:
    """Refuse a calibration whose right camera sits to the left of the left one (swapped images or
    cameras): its rectified baseline is negative and every depth from it would be wrong."""
    # right camera, left frame
    centre = -np.asarray(cal["R"], float).T @ np.asarray(cal["T_cm"], float).ravel()
    if centre[0] < 0 and abs(centre[0]) >= 0.5 * float(np.linalg.norm(centre)):
        unit = cal.get("length_unit", "cm")
        raise NodeError(
            f"the right camera's centre is at x = {centre[0]:+.3g} {unit} in the left "
            "camera's frame, to "
            "the LEFT of the left camera: the left and right images (or cameras) are swapped.",
            hint="swap left and right (left_glob / right_glob, the camera indices, the CSV's pixel "
            "columns or the files) and calibrate again: the left camera is the one on the left, "
            "seen from behind the cameras",
        )


def board_calibration_outputs(
    cal: dict, rejected: dict, board: dict, max_rms_px: float, label: str, ctx=None
) -> dict:
    """:func:`calibration_outputs` of a calibration from board views: refused when its overall
    reprojection RMS exceeds ``max_rms_px``; the views left out named, with why."""
    check_overall_rms(cal, max_rms_px, label)
    cal["rejected_views"] = sorted(rejected)
    cal["rejected_reasons"] = rejected
    if rejected and ctx is not None:
        ctx.warn(f"rejected {len(rejected)} view(s): " + ", ".join(sorted(rejected)))
    return calibration_outputs(cal, ctx, board)


def calibration_outputs(cal: dict, ctx=None, board: dict | None = None) -> dict:
    """What a calibrator returns: the calibration (with ``baseline_cm``, ``dy_mean_px``) and its
    exports.

    The one-line summary (RMS, baseline with its unit, mean |Δy|) goes first among the node's
    messages, so that the run's console table shows it. ``board`` (the views' board) tells the
    length unit: ``length_unit: squares`` when no square size was given (``T_cm`` is then in
    squares, and the exports say so).
    """
    if board is not None and board.get("length_unit"):
        cal["length_unit"] = str(board["length_unit"])
    _check_left_is_left(cal)
    if cal.get("length_unit", "cm") != "cm" and ctx is not None:
        ctx.warn(
            f"lengths are in {cal['length_unit']}, not cm (no square size given): give "
            "the board's square_cm "
            "to calibrate in real units; the ROS camera_info files cannot state this unit"
        )
    facts, line = calibration_summary(cal)
    cal.update(facts)
    if ctx is not None:
        ctx.messages.insert(0, line)
    return {"calibration": cal, **export_texts(cal)}
