"""Accuracy table for every segmenter x disparity estimator, plus shadow suppression on/off.

Renders the synthetic rig once (source.synthetic: n placements at 30-60 cm, seeded train/test
split), rectifies with the true or a chessboard calibration, and runs every combination of
segmenter.{edge_morph, color, otsu} x disparity.{centroid, ellipse, sgbm} -> locator.triangulate
-> report.accuracy's error_table on the TEST split (or all with --split all). Then the
strong-shadow comparison: scenes with a full, long shadow (shadow_strength 0.95, low light),
each segmenter with shadow suppression off and on.

Usage::

    .venv/bin/python benchmarks/locate_matrix.py                     # 120 placements, chessboard
                                                                     # calibration
    .venv/bin/python benchmarks/locate_matrix.py --calibration truth # isolate the locating error
    .venv/bin/python benchmarks/locate_matrix.py --n 60 --no-sgbm     # quicker
    .venv/bin/python benchmarks/locate_matrix.py --rectify on-demand  # segmenters given the camera
                                                                      # pairs

Prints Markdown tables (cm): mean / std / max|err| per axis, n_found / n.
"""

from __future__ import annotations

import argparse
import sys
import time
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nodes.calibrators.chessboard import ChessboardParams, chessboard  # noqa: E402
from nodes.calibrators.truth import truth_calibration  # noqa: E402
from nodes.disparity.centroid import CentroidParams, centroid  # noqa: E402
from nodes.disparity.ellipse import EllipseParams, ellipse  # noqa: E402
from nodes.disparity.sgbm import SgbmParams, sgbm  # noqa: E402
from nodes.locators.triangulate import TriangulateParams, triangulate  # noqa: E402
from nodes.rectifiers.opencv import rectify_calibration  # noqa: E402
from nodes.rectifiers.remap import RemapParams, remap  # noqa: E402
from nodes.reports.accuracy import error_table  # noqa: E402
from nodes.segmenters.color import ColorParams, color  # noqa: E402
from nodes.segmenters.edge_morph import EdgeMorphParams, edge_morph  # noqa: E402
from nodes.segmenters.hough import HoughParams, hough  # noqa: E402
from nodes.segmenters.otsu import OtsuParams, otsu  # noqa: E402
from nodes.segmenters.slic import SlicParams, slic  # noqa: E402
from nodes.segmenters.watershed import WatershedParams, watershed  # noqa: E402
from nodes.sources.synthetic import SyntheticParams, synthetic  # noqa: E402

OBJECT = {"radius_cm": 2.0, "color_bgr": [20, 120, 245]}
SEGMENTERS = {
    "edge_morph": (edge_morph, EdgeMorphParams),
    "color": (color, ColorParams),
    "otsu": (otsu, OtsuParams),
    "hough": (hough, HoughParams),
    "watershed": (watershed, WatershedParams),
    "slic": (slic, SlicParams),
}


def prepare(n: int, seed: int, calibration: str, **rig) -> tuple[list[dict], dict]:
    src = synthetic(
        SyntheticParams(
            n_scenes=n, n_views=16 if calibration == "chessboard" else 0, seed=seed, **rig
        )
    )
    if calibration == "chessboard":
        cal = chessboard(ChessboardParams(), views=src["views"])["calibration"]
    else:
        cal = truth_calibration(src["truth"])
    rect = rectify_calibration(cal)
    raw = list(src["pairs"].values())
    pairs = [remap(RemapParams(), rectification=rect, pair=p)["rectified"] for p in raw]
    return pairs, rect, raw


# What the engine tells a segmenter whose `pair` input is wired to a source's camera pairs.
ON_DEMAND = types.SimpleNamespace(
    input_types={"pair": "StereoPair"}, item=None, warn=lambda message: None
)


