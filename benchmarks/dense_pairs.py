"""disparity.dense's defaults scored on real stereo pairs with ground truth: fill and bad-2.0.

    .venv/bin/python benchmarks/dense_pairs.py [--set dense.PARAM=VALUE ...]

Pairs: Middlebury's Aloe (``../shared/data``, full size) and Motorcycle (the quarter-size Middlebury
2014 pair scikit-image ships as ``skimage.data.stereo_motorcycle``: ``pip install scikit-image``;
skipped, saying so, without it). Each is run through ``disparity.dense`` with the given overrides
(default: the node's defaults) and scored as ``report.disparity`` scores: fill = share of pixels
with known truth that got a disparity; bad-2.0 = share of those more than 2 px from the truth
(target: bad-2.0 <= 3.8 % at >= 72 % fill on every pair), and the same for the padded left strip
alone.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nodes.contracts.disparity_scores import bad_pixels  # noqa: E402

ALOE = ROOT.parent / "shared" / "data" / "middlebury-aloe-opencv"
# Middlebury 2014 Motorcycle, quarter size (741x500): f 3979.911 / 4 px, doffs 124.343 / 4 px, B 193
# mm
MOTO_RIG = (
    "{f_px: 995.0, cx_px: 370.5, cy_px: 249.5, cx_right_px: 401.6, baseline_cm: 19.3, "
    "image_size: [741, 500]}"
)
ALOE_RIG = (
    "{f_px: 3740.0, cx_px: 640.5, cy_px: 554.5, cx_right_px: 910.5, baseline_cm: 16.0, "
    "image_size: [1282, 1110]}"
)


def _pipeline(folder: Path, rig: str, range_cm: str) -> str:
    return f"""name: dense-pair
nodes:
  pairs: {{type: source.files, params: {{folder: '{folder}'}}}}
  rectify: {{type: rectifier.given, params: {rig}}}
  remap: {{type: rectifier.remap,
          inputs: {{rectification: rectify.rectification, pair: pairs.pairs}}}}
  dense: {{type: disparity.dense, params: {{working_range_cm: {range_cm}}},
          inputs: {{pair: remap.rectified, rectification: rectify.rectification}}}}
"""


def pairs(tmp: Path) -> list[tuple[str, Path, str, str, np.ndarray]]:
    out = []
    gt = cv2.imread(str(ALOE / "aloeGT.png"), cv2.IMREAD_GRAYSCALE)
    if gt is not None:
        out.append(
            (
                "Aloe (Middlebury 2006, full size)",
                ALOE,
                ALOE_RIG,
                "[120.0, 200.0]",
                gt.astype(np.float32),
            )
        )
    try:
        from skimage.data import stereo_motorcycle
    except ImportError:
        print("Motorcycle skipped: pip install scikit-image (it ships the pair)", file=sys.stderr)
        return out
    left, right, disp = stereo_motorcycle()
    folder = tmp / "motorcycle"
    folder.mkdir()
    cv2.imwrite(str(folder / "motorcycle_left.png"), cv2.cvtColor(left, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "motorcycle_right.png"), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
    gt = np.where(np.isfinite(disp), disp, 0).astype(np.float32)
    out.append(
        ("Motorcycle (Middlebury 2014, quarter size)", folder, MOTO_RIG, "[150.0, 700.0]", gt)
    )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", action="append", default=[], metavar="dense.PARAM=VALUE")
    a = ap.parse_args(argv)
    ok = True
    print(f"{'pair':<44} {'fill':>6} {'bad-2.0':>8} {'strip fill':>11} {'strip bad':>10}")
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        for name, folder, rig, range_cm, gt in pairs(tmp):
            pipe = tmp / f"{len(name)}.yaml"
            pipe.write_text(_pipeline(folder, rig, range_cm))
            out = tmp / f"out{len(name)}"
            cmd = [
                sys.executable,
                "-m",
                "stereograph",
                "run",
                str(pipe),
                "--no-cache",
                "--out",
                str(out),
            ]
            done = subprocess.run(
                cmd + [x for s in a.set for x in ("--set", s)],
                capture_output=True,
                text=True,
                cwd=ROOT,
            )
            if done.returncode:
                print(
                    f"{name}: the run failed:\n{done.stdout[-1500:]}{done.stderr[-1500:]}",
                    file=sys.stderr,
                )
                return 2
            rec = json.loads((out / "dense" / "disparity_map.json").read_text())[0]
            disp = np.load(out / "dense" / "disparity_map.npz")[rec["disparity_px"]["npz"]]
            fill, bad = bad_pixels(disp, gt, 2.0)
            w = int(rec["search_range_px"][1])  # the left strip the padding matches
            sfill, sbad = bad_pixels(disp[:, :w], gt[:, :w], 2.0)
            ok = ok and fill >= 0.72 and bad <= 0.038
            print(f"{name:<44} {fill:6.1%} {bad:8.2%} {sfill:11.1%} {sbad:10.2%}")
    print(f"target bad-2.0 <= 3.8 % at >= 72 % fill: {'met on every pair' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
