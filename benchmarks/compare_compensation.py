"""Compensation on the synthetic rig: the issue-5 figures.

Runs ``stereograph compare`` (pipelines/compare-compensation.yaml: none, polynomial,
disparity_curve, lookup, xyz) on

1. the nominal rig (calibrated from 16 chessboard views),
2. a rig calibrated from only 4 views (``--set rig.n_views=4``), and
3. a rig whose calibration carries a 2 % baseline error (``--set calib_error.baseline_scale=1.02``,
   injected by ``calibrator.perturb``),

prints the full comparison tables, then the checks of the issue:

* nominal: the best compensator brings the test split's |mean z error| to <= 0.05 cm with
  a z std no worse than compensator.none's;
* imperfect (each of 2 and 3): the best compensator lowers z RMS by >= 50 % against
  compensator.none, with x and y RMS no worse (tolerance 0.005 cm, the noise of the RMS figures
  themselves).

Usage::

    .venv/bin/python benchmarks/compare_compensation.py [--n-scenes 120] [--out
    runs/bench-compensation]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console

from stereograph.app.compare import compare
from stereograph.app.compare_table import print_table

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ROOT / "pipelines" / "compare-compensation.yaml"
TOL_CM = 0.005
RIGS = {
    "nominal": [],
    "views4": ["rig.n_views=4"],
    "baseline2": ["calib_error.baseline_scale=1.02"],
}


#: The columns printed (compare.csv has every metric the pipeline declares).
TABLE = [
    "n",
    "n_found",
    "[xyz]_mean_cm",
    "[xyz]_std_cm",
    "[xyz]_rms_cm",
    "n_extrapolated",
    "fit_time_s",
    "per_pair_s",
]


def check_nominal(res, con) -> bool:
    none = res.row(**{"fit.type": "none"})
    ok_any = False
    for r in res.rows:
        if r["settings"]["fit.type"] == "none" or r.get("z_mean_cm") is None:
            continue
        ok = abs(r["z_mean_cm"]) <= 0.05 and r["z_std_cm"] <= none["z_std_cm"]
        ok_any |= ok
        con.print(
            f"  {r['settings']['fit.type']:<16} |z mean| {abs(r['z_mean_cm']):.3f} cm (<= 0.05), "
            f"z std {r['z_std_cm']:.3f} vs none {none['z_std_cm']:.3f} cm -> "
            f"{'PASS' if ok else 'fail'}"
        )
    return ok_any


def check_imperfect(res, con) -> bool:
    none = res.row(**{"fit.type": "none"})
    ok_any = False
    for r in res.rows:
        if r["settings"]["fit.type"] == "none" or r.get("z_rms_cm") is None:
            continue
        change = r["z_rms_cm"] / none["z_rms_cm"] - 1
        xy = all(r[f"{a}_rms_cm"] <= none[f"{a}_rms_cm"] + TOL_CM for a in "xy")
        ok = change <= -0.5 and xy
        ok_any |= ok
        con.print(
            f"  {r['settings']['fit.type']:<16} z RMS {none['z_rms_cm']:.3f} -> "
            f"{r['z_rms_cm']:.3f} cm "
            f"({100 * change:+.0f} %; need <= -50 %), x RMS {r['x_rms_cm']:.3f} (none "
            f"{none['x_rms_cm']:.3f}), "
            f"y RMS {r['y_rms_cm']:.3f} (none {none['y_rms_cm']:.3f}) -> {'PASS' if ok else 'fail'}"
        )
    return ok_any


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--n-scenes", type=int, default=120, help="synthetic placements (half train, half test)"
    )
    ap.add_argument("--out", default=str(ROOT / "runs" / "bench-compensation"))
    ap.add_argument(
        "--cache-dir", default=None, help="artifact cache (default: next to the pipeline)"
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NODE.PARAM=VALUE",
        help="extra overrides for every rig (e.g. segment.type=segmenter.color)",
    )
    ap.add_argument(
        "--rig",
        action="append",
        default=None,
        choices=list(RIGS),
        help="which rigs to run (repeatable; default all)",
    )
    args = ap.parse_args(argv)
    con = Console(highlight=False, width=220)
    common = [f"rig.n_scenes={args.n_scenes}", *args.set]
    results = {}
    for name in args.rig or list(RIGS):
        sets = common + RIGS[name]
        con.rule(f"{name} rig: --set {' '.join(sets)}")
        res = compare(PIPELINE, [], Path(args.out) / name, overrides=sets, cache_dir=args.cache_dir)
        print_table(res, con, metrics=TABLE, best="z_rms_cm")
        results[name] = res
        con.print(f"files: {res.out_dir}")
    con.rule("checks (test split)")
    verdicts = {}
    for name, res in results.items():
        if name == "nominal":
            con.print(
                "nominal rig: best compensator |z mean| <= 0.05 cm with z std no worse than none"
            )
            verdicts[name] = check_nominal(res, con)
        else:
            con.print(f"{name} rig ({' '.join(RIGS[name])}): z RMS -50 % vs none, x/y RMS no worse")
            verdicts[name] = check_imperfect(res, con)
    con.print("; ".join(f"{k}: {'PASS' if v else 'FAIL'}" for k, v in verdicts.items()))
    return 0 if all(verdicts.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
