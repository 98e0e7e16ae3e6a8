"""A calibration written as the files other tools read: OpenCV FileStorage YAML and ROS
``camera_info``.

Shared by the calibrators (the calibration at ``alpha`` 1) and ``rectifier.opencv`` (with the
rectification the run uses: its ``alpha``, recorded as ``rectify_alpha``). Lengths: cm in the OpenCV
file (its ``unit`` entry says so), metres in ROS's. The readers are in ``nodes.calibrators``.
Public: :data:`EXPORT_OUTPUTS`, :func:`export_texts`, :func:`opencv_text`, :func:`ros_camera_info`,
:func:`rectify_params`.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
import yaml

from nodes.contracts.cv_overloads import stop_signals_held

__all__ = [
    "EXPORT_OUTPUTS",
    "EXPORT_OUTPUTS_DOC",
    "export_texts",
    "opencv_text",
    "rectify_params",
    "ros_camera_info",
]


def rectify_params(cal: dict, alpha: float = 1.0) -> dict:
    """``stereoRectify``'s R1 R2 P1 P2 Q of a calibration (no maps), lengths in cm."""
    w, h = (int(v) for v in cal["image_size"])
    K1, D1, K2, D2, R = (np.asarray(cal[k], dtype=float) for k in ("K1", "D1", "K2", "D2", "R"))
    T = np.asarray(cal["T_cm"], dtype=float).reshape(3, 1)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        K1, D1, K2, D2, (w, h), R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha
    )
    return {"R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q, "alpha": float(alpha)}


def opencv_text(cal: dict, rect: dict | None = None) -> str:
    """The calibration as OpenCV FileStorage YAML (stereo_calib's names, lengths in cm), with the
    ``R1 R2 P1 P2 Q`` of ``rect`` (default: :func:`rectify_params` at alpha 1) and its
    ``rectify_alpha``."""
    rect = rect if rect is not None else rectify_params(cal)
    w, h = (int(v) for v in cal["image_size"])
    fd, tmp = tempfile.mkstemp(suffix=".yml")
    os.close(fd)
    try:
        # FileStorage's in-memory mode is not in every build's Python binding; a temporary file
        # is. Its write tries its overloads in turn (int, float, str, matrix): see cv_overloads.
        with stop_signals_held():
            fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
            fs.write("image_width", w)
            fs.write("image_height", h)
            fs.write("unit", str(cal.get("length_unit", "cm")))
            fs.write("method", str(cal.get("method", "")))
            if cal.get("rms_px") is not None:
                fs.write("rms_px", float(cal["rms_px"]))
            board = cal.get("board") or {}
            if all(isinstance(board.get(k), (int, float)) for k in ("cols", "rows", "square_cm")):
                # (read back by calibrator.load: the board survives)
                for k in ("cols", "rows", "square_cm"):
                    fs.write(f"board_{k}", board[k])
            for name, key in (("M1", "K1"), ("D1", "D1"), ("M2", "K2"), ("D2", "D2"), ("R", "R")):
                fs.write(
                    name,
                    np.asarray(cal[key], np.float64).reshape(3, 3)
                    if name[0] in "MR"
                    else np.asarray(cal[key], np.float64).reshape(1, -1),
                )
            fs.write("T", np.asarray(cal["T_cm"], np.float64).reshape(3, 1))
            for name in ("R1", "R2", "P1", "P2", "Q"):
                fs.write(name, np.asarray(rect[name], np.float64))
            fs.write(
                "rectify_alpha", float(rect.get("alpha", 1.0))
            )  # what R1..Q were computed with
            fs.release()
        return Path(tmp).read_text()
    finally:
        os.unlink(tmp)


def _distortion_model(D: np.ndarray) -> str:
    return "plumb_bob" if D.size <= 5 else "rational_polynomial"


def ros_camera_info(
    cal: dict, side: str, camera_name: str | None = None, rect: dict | None = None
) -> dict:
    """One camera's ROS ``camera_info`` (as a dict), lengths in metres.

    Parameters
    ----------
    cal : dict
        A ``StereoCalibration`` (lengths in cm).
    side : {"left", "right"}
    camera_name : str, optional
        Default ``"left"`` / ``"right"``.
    rect : dict, optional
        The rectification whose ``R`` and ``P`` to write (default: :func:`rectify_params` at alpha
        1).
    """
    rect = rect if rect is not None else rectify_params(cal)
    s = "1" if side == "left" else "2"
    K = np.asarray(cal["K" + s], float)
    D = np.asarray(cal["D" + s], float).ravel()
    if D.size < 5:
        D = np.concatenate([D, np.zeros(5 - D.size)])
    P = np.asarray(rect["P" + s], float).copy()
    P[:, 3] = P[:, 3] / 100.0  # cm -> m: ROS's Tx = -fx' B with B in metres
    w, h = (int(v) for v in cal["image_size"])

    def block(rows, cols, m):
        return {
            "rows": rows,
            "cols": cols,
            "data": [float(v) for v in np.asarray(m, float).ravel()],
        }

    return {
        "image_width": w,
        "image_height": h,
        "camera_name": camera_name or side,
        "camera_matrix": block(3, 3, K),
        "distortion_model": _distortion_model(D),
        "distortion_coefficients": block(1, D.size, D),
        "rectification_matrix": block(3, 3, rect["R" + s]),
        "projection_matrix": block(3, 4, P),
    }


#: The export outputs every calibrator declares beside ``calibration`` (``TextFile`` artifacts:
#: the engine writes each as ``<run>/<node>/<output><suffix>``).
EXPORT_OUTPUTS_DOC = {
    "opencv": "OpenCV FileStorage YAML (stereo_calib's M1 D1 M2 D2 R T R1 R2 P1 P2 Q; lengths in "
    "cm).",
    "camera_info_left": "ROS camera_info YAML of the left camera (metres).",
    "camera_info_right": "ROS camera_info YAML of the right camera (metres).",
}
_SUFFIX = {"opencv": ".yml", "camera_info_left": ".yaml", "camera_info_right": ".yaml"}


def _export_outputs():
    from stereograph.api import Out

    return {
        k: Out("TextFile", save=True, optional=True, description=d)
        for k, d in EXPORT_OUTPUTS_DOC.items()
    }


EXPORT_OUTPUTS = _export_outputs()


def export_texts(cal: dict, rect: dict | None = None) -> dict:
    """The three export outputs of a calibration, as ``TextFile`` values ``{"file_text",
    "file_suffix"}`` (with the rectification ``rect``, default :func:`rectify_params` at alpha
    1)."""
    unit = cal.get("length_unit", "cm")
    # ROS has no unit field: a calibration in squares is flagged in a comment, and by the run's
    # warning
    head = (
        ""
        if unit == "cm"
        else f"# projection_matrix lengths are in {unit}/100, not metres: no square size given\n"
    )
    texts = {
        "opencv": opencv_text(cal, rect),
        "camera_info_left": head
        + yaml.safe_dump(ros_camera_info(cal, "left", rect=rect), sort_keys=False),
        "camera_info_right": head
        + yaml.safe_dump(ros_camera_info(cal, "right", rect=rect), sort_keys=False),
    }
    return {k: {"file_text": t, "file_suffix": _SUFFIX[k]} for k, t in texts.items()}
