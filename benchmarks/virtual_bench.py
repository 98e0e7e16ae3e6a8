"""The bench procedure of docs/bench.md on a virtual bench, with the figures it reaches.

Writes the synthetic rig's bench as image files into a folder (default ``bench/`` at the
repository root) -- ``calib/`` (chessboard pairs), ``table/`` (the board lying on the table),
``balls/`` (ball placements) and ``truth.csv`` (the training placements' centres, measured in the
board's table frame, as a ruler on a real bench would) -- then runs the bench's steps exactly as
the documentation's commands do:

1. ``pipelines/calibrate.yaml`` on ``calib/``      -> calibration.json, opencv.yml,
   camera_info_*.yaml
2. ``pipelines/bench-table.yaml``                  -> table_frame.json
3. ``pipelines/bench-fit.yaml``                    -> model.json, hand_eye.json

and prints what the user cannot see on a real bench: the table frame's error against the board's
true pose, and the error of the *target* placements (not in truth.csv) before and after
compensation, in the left-camera and the table frame.

    python benchmarks/virtual_bench.py [--folder DIR] [--n-scenes 60] [--seed 0]
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nodes.sources._boards import render_table_board  # noqa: E402
from nodes.sources._rig import make_rig  # noqa: E402
from nodes.sources.synthetic import SyntheticParams, _rig_kwargs, synthetic  # noqa: E402
from stereograph.core.runner import run_pipeline  # noqa: E402


def _save(folder: Path, name: str, left, right) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / f"left_{name}.png"), left)
    cv2.imwrite(str(folder / f"right_{name}.png"), right)


def write_bench(folder: Path, n_scenes: int, n_views: int, seed: int) -> dict:
    """Write the virtual bench's files; return the hidden truth {pair: (split, centre_left_cm)} and
    frame."""
    params = SyntheticParams(
        n_scenes=n_scenes,
        n_views=n_views,
        seed=seed,
        train_fraction=0.5,
        placement_region_cm=[0, 0, 12, 23],
    )
    out = synthetic(params)
    for sub in ("calib", "table", "balls"):
        shutil.rmtree(folder / sub, ignore_errors=True)
    for v in out["views"]["views"]:
        _save(folder / "calib", v["id"], v["left"], v["right"])
    rig = make_rig(**_rig_kwargs(params))
    left, right, T_board = render_table_board(rig)
    _save(folder / "table", "table", left, right)
    hidden = {}
    with (folder / "truth.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "table_x_cm", "table_y_cm", "table_z_cm", "radius_cm"])
        for pid, p in out["pairs"].items():
            _save(folder / "balls", pid, p["left"], p["right"])
            c = np.asarray(p["truth"]["center_left_cm"], float)
            hidden[pid] = (p["split"], c)
            if p["split"] == "train":
                w.writerow(
                    [
                        pid,
                        *np.round(T_board[:3, :3] @ c + T_board[:3, 3], 4),
                        p["truth"]["radius_cm"],
                    ]
                )
    return {"hidden": hidden, "T_board_from_left": T_board}


def _rms(
    locs: dict, hidden: dict, T: np.ndarray | None = None, raw: bool = False
) -> tuple[float, int]:
    """3-D RMS error (cm) of the found, not extrapolated target placements; in the frame ``T`` maps
    the left-camera frame to (the measured table frame for the locations, the true one for the
    truth)."""
    errs = []
    for pid, loc in locs.items():
        if hidden[pid][0] != "test" or not loc.get("found") or loc.get("extrapolated"):
            continue
        xyz = np.array(
            [loc["raw_x_cm"], loc["raw_y_cm"], loc["raw_z_cm"]]
            if raw
            else [loc["x_cm"], loc["y_cm"], loc["z_cm"]],
            float,
        )
        c = hidden[pid][1]
        if T is not None:
            xyz, c = T[0][:3, :3] @ xyz + T[0][:3, 3], T[1][:3, :3] @ c + T[1][:3, 3]
        errs.append(xyz - c)
    e = np.array(errs).reshape(-1, 3)
    return (float(np.sqrt((e**2).sum(1).mean())) if len(e) else float("nan")), len(e)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--folder", default=str(ROOT / "bench"), help="where the bench's files go (default bench/)"
    )
    ap.add_argument(
        "--n-scenes", type=int, default=60, help="ball placements (about half are training)"
    )
    ap.add_argument("--n-views", type=int, default=12, help="chessboard calibration pairs")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    folder = Path(a.folder).resolve()
    bench = write_bench(folder, a.n_scenes, a.n_views, a.seed)
    pl = ROOT / "pipelines"
    steps = [
        (
            "calibrate",
            pl / "calibrate.yaml",
            ["rig.type=source.calib_files", f"rig.folder={folder / 'calib'}", "rig.square_cm=2.5"],
        ),
        (
            "table",
            pl / "bench-table.yaml",
            [
                f"calibration.path={folder}/runs/calibrate/calib/calibration.json",
                f"board.folder={folder / 'table'}",
            ],
        ),
        (
            "fit",
            pl / "bench-fit.yaml",
            [
                f"calibration.path={folder}/runs/calibrate/calib/calibration.json",
                f"table.path={folder}/runs/table/table/table_frame.json",
                f"balls.folder={folder / 'balls'}",
                f"balls.truth={folder / 'truth.csv'}",
            ],
        ),
    ]
    results = {}
    for name, pipe, sets in steps:
        print(
            f"$ stereograph run {pipe.relative_to(ROOT)} "
            + " ".join(f"--set {s}" for s in sets)
            + f" --out {folder}/runs/{name}"
        )
        r = run_pipeline(
            pipe,
            sets,
            out_dir=folder / "runs" / name,
            cache_dir=folder / ".cache",
            keep={"compensate", "calib"} if name != "table" else None,
        )
        if not r.ok:
            bad = {n: r.reports[n].error for n in r.status if r.reports[n].error}
            print(f"step {name} failed: {bad}")
            return 1
        results[name] = r
    cal = results["calibrate"].outputs("calib", "calibration")
    print(
        f"\ncalibration: RMS {cal['rms_px']:.4f} px, baseline {cal['baseline_cm']:.4f} cm, "
        f"mean |dy| {cal['dy_mean_px']:.3f} px"
    )
    tf = results["table"].outputs("table", "table_frame")
    T, Tt = np.asarray(tf["T_table_from_left"]), bench["T_board_from_left"]
    rot = float(np.degrees(np.linalg.norm(cv2.Rodrigues(T[:3, :3] @ Tt[:3, :3].T)[0])))
    print(
        f"table frame vs the board's true pose: {np.abs(T[:3, 3] - Tt[:3, 3]).max():.4f} "
        f"cm, {rot:.4f} deg "
        f"(left vs right view: {tf['disagreement']['translation_cm']:.4f} cm, "
        f"{tf['disagreement']['rotation_deg']:.4f} deg)"
    )
    locs = results["fit"].outputs("compensate", "location")
    hid = bench["hidden"]
    print("target placements (not in truth.csv), 3-D RMS error, found and not extrapolated:")
    for label, kw in (
        ("left-camera frame, raw", {"raw": True}),
        ("left-camera frame, compensated", {}),
        ("table frame (as measured), compensated", {"T": (T, Tt)}),
    ):
        rms, n = _rms(locs, hid, **kw)
        print(f"  {label:40s} {rms:.4f} cm  (n={n})")
    print(
        f"\nfiles: {folder}/runs/calibrate/calib/"
        "{calibration.json,opencv.yml,camera_info_*.yaml}, "
        f"{folder}/runs/table/table/table_frame.json, {folder}/runs/fit/fit/model.json, "
        f"{folder}/runs/fit/hand_eye/hand_eye.json"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
