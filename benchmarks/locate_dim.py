"""A dim scene with an orange ball on the grey-brown table: found / error per edge_morph channel
(issue 15).

Renders plain scenes with low ambient light, darkens each image to 30 % (+ 1 gray level of noise: a
short exposure), rectifies with the true cameras and runs segmenter.edge_morph (colour given) ->
centroid -> triangulate with ``channel`` gray / auto, exposure normalisation off / on.

Usage::

    .venv/bin/python benchmarks/locate_dim.py            # 8 scenes
    .venv/bin/python benchmarks/locate_dim.py --n 20 --gain 0.2
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nodes.calibrators.truth import truth_calibration  # noqa: E402
from nodes.disparity.centroid import CentroidParams, centroid  # noqa: E402
from nodes.locators.triangulate import TriangulateParams, triangulate  # noqa: E402
from nodes.rectifiers.opencv import rectify_calibration  # noqa: E402
from nodes.rectifiers.remap import RemapParams, remap  # noqa: E402
from nodes.segmenters.edge_morph import EdgeMorphParams, edge_morph  # noqa: E402
from nodes.sources.synthetic import SyntheticParams, synthetic  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=8, help="scenes (count)")
    ap.add_argument(
        "--gain", type=float, default=0.3, help="exposure factor applied to the renders (ratio)"
    )
    a = ap.parse_args(argv)
    src = synthetic(
        SyntheticParams(n_scenes=a.n, n_views=0, seed=5, ball_color="orange", ambient=0.2)
    )
    rect = rectify_calibration(truth_calibration(src["truth"]))
    rng = np.random.default_rng(0)
    dim = []
    for p in src["pairs"].values():
        q = dict(p)
        for k in ("left", "right"):
            q[k] = np.clip(
                p[k].astype(np.float32) * a.gain + rng.normal(0, 1.0, p[k].shape), 0, 255
            ).astype(np.uint8)
        dim.append(remap(RemapParams(), rectification=rect, pair=q)["rectified"])
    print(f"{len(dim)} plain scenes at {a.gain:.0%} exposure; orange ball, colour given\n")
    print("| channel | normalize_exposure | found | max error cm |\n|---|---|---:|---:|")
    for ch in ("gray", "auto"):
        for norm in (False, True):
            P = EdgeMorphParams(
                object={"radius_cm": 2.0, "color_bgr": [20, 120, 245]},
                channel=ch,
                normalize_exposure=norm,
                overlay=False,
            )
            errs = []
            for r in dim:
                seg = edge_morph(P, pair=r, rectification=rect)["segmentation"]
                d = centroid(CentroidParams(), segmentation=seg, rectification=rect)["disparity"]
                loc = triangulate(TriangulateParams(), disparity=d, rectification=rect, pair=r)[
                    "location"
                ]
                if loc["found"]:
                    errs.append(
                        float(
                            np.linalg.norm(
                                np.subtract(
                                    [loc["x_cm"], loc["y_cm"], loc["z_cm"]], loc["truth_cm"]
                                )
                            )
                        )
                    )
            mx = f"{max(errs):.2f}" if errs else "-"
            print(f"| {ch} | {norm} | {len(errs)}/{len(dim)} | {mx} |", flush=True)


if __name__ == "__main__":
    main()
