"""End-to-end pick accuracy on the synthetic rig: commanded gripper target vs the true ball centre.

    .venv/bin/python benchmarks/pick_accuracy.py [--seeds 0,1,2] [--hand-eye located|rig] [--ik
    analytic_3dof|numeric]

Runs ``pipelines/pick.yaml`` up to the ``pick`` node (plans only; the servos are not needed for the
number) for each rig seed and, for every TEST placement, compares the tool point of the grasp
waypoint's servo goals (forward kinematics of the whole-unit servo positions actually commanded)
with the ball's true centre in the arm-base frame (from the rig's ground truth and the arm base's
pose, independent of the fitted hand-eye). Prints the distribution and the share within 0.5 cm —
over the placements that got a plan and over all test placements (a missed or refused ball counts as
a miss).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", default="0,1,2", help="rig seeds (each: 120 placements, half of them test)"
    )
    ap.add_argument(
        "--hand-eye", default="located", choices=["located", "rig"], help="hand-eye mode"
    )
    ap.add_argument("--ik", default="analytic_3dof", choices=["analytic_3dof", "numeric"])
    ap.add_argument("--threshold-cm", type=float, default=0.5)
    a = ap.parse_args(argv)
    from nodes.ik._solvers import OK, analytic_ik_batch
    from stereograph.core.runner import run_pipeline

    def in_workspace(model, p) -> bool:
        """Can the arm reach the true centre and the approach / lift points above it?"""
        P = np.array(p, float) + np.array([[0, 0, 0], [0, 0, 6.0], [0, 0, 8.0]])
        return bool((analytic_ik_batch(model, P)[1] == OK).all())

    from nodes.ik.arm import ArmParams, build_arm_model
    from stereograph.core.config import load_pipeline

    doc = load_pipeline(ROOT / "pipelines" / "pick.yaml")
    model = build_arm_model(ArmParams(**(doc.nodes["arm"].get("params") or {})))
    errs, n_test, refused, he_rms, n_outside = [], 0, {}, [], 0
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in [int(s) for s in a.seeds.split(",")]:
            r = run_pipeline(
                ROOT / "pipelines" / "pick.yaml",
                overrides=[f"rig.seed={seed}", f"hand_eye.mode={a.hand_eye}", f"ik.type=ik.{a.ik}"],
                only="pick",
                out_dir=Path(tmp) / str(seed),
            )
            if r.status.get("pick") not in ("ran", "cached"):
                print(f"seed {seed}: pipeline stopped: {r.status}")
                return 1
            he = r.outputs("hand_eye", "hand_eye")
            if he.get("residual_cm"):
                he_rms.append(he["residual_cm"]["rms"])
            for item, plan in r.outputs("pick", "plan").items():
                if plan.get("split") != "test":
                    continue
                n_test += 1
                if plan.get("refused"):
                    refused[f"{seed}/{item}"] = plan["reason"]
                    if plan.get("truth_base_cm") is not None and not in_workspace(
                        model, plan["truth_base_cm"]
                    ):
                        n_outside += 1
                    continue
                errs.append(np.array(plan["grasp_fk_cm"]) - np.array(plan["truth_base_cm"]))
    E = np.array(errs)
    d = np.linalg.norm(E, axis=1)
    thr = a.threshold_cm
    print(
        f"pick accuracy: pipelines/pick.yaml, seeds {a.seeds}, hand-eye {a.hand_eye}, IK {a.ik} "
        f"({time.time() - t0:.0f} s)"
    )
    if he_rms:
        print(f"hand-eye fit RMS residual: {np.mean(he_rms):.3f} cm (mean over seeds)")
    print(f"test placements: {n_test}; planned: {len(d)}; refused / not found: {len(refused)}")
    print("distance |commanded grasp point - true ball centre| (cm):")
    q = np.percentile(d, [50, 90, 95, 99])
    print(
        f"  mean {d.mean():.3f}  median {q[0]:.3f}  p90 {q[1]:.3f}  p95 {q[2]:.3f}  p99 "
        f"{q[3]:.3f}  "
        f"max {d.max():.3f}"
    )
    for name, i in (("x", 0), ("y", 1), ("z", 2)):
        print(f"  {name} (arm base): mean {E[:, i].mean():+.3f}  std {E[:, i].std():.3f}")
    hist, edges = np.histogram(d, bins=[0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.75, 1.0, np.inf])
    for h, lo_, hi_ in zip(hist, edges[:-1], edges[1:]):
        print(f"  [{lo_:.2f}, {hi_:.2f}) cm  {h:4d}  {'#' * int(round(60 * h / max(1, len(d))))}")
    ok = int((d <= thr).sum())
    n_ws = n_test - n_outside
    print(
        f"within {thr} cm: {ok}/{len(d)} planned = {100 * ok / max(1, len(d)):.1f} %;  "
        f"{ok}/{n_ws} test placements inside the arm's workspace = "
        f"{100 * ok / max(1, n_ws):.1f} %;  "
        f"{ok}/{n_test} of all test placements = {100 * ok / max(1, n_test):.1f} %"
    )
    print(
        f"({n_outside} test balls lie where the arm cannot reach them or the approach "
        "point above them; the "
        f"others not picked were not found or flagged extrapolated)"
    )
    for k, why in list(refused.items())[:5]:
        print(f"  not picked {k}: {why[:140]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
