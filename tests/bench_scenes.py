"""Synthetic bench helpers for the tests: a chessboard lying on the synthetic rig's table."""

from __future__ import annotations

import numpy as np

from nodes.sources import _render


def table_board(rig: dict, cols: int = 9, rows: int = 6, square_cm: float = 2.5, yaw_deg: float = 0.0,
                centre_table_cm=(0.0, 5.0), seed: int = 1):
    """Render a board lying flat on the table, turned ``yaw_deg`` about the vertical.

    Returns
    -------
    left, right : uint8 images
    T_frame_from_left : 4x4
        The table frame the board defines by the conventions' rule (origin at the inner corner
        nearest the cameras on the left, x right, y away, z up), exact -- for ``yaw_deg`` a
        multiple of 90 degrees, when the board's edges run along and across the view.
    """
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T_tb = np.eye(4)
    T_tb[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    ctr = np.array([(cols - 1) * square_cm / 2, (rows - 1) * square_cm / 2, 0.0])
    T_tb[:3, 3] = np.array([*centre_table_cm, 0.0]) - T_tb[:3, :3] @ ctr
    T_tl = np.asarray(rig["truth"]["T_table_from_left"], float)
    left, right, corners = _render.render_board_view(rig, np.linalg.inv(T_tl) @ T_tb, cols, rows, square_cm,
                                                     seed=seed)
    P = corners["board_cm"] @ T_tb[:3, :3].T + T_tb[:3, 3]
    origin = P[np.argmin(P[:, 0] + P[:, 1])]
    T = np.eye(4)
    T[:3, 3] = -origin
    return left, right, T @ T_tl