def locate_all(pairs, rect, seg_name, disp_name, shadow=True, raw=None, object_=None, **extra):
    """Locations of every pair; ``raw`` (the camera pairs): segment them with on-demand
    rectification; ``object_``: the segmenters' object model (default OBJECT)."""
    fn, P = SEGMENTERS[seg_name]
    params = P(
        object=OBJECT if object_ is None else object_,
        overlay=False,
        shadow={"enabled": shadow},
        **extra,
    )
    out = []
    for i, p in enumerate(pairs):
        if raw is None:
            seg = fn(params, pair=p, rectification=rect)["segmentation"]
        else:
            seg = fn(params, pair=raw[i], rectification=rect, ctx=ON_DEMAND)["segmentation"]
        if disp_name == "centroid":
            d = centroid(CentroidParams(), segmentation=seg, rectification=rect)["disparity"]
        elif disp_name == "ellipse":
            d = ellipse(EllipseParams(), segmentation=seg, rectification=rect)["disparity"]
        else:
            d = sgbm(SgbmParams(), segmentation=seg, pair=p, rectification=rect)["disparity"]
        out.append(
            triangulate(TriangulateParams(), disparity=d, rectification=rect, pair=p)["location"]
        )
    return out


def row(label, locs, split):
    sel = [v for v in locs if split == "all" or v.get("split") == split]
    ok = [v for v in sel if v["found"] and v["truth_cm"] is not None]
    m = np.array([[v["x_cm"], v["y_cm"], v["z_cm"]] for v in ok]).reshape(-1, 3)
    t = np.array([v["truth_cm"] for v in ok]).reshape(-1, 3)
    tab = error_table(m, t)
    cells = []
    for ax in "xyz":
        s = tab[ax]
        cells.append(
            "–"
            if s["mean_cm"] is None
            else f"{s['mean_cm']:+.3f} / {s['std_cm']:.3f} / {s['max_abs_cm']:.3f}"
        )
    return f"| {label} | {len(ok)}/{len(sel)} | " + " | ".join(cells) + " |"


HEADER = (
    "| combination | found / n | x mean / std / max | y mean / std / max | z mean / std / max |\n"
    "|---|---:|---:|---:|---:|"
)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=120, help="ball placements (count)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--calibration", choices=["chessboard", "truth"], default="chessboard")
    ap.add_argument("--split", choices=["test", "train", "all"], default="test")
    ap.add_argument("--no-sgbm", action="store_true", help="skip the (slow) dense estimator")
    ap.add_argument(
        "--shadow-n", type=int, default=40, help="strong-shadow placements (count; 0 = skip)"
    )
    ap.add_argument(
        "--rectify",
        choices=["remap", "on-demand"],
        default="remap",
        help="segment rectifier.remap's whole rectified images, or the camera pairs rectified "
        "on demand",
    )
    a = ap.parse_args(argv)

    t0 = time.time()
    pairs, rect, raw = prepare(a.n, a.seed, a.calibration)
    raw = raw if a.rectify == "on-demand" else None
    print(
        f"{len(pairs)} placements, {a.calibration} calibration, f = {rect['f_px']:.1f} px, "
        f"B = {rect['baseline_cm']:.2f} cm; errors = measured - true (cm), {a.split} split, "
        f"rectification: {a.rectify}\n"
    )
    print(HEADER)
    disps = ["centroid", "ellipse"] + ([] if a.no_sgbm else ["sgbm"])
    for s in SEGMENTERS:
        for d in disps:
            print(row(f"{s} + {d}", locate_all(pairs, rect, s, d, raw=raw), a.split), flush=True)
    if a.shadow_n:
        sp, srect, sraw = prepare(
            a.shadow_n, a.seed + 1, a.calibration, shadow_strength=0.95, light_cm=(40.0, 30.0, 45.0)
        )
        raw = sraw if a.rectify == "on-demand" else None
        print(
            f"\nStrong shadow ({len(sp)} placements, shadow_strength 0.95, low light; all items), "
            "centroid disparity:\n"
        )
        print(HEADER)
        for s in SEGMENTERS:
            print(
                row(
                    f"{s}, suppression off, no roundness check (thesis: largest region)",
                    locate_all(sp, srect, s, "centroid", shadow=False, raw=raw, min_roundness=0.0),
                    "all",
                ),
                flush=True,
            )
            for on in (False, True):
                print(
                    row(
                        f"{s}, shadow suppression {'on' if on else 'off'}",
                        locate_all(sp, srect, s, "centroid", shadow=on, raw=raw),
                        "all",
                    ),
                    flush=True,
                )
    print(f"\n({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
