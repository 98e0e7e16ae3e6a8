"""Calibration board definitions shared by the renderer that draws a board and the calibrators that
detect it.

A ChArUco board is named by its inner-corner count ``cols x rows`` (the chessboard convention:
``cols + 1 x rows + 1`` squares), its square side (cm), the ArUco dictionary and the marker side
as a fraction of the square. ``source.synthetic`` renders it and ``calibrator.charuco`` detects it
with the same ``cv2.aruco.CharucoBoard``, so the corner ids and board coordinates agree.
"""

from __future__ import annotations

import cv2

__all__ = ["charuco_board"]


def charuco_board(
    cols: int,
    rows: int,
    square_cm: float,
    dictionary: str = "DICT_4X4_50",
    marker_fraction: float = 0.7,
):
    """``cv2.aruco.CharucoBoard`` with ``cols x rows`` inner corners (``cols+1 x rows+1`` squares).

    Raises ValueError for an unknown dictionary name or a board needing more
    markers than the dictionary holds.
    """
    code = getattr(cv2.aruco, str(dictionary), None)
    if not str(dictionary).startswith("DICT_") or not isinstance(code, int):
        names = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise ValueError(f"unknown ArUco dictionary {dictionary!r}; known: {', '.join(names)}")
    d = cv2.aruco.getPredefinedDictionary(code)
    n_markers = ((cols + 1) * (rows + 1)) // 2
    if n_markers > d.bytesList.shape[0]:
        raise ValueError(
            f"a {cols}x{rows} ChArUco board needs {n_markers} markers but {dictionary} holds "
            f"{d.bytesList.shape[0]}"
        )
    return cv2.aruco.CharucoBoard(
        (cols + 1, rows + 1), float(square_cm), float(marker_fraction * square_cm), d
    )
