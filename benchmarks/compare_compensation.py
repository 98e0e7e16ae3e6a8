"""Compensation on the synthetic rig: the issue-5 figures.

Runs ``stereograph compare`` (pipelines/compare-compensation.yaml: none, polynomial,
disparity_curve, lookup, xyz) on

1. the nominal rig (calibrated from 16 chessboard views), and
2. a realistically imperfect rig: calibrated from only 4 views (``--set rig.n_views=4``)
   and/or with a 2 % baseline error injected (``--baseline-scale 1.02``, applied to the
   calibration's T by ``calibrator.perturb`` when that node is installed),

prints both full comparison tables, then the two checks of the issue:

* nominal: the best compensator brings the test split's |mean z error| to <= 0.05 cm with
  a z std no worse than compensator.none's;
* imperfect: the best compensator lowers z RMS by >= 50 % against compensator.none, with
  x and y RMS no worse (tolerance 0.005 cm, the noise of the RMS figures themselves).

Usage::

    .venv/bin/python benchmarks/compare_compensation.py [--n-scenes 120] [--out runs/bench-compensation]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console

from stereograph.compare import compare, print_table

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ROOT / "pipelines" / "compare-compensation.yaml"
TOL_CM = 0.005


def check_nominal(res, con) -> bool:
    none = res.row(**{"fit.type": "none"})
    ok_any = False
    for r in res.rows:
        if r["settings"]["fit.type"] == "none" or r.get("z_mean_cm") is None:
            continue
        ok = abs(r["z_mean_cm"]) <= 0.05 and r["z_std_cm"] <= none["z_std_cm"]
        ok_any |= ok
        con.print(f"  {r['settings']['fit.type']:<16} |z mean| {abs(r['z_mean_cm']):.3f} cm (<= 0.05), "
                  f"z std {r['z_std_cm']:.3f} vs none {none['z_std_cm']:.3f} cm -> {'PASS' if ok else 'fail'}")
    return ok_any


def check_imperfect(res, con) -> bool:
    none = res.row(**{"fit.type": "none"})
    ok_any = False
    for r in res.rows:
        if r["settings"]["fit.type"] == "none" or r.get("z_rms_cm") is None:
            continue
        drop = 1 - r["z_rms_cm"] / none["z_rms_cm"]
        xy = all(r[f"{a}_rms_cm"] <= none[f"{a}_rms_cm"] + TOL_CM for a in "xy")
        ok = drop >= 0.5 and xy
        ok_any |= ok
        con.print(f"  {r['settings']['fit.type']:<16} z RMS {none['z_rms_cm']:.3f} -> {r['z_rms_cm']:.3f} cm "
                  f"({100 * drop:+.0f} % lower; need >= 50 %), x RMS {r['x_rms_cm']:.3f} (none {none['x_rms_cm']:.3f}), "
                  f"y RMS {r['y_rms_cm']:.3f} (none {none['y_rms_cm']:.3f}) -> {'PASS' if ok else 'fail'}")
    return ok_any


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-scenes", type=int, default=120, help="synthetic placements (half train, half test)")
    ap.add_argument("--out", default=str(ROOT / "runs" / "bench-compensation"))
    ap.add_argument("--cache-dir", default=None, help="artifact cache (default: next to the pipeline)")
    ap.add_argument("--imperfect", action="append", default=None,
                    help="--set overrides making the imperfect rig (repeatable; default rig.n_views=4)")
    args = ap.parse_args(argv)
    con = Console(highlight=False, width=220)
    common = [f"rig.n_scenes={args.n_scenes}"]
    imperfect = args.imperfect or ["rig.n_views=4"]
    results = {}
    for name, sets in (("nominal", common), ("imperfect", common + imperfect)):
        con.rule(f"{name} rig: --set {' '.join(sets)}")
        res = compare(PIPELINE, [], Path(args.out) / name, overrides=sets, cache_dir=args.cache_dir)
        print_table(res, con)
        results[name] = res
        con.print(f"files: {res.out_dir}")
    con.rule("checks (test split)")
    con.print("nominal rig: best compensator |z mean| <= 0.05 cm with z std no worse than none")
    a = check_nominal(results["nominal"], con)
    con.print(f"imperfect rig ({' '.join(imperfect)}): z RMS -50 % vs none, x/y RMS no worse")
    b = check_imperfect(results["imperfect"], con)
    con.print(f"nominal: {'PASS' if a else 'FAIL'}; imperfect: {'PASS' if b else 'FAIL'}")
    return 0 if a and b else 1


if __name__ == "__main__":
    sys.exit(main())
