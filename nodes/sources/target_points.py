"""``source.target_points``: 3-D target points and their image points from CSV (input of
``calibrator.tsai``).

Two layouts (``#`` lines and blank lines are skipped; the first other line is the header):

* **one file, columns per camera** (``points:``)::

      id,x_cm,y_cm,z_cm,left_u_px,left_v_px,right_u_px,right_v_px
      p01,0.0,0.0,0.0,212.31,301.77,158.02,300.95

* **one file per camera** (``left:`` and ``right:``), each ``id,x_cm,y_cm,z_cm,u_px,v_px``.
  Rows are matched by ``id`` when both files have one (a point seen by one camera only is left
  out, with a warning), else by row order (then both files must list the same 3-D points).

The 3-D unit is the suffix of the coordinate columns (``x_mm``, ``x_cm``, ``x_m``, ``x_in``);
bare ``x, y, z`` columns are in ``length_unit``. Image points are pixels, origin at the centre
of the top-left pixel (docs/conventions.md), as measured in the *distorted* images. The ``id``
column is optional. Output: the ``CalibrationPoints`` artifact::

    {"world_cm": (N, 3), "left_px": (N, 2), "right_px": (N, 2), "image_size": [w, h],
     "ids": [str, ...], "files": [str, ...]}
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import model_validator

from stereograph.api import Field, NodeError, Out, Params, PathField, data_file, node

__all__ = ["TargetPointsParams", "read_target_csv", "target_points", "write_target_csv"]

UNIT_CM = {"mm": 0.1, "cm": 1.0, "m": 100.0, "in": 2.54}
MIN_POINTS = 7  # Tsai's non-coplanar linear step has seven unknowns (the coplanar one five)
_NODE = "source.target_points"


class TargetPointsParams(Params):
    points: str | None = PathField(
        None,
        description="One CSV with columns "
        "id,x_cm,y_cm,z_cm,left_u_px,left_v_px,right_u_px,right_v_px "
        "(path relative to the pipeline file). Or give `left` and `right`.",
    )
    left: str | None = PathField(
        None, description="Left camera's CSV: id,x_cm,y_cm,z_cm,u_px,v_px (relative path)."
    )
    right: str | None = PathField(
        None, description="Right camera's CSV, same columns as `left` (relative path)."
    )
    image_size_px: tuple[int, int] = Field(
        ..., description="Image width and height of both cameras (pixels), e.g. [640, 480]."
    )
    length_unit: Literal["mm", "cm", "m", "in"] = Field(
        "cm",
        description="Unit of bare x, y, z columns; columns named x_mm / x_cm / x_m / x_in state "
        "their own.",
    )

    @model_validator(mode="after")
    def _check(self):
        # Checked here, not at run time, so `stereograph validate` reports them (exit 2, file:line).
        if min(self.image_size_px) <= 0:
            raise ValueError(
                f"image_size_px {list(self.image_size_px)} must be a positive width and "
                "height, pixels"
            )
        if self.points and (self.left or self.right):
            raise ValueError(
                "give either `points` (one CSV, columns per camera) or `left` + `right`, not both"
            )
        if not self.points and not (self.left and self.right):
            side = "right" if self.left else "left" if self.right else None
            raise ValueError(
                f"no CSV for the {side} camera: give `left` and `right` together"
                if side
                else "no CSV given: set `points` (one file with left_/right_ columns) or "
                "`left` and `right`"
            )
        return self


MAX_POINTS = 100_000  # target points in one file: a target has tens to thousands


def _paths(params: TargetPointsParams, resolve) -> list[Path]:
    return [resolve(p) for p in (params.points, params.left, params.right) if p]


def _reads(params: TargetPointsParams, pipeline_dir: Path) -> list[Path]:
    def resolve(v):
        p = Path(v).expanduser()
        return p if p.is_absolute() else pipeline_dir / p

    return [p for p in _paths(params, resolve) if p.is_file()]


def _fail(path: Path, line: int | None, what: str, fix: str):
    where = f"{path}" + (f" line {line}" if line else "")
    raise NodeError(f"{_NODE}: {where}: {what}", hint=fix)


def read_target_csv(path: Path, cameras: tuple[str, ...], default_unit: str = "cm") -> dict:
    """Read one target CSV.

    Parameters
    ----------
    path : Path
        The file.
    cameras : tuple of str
        ``("left", "right")`` for a file with columns per camera (``left_u_px`` ...), ``("",)``
        for a one-camera file (``u_px, v_px``).
    default_unit : str
        Unit of bare ``x, y, z`` columns.

    Returns
    -------
    dict
        ``ids`` (list of str, None when the file has no id column), ``world_cm`` (N, 3), ``lines``
        (the file line of each row), and per camera ``<camera>_px`` (N, 2) (key ``px`` for ``""``).

    Raises
    ------
    NodeError
        Naming the file, the line and the fix, for every malformed input.
    """
    rows = _target_rows(path)
    head_line, head = rows[0]
    names, col, xyz, scale, want = _target_header(path, head_line, head, cameras, default_unit)
    has_id = "id" in col
    ids, world, pix, lines = [], [], {cam: [] for cam in cameras}, []
    for ln, raw in rows[1:]:
        vals = [v.strip() for v in _fields(raw)]
        if len(vals) != len(names):
            _fail(
                path,
                ln,
                f"{len(vals)} values but the header has {len(names)} columns.",
                "give one value per column (a decimal point, not a comma, inside numbers)",
            )

        def num(name, vals=vals, ln=ln):
            return _number(path, ln, name, vals[col[name]])

        world.append([num(n) * scale for n in xyz])
        for cam, cols in want.items():
            pix[cam].append([num(c) for c in cols])
        if has_id and not vals[col["id"]]:
            _fail(
                path,
                ln,
                "the id is empty.",
                "give every point an id, or drop the id column from the header",
            )
        ids.append(vals[col["id"]] if has_id else str(len(ids) + 1))
        lines.append(ln)
    if has_id:
        _check_unique_ids(path, ids, lines)
    out = {
        "ids": ids if has_id else None,
        "lines": lines,
        "world_cm": np.asarray(world, float).reshape(-1, 3),
    }
    for cam in cameras:
        out[f"{cam}_px" if cam else "px"] = np.asarray(pix[cam], float).reshape(-1, 2)
    return out


def _target_rows(path: Path) -> list[tuple[int, str]]:
    """``(line, text)`` of a target CSV's header and rows (no blank or comment line), checked."""
    if not path.exists():
        _fail(
            path,
            None,
            "file does not exist.",
            "fix the path (relative paths start at the pipeline file's folder)",
        )
    data_file(path, "a CSV of target points", _NODE)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        _fail(path, None, f"cannot be read as text ({exc}).", "save it as a UTF-8 CSV file")
    rows = [
        (i, ln)
        for i, ln in enumerate(text.splitlines(), 1)
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not rows:
        _fail(
            path,
            None,
            "has no header and no rows.",
            "see docs/rig.md, 'Tsai on your own target', for the format",
        )
    if len(rows) - 1 > MAX_POINTS:  # (a million points went on into Tsai's solver as they were)
        _fail(
            path,
            None,
            f"has {len(rows) - 1} points; a calibration target has at most {MAX_POINTS}.",
            "give the target's measured points (tens to thousands), not a dense point cloud",
        )
    return rows


def _target_header(
    path: Path, head_line: int, head: str, cameras: tuple[str, ...], default_unit: str
) -> tuple[list[str], dict[str, int], list[str], float, dict[str, list[str]]]:
    """``(column names, column index by name, the 3-D columns, cm per their unit, the pixel columns
    per camera)`` of a target CSV's header, checked."""
    if "," not in head and any(sep in head for sep in (";", "\t")):
        _fail(
            path,
            head_line,
            f"the header ({head.strip()}) is not separated by commas.",
            "save the file as comma-separated values (a spreadsheet's 'CSV (comma delimited)'), "
            "with a decimal point in numbers",
        )
    names = [c.strip().lower() for c in _fields(head)]
    col = {n: j for j, n in enumerate(names)}
    if len(col) != len(names):
        _fail(
            path,
            head_line,
            f"the header repeats a column name ({head.strip()}).",
            "name every column once",
        )
    unit = next((u for u in UNIT_CM if {f"x_{u}", f"y_{u}", f"z_{u}"} <= col.keys()), None)
    xyz = [f"{a}_{unit}" for a in "xyz"] if unit else ["x", "y", "z"]
    if not set(xyz) <= col.keys():
        _fail(
            path,
            head_line,
            f"the header ({head.strip()}) lacks the 3-D columns x_cm, y_cm, z_cm.",
            "name them x_cm,y_cm,z_cm (or _mm, _m, _in; bare x,y,z are in `length_unit`)",
        )
    scale = UNIT_CM[unit or default_unit]
    want = {cam: [f"{cam}_u_px", f"{cam}_v_px"] if cam else ["u_px", "v_px"] for cam in cameras}
    for cam, cols in want.items():
        missing = [c for c in cols if c not in col]
        if missing:
            who = f"the {cam} camera's columns" if cam else "the image columns"
            others = (
                ""
                if cam
                else " (a file with left_/right_ columns goes in `points:`, not `left:`/`right:`)"
            )
            _fail(
                path,
                head_line,
                f"{who} {', '.join(missing)} are missing (header: {head.strip()}){others}.",
                f"add {', '.join(cols)} (pixels in that camera's image)"
                + (", or give one CSV per camera with `left:` and `right:`" if cam else ""),
            )
    return names, col, xyz, scale, want


def _check_unique_ids(path: Path, ids: list[str], lines: list[int]) -> None:
    """Every point of a target CSV has its own id (NodeError naming the line of the second)."""
    seen: dict[str, int] = {}
    for i, ln in zip(ids, lines):
        if i in seen:
            _fail(
                path,
                ln,
                f"id {i!r} is used again (first on line {seen[i]}).",
                "give every point its own id",
            )
        seen[i] = ln


def _fields(line: str) -> list[str]:
    """One CSV line's fields (quotes allowed, as spreadsheets write them)."""
    return next(csv.reader([line]), [])


def _number(path: Path, line: int, column: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        _fail(
            path, line, f"column {column}: {text!r} is not a number.", "write plain decimal numbers"
        )
    if not math.isfinite(x):
        _fail(
            path,
            line,
            f"column {column} is {text!r}; every coordinate must be a finite number.",
            "delete the row of a point that a camera did not see (use one CSV per camera for "
            "points seen by one camera only)",
        )
    return x


def _check(path: Path, lines: list[int], px: np.ndarray, size, cam: str):
    w, h = size
    bad = np.flatnonzero(
        (px[:, 0] < -0.5) | (px[:, 1] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] > h - 0.5)
    )
    if bad.size:
        i = int(bad[0])
        _fail(
            path,
            lines[i],
            f"{cam} image point ({px[i, 0]:g}, {px[i, 1]:g}) px lies outside the {w}x{h} image "
            f"({bad.size} such row(s)).",
            "check image_size_px and that u (column) comes before v (row)",
        )


def _match(
    pl: Path, a: dict, pr: Path, b: dict, warn
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    if a["ids"] is not None and b["ids"] is not None:
        ib = {i: k for k, i in enumerate(b["ids"])}
        common = [(k, ib[i]) for k, i in enumerate(a["ids"]) if i in ib]
        only_l = [i for i in a["ids"] if i not in ib]
        only_r = sorted(set(b["ids"]) - set(a["ids"]))
        if only_l or only_r:
            warn(
                f"points seen by one camera only are left out: left only {only_l[:10]}, "
                f"right only {only_r[:10]}"
            )
        ka, kb = (np.array([c[j] for c in common], int) for j in (0, 1))
        ids = [a["ids"][k] for k in ka]
    else:
        if len(a["lines"]) != len(b["lines"]):
            _fail(
                pr,
                None,
                f"{len(b['lines'])} rows but {pl} has {len(a['lines'])}; without an id "
                "column rows are "
                "matched by order.",
                "add an id column to both files, or list the same points in the same order",
            )
        ka = kb = np.arange(len(a["lines"]))
        ids = a["ids"] or b["ids"] or [str(k + 1) for k in ka]
    Wa, Wb = a["world_cm"][ka], b["world_cm"][kb]
    # The same point written by two exports may differ in the last decimal: allow 10 micrometres.
    off = np.flatnonzero(
        np.linalg.norm(Wa - Wb, axis=1) > max(1e-3, 1e-6 * float(np.abs(Wa).max(initial=0)))
    )
    if off.size:
        k = int(off[0])
        _fail(
            pr,
            b["lines"][kb[k]],
            f"point {ids[k]!r} is at {Wb[k].tolist()} cm here but at {Wa[k].tolist()} cm in "
            f"{pl} line {a['lines'][ka[k]]}.",
            "both files must give the same 3-D coordinates for a point",
        )
    return Wa, a["px"][ka], b["px"][kb], ids


@node(
    _NODE,
    outputs={
        "points": Out(
            "CalibrationPoints", description="World points (cm) and their left/right pixels."
        )
    },
    params=TargetPointsParams,
    version="1",
    reads=_reads,
)
def target_points(params: TargetPointsParams, ctx=None) -> dict:
    """Read a calibration target's 3-D points and their left/right image points from CSV (for
    Tsai)."""
    resolve = ctx.path if ctx is not None else (lambda v: Path(v).expanduser())
    warn = ctx.warn if ctx is not None else (lambda m: None)
    size = [int(params.image_size_px[0]), int(params.image_size_px[1])]
    if params.points:
        path = resolve(params.points)
        d = read_target_csv(path, ("left", "right"), params.length_unit)
        _check(path, d["lines"], d["left_px"], size, "left")
        _check(path, d["lines"], d["right_px"], size, "right")
        W, L, R, ids, files = d["world_cm"], d["left_px"], d["right_px"], d["ids"], [str(path)]
        ids = ids or [str(k + 1) for k in range(len(W))]
        first = path
    else:  # left and right (TargetPointsParams refuses any other combination)
        pl, pr = resolve(params.left), resolve(params.right)
        a, b = (
            read_target_csv(pl, ("",), params.length_unit),
            read_target_csv(pr, ("",), params.length_unit),
        )
        _check(pl, a["lines"], a["px"], size, "left")
        _check(pr, b["lines"], b["px"], size, "right")
        W, L, R, ids = _match(pl, a, pr, b, warn)
        files, first = [str(pl), str(pr)], pl
    if len(W) < MIN_POINTS:
        raise NodeError(
            f"{_NODE}: {first} gives {len(W)} point(s) seen by both cameras; Tsai's "
            "method needs at least "
            f"{MIN_POINTS} (its linear step has seven unknowns).",
            hint="measure more target points: 30 or more spread over the whole image "
            "calibrate well",
        )
    return {
        "points": {
            "world_cm": W,
            "left_px": L,
            "right_px": R,
            "image_size": size,
            "ids": list(ids),
            "files": files,
        }
    }


def write_target_csv(
    path: Path,
    world_cm: np.ndarray,
    left_px: np.ndarray | None,
    right_px: np.ndarray | None,
    ids: list[str] | None = None,
    comment: str = "",
) -> None:
    """Write a target CSV in the format :func:`read_target_csv` reads (both cameras, or one when the
    other is None).

    World coordinates in cm, pixels with 4 decimals; used by the example generator and the tests.
    """
    W = np.asarray(world_cm, float)
    ids = ids or [f"p{k + 1:03d}" for k in range(len(W))]
    cams = [
        (n, np.asarray(p, float))
        for n, p in (("left", left_px), ("right", right_px))
        if p is not None
    ]
    pre = (lambda n: f"{n}_") if len(cams) == 2 else (lambda n: "")
    head = ["id", "x_cm", "y_cm", "z_cm"] + [f"{pre(n)}{a}_px" for n, _ in cams for a in "uv"]
    out = [f"# {c}" for c in comment.splitlines()] + [",".join(head)]
    for k, i in enumerate(ids):
        vals = [f"{v:.4f}" for v in W[k]] + [f"{v:.4f}" for _, p in cams for v in p[k]]
        out.append(",".join([str(i)] + vals))
    Path(path).write_text("\n".join(out) + "\n")
