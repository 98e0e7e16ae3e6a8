"""Write the example target files of docs/rig.md ("Tsai on your own target") from the synthetic rig.

    python pipelines/examples/make_tsai_example.py      # rewrites
    pipelines/examples/tsai-target/*.csv

The synthetic rig's two cameras are modelled as Tsai cameras (radial k1 only; kappa 0.15 left,
0.12 right, normalised units) and see, in the table frame (cm):

* ``points.csv`` — a coplanar target: a 5 cm grid of dots printed on a sheet lying on the table
  (z = 0); one file, columns per camera.
* ``left.csv`` / ``right.csv`` — a non-coplanar target: the same sheet lifted to z = 0, 5 and
  10 cm on spacers (Tsai's own set-up: a plane moved by known amounts); one file per camera,
  rows matched by id, a few points seen by one camera only.

Pixels carry 0.2 px Gaussian noise (seed 0), like careful dot-centre measurements. The true
cameras are written to ``truth.json`` so the example's result can be checked.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from nodes.sources._rig import make_rig
from nodes.sources._synthetic_target import target_points, tsai_cameras
from nodes.sources.target_points import write_target_csv

OUT = Path(__file__).resolve().parent / "tsai-target"


def main(out: Path = OUT, noise_px: float = 0.2, seed: int = 0) -> None:
    rig = make_rig()
    cams = tsai_cameras(rig)
    rng = np.random.default_rng(seed)
    out.mkdir(parents=True, exist_ok=True)
    W, L, R = target_points(rig, cams, "coplanar", spacing_cm=5.0)
    L, R = L + rng.normal(0, noise_px, L.shape), R + rng.normal(0, noise_px, R.shape)
    write_target_csv(
        out / "points.csv",
        W,
        L,
        R,
        comment="Coplanar target: 5 cm dot grid on the table (z = 0), "
        "table frame in cm; pixels of each dot centre in the left and right images (640x480).",
    )
    W, L, R = target_points(rig, cams, "non_coplanar", spacing_cm=5.0)
    L, R = L + rng.normal(0, noise_px, L.shape), R + rng.normal(0, noise_px, R.shape)
    ids = [f"z{int(round(w[2])):02d}_{k:03d}" for k, w in enumerate(W)]
    # A real camera misses a few points the other sees: drop some rows from each file.
    keep_l, keep_r = np.ones(len(W), bool), np.ones(len(W), bool)
    keep_l[[3, 40]] = False
    keep_r[[7]] = False
    note = (
        "Non-coplanar target: the dot sheet at z = 0, 5, 10 cm (table frame, cm); {} camera "
        "pixels (640x480)."
    )
    for name, keep, px in (("left", keep_l, L), ("right", keep_r, R)):
        write_target_csv(
            out / f"{name}.csv",
            W[keep],
            px[keep],
            None,
            [i for i, k in zip(ids, keep) if k],
            comment=note.format(name),
        )
    truth = {
        side: {
            "f_px": c["f"],
            "kappa": c["k1"] * c["f"] ** 2,
            "sx": c["sx"],
            "u0_px": c["u0"],
            "v0_px": c["v0"],
            "R": c["R"].tolist(),
            "t_cm": c["t_cm"].tolist(),
        }
        for side, c in zip(("left", "right"), cams)
    }
    truth["stereo"] = {
        "R": rig["truth"]["R"].tolist(),
        "T_cm": rig["truth"]["T_cm"].tolist(),
        "baseline_cm": float(np.linalg.norm(rig["truth"]["T_cm"])),
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")


if __name__ == "__main__":
    main()
