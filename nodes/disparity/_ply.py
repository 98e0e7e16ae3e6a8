"""Point clouds as PLY files (binary little-endian; x, y, z float32 in cm, red, green, blue uint8).

PLY is what point-cloud viewers (MeshLab, CloudCompare, Open3D, PCL's ``pcl_ply2pcd``) open
directly. The file has no unit or frame field, so both are stated in ``comment`` lines.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PLY_DTYPE", "encode_ply", "decode_ply"]

PLY_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
)


def encode_ply(points_cm: np.ndarray, rgb: np.ndarray, comments: list[str] = ()) -> bytes:
    """A binary PLY file of coloured points.

    Parameters
    ----------
    points_cm : ndarray (N, 3)
        Point coordinates, cm.
    rgb : ndarray (N, 3) uint8
        Point colours, red-green-blue order.
    comments : list of str
        One ``comment`` line each (units, frame, source); no newlines.
    """
    n = len(points_cm)
    rec = np.empty(n, dtype=PLY_DTYPE)
    for k, name in enumerate("xyz"):
        rec[name] = points_cm[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        rec[name] = rgb[:, k]
    lines = [
        "ply",
        "format binary_little_endian 1.0",
        *(f"comment {c}" for c in comments),
        f"element vertex {n}",
        "property float x",
        "property float y",
        "property float z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
        "end_header",
    ]
    return ("\n".join(lines) + "\n").encode("ascii") + rec.tobytes()


def decode_ply(data: bytes) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read back a file written by :func:`encode_ply`: points (N, 3) cm, colours (N, 3) uint8,
    comments."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    if header[:2] != ["ply", "format binary_little_endian 1.0"]:
        raise ValueError("not a binary little-endian PLY file")
    n = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    rec = np.frombuffer(data, dtype=PLY_DTYPE, count=n, offset=end)
    pts = np.column_stack([rec["x"], rec["y"], rec["z"]])
    rgb = np.column_stack([rec["red"], rec["green"], rec["blue"]])
    return pts, rgb, [line[8:] for line in header if line.startswith("comment ")]
