"""Found rate and wrong answers per hard-scene kind, with the ball's colour given and unset (issue
15).

Renders ``source.synthetic``'s issue-15 kinds (``nodes/sources/_hard_scenes.py``: border_cut,
occluded_part, touching_box, touching_ball, distractor, same_color; ``--n`` scenes each) and,
with ``--old``, the issue-4 kinds (clutter, second_ball, border, occluded, hidden, empty),
calibrates with the chessboard views (or uses the true cameras), rectifies, and runs segmenter x
disparity -> locator.triangulate on every pair, with ``object.color_bgr`` given and unset.

Printed per kind: found / n, found among the balls with >= 50 % visible (the less visible view,
measured from the render's coverage), the number of found results more than 1 cm from the
truth (the worst outcome) and the largest error among the found, plus the most frequent reasons
for not found. ``same_color`` has no right location: found there counts as wrong when > 1 cm off.

Usage::

    .venv/bin/python benchmarks/locate_hard.py                 # 40 scenes per kind
    .venv/bin/python benchmarks/locate_hard.py --n 10 --old    # quicker, plus the issue-4 kinds
    .venv/bin/python benchmarks/locate_hard.py --segmenters edge_morph color --disparity ellipse
    .venv/bin/python benchmarks/locate_hard.py --learn         # also the colour learned from
                                                               # training truth
"""

from __future__ import annotations

import argparse
import collections
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.locate_matrix import SEGMENTERS, locate_all, prepare  # noqa: E402
from nodes.segmenters.appearance import AppearanceParams, learn_appearance  # noqa: E402
from nodes.sources._hard_scenes import HARD_KINDS  # noqa: E402

OLD_KINDS = ("clutter", "second_ball", "border", "occluded", "hidden", "empty")
COLOR = [20, 120, 245]  # the synthetic rig's orange ball


def table(locs: list[dict], raw: list[dict], kinds) -> list[str]:
    vis = {}
    for p in raw:
        t = p["truth"]
        vis[p["id"]] = (
            None if t is None else min(t["visible_fraction_left"], t["visible_fraction_right"])
        )
    rows = []
    for kind in kinds:
        sel = [v for v in locs if _kind(_pid(v)) == kind]
        found = [v for v in sel if v["found"]]
        vis50 = [v for v in sel if vis[_pid(v)] is not None and vis[_pid(v)] >= 0.5]
        f50 = [v for v in vis50 if v["found"]]
        errs = [
            float(np.linalg.norm(np.subtract([v["x_cm"], v["y_cm"], v["z_cm"]], v["truth_cm"])))
            if v["truth_cm"] is not None
            else float("inf")
            for v in found
        ]
        bad = sum(e > 1.0 for e in errs)
        reasons = collections.Counter(_short(v["reason"]) for v in sel if not v["found"])
        top = "; ".join(f"{n}x {r}" for r, n in reasons.most_common(2))
        worst = ", ".join(_pid(v) for v, e in zip(found, errs, strict=True) if e > 1.0)
        rows.append(
            f"| {kind} | {len(found)}/{len(sel)} | {len(f50)}/{len(vis50)} | {bad} | "
            f"{max(errs) if errs else float('nan'):.2f} | {top} |"
            + (f" > 1 cm: {worst}" if worst else "")
        )
    return rows


def _kind(pid: str) -> str:
    k = pid.rstrip("0123456789")
    return "plain" if k == "s" else k


def _pid(loc: dict) -> str:
    return str(loc.get("pair", loc.get("id")))


def _short(reason: str | None) -> str:
    r = (reason or "").split(" (")[0]
    return r[:70]


def _prepare(cache: Path | None, n: int, seed: int, calibration: str, **kw):
    if cache is not None and cache.exists():
        return pickle.loads(cache.read_bytes())
    out = prepare(n, seed, calibration, **kw)
    if cache is not None:
        cache.write_bytes(pickle.dumps(out))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=40, help="scenes per kind (count)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--old", action="store_true", help="also the issue-4 kinds (clutter, border, ...)"
    )
    ap.add_argument("--calibration", choices=["chessboard", "truth"], default="chessboard")
    ap.add_argument(
        "--segmenters", nargs="+", default=["edge_morph", "color"], choices=list(SEGMENTERS)
    )
    ap.add_argument(
        "--disparity", nargs="+", default=["centroid", "ellipse"], choices=["centroid", "ellipse"]
    )
    ap.add_argument(
        "--plain", type=int, default=0, help="also this many plain scenes (one ball, nothing else)"
    )
    ap.add_argument(
        "--learn",
        action="store_true",
        help="also the colour learned from the training placements' truth (segmenter.appearance)",
    )
    ap.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="pickle file: reuse the rendered, rectified pairs from there (written when absent)",
    )
    a = ap.parse_args(argv)
    kinds = list(HARD_KINDS) + (list(OLD_KINDS) if a.old else [])
    t0 = time.time()
    pairs, rect, raw = _prepare(
        a.cache, 0, a.seed, a.calibration, hard_cases=kinds, n_hard_each=a.n
    )
    if a.plain:
        # Same seed, so the same rig, views and calibration as the hard scenes.
        cache = None if a.cache is None else a.cache.with_suffix(f".plain{a.plain}.pkl")
        p2, _, r2 = _prepare(cache, a.plain, a.seed, a.calibration)
        pairs, raw, kinds = pairs + p2, raw + r2, kinds + ["plain"]
    print(
        f"{len(pairs)} hard pairs ({a.n} per kind), {a.calibration} calibration, f = "
        f"{rect['f_px']:.1f} px, "
        f"B = {rect['baseline_cm']:.2f} cm; rendered in {time.time() - t0:.0f} s\n"
    )
    modes = {
        "given": {"radius_cm": 2.0, "color_bgr": COLOR},
        "unset": {"radius_cm": 2.0, "color_bgr": None},
    }
    if a.learn:
        learned = learn_appearance({p["id"]: p for p in pairs}, rect, AppearanceParams(), raw=False)
        modes["learned"] = {
            "radius_cm": 2.0,
            "color_bgr": learned["color_bgr"],
            "color_tolerance": learned["color_tolerance"],
        }
        print(
            f"learned from {learned['n_pairs']} training placements: color_bgr "
            f"{learned['color_bgr']}, "
            f"tolerance {learned['color_tolerance']:.3f}; left out {len(learned['left_out'])}\n"
        )
    for seg in a.segmenters:
        for mode, obj in modes.items():
            if seg == "color" and mode == "unset":
                continue  # segmenter.color refuses to run without a colour (NodeError)
            for disp in a.disparity:
                locs = locate_all(pairs, rect, seg, disp, object_=obj)
                print(f"**{seg} + {disp}, colour {mode}**\n")
                print(
                    "| kind | found | found, >= 50 % visible | found > 1 cm off | max err cm "
                    "| main reasons (not found) |"
                )
                print("|---|---:|---:|---:|---:|---|")
                print("\n".join(table(locs, raw, kinds)) + "\n", flush=True)
    print(f"({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
