"""Print the camera-rig figures: renderer speed and self-consistency, chessboard and Tsai recovery,
real data.

    .venv/bin/python benchmarks/bench_calibration.py [--scenes 30] [--views 16]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from nodes.calibrators._board import board_points, detect_views
from nodes.calibrators.chessboard import ChessboardParams, chessboard
from nodes.calibrators.tsai import tsai_k1_of_opencv, tsai_project, tsai_stereo
from nodes.rectifiers.opencv import RectifyParams, opencv
from nodes.sources._boards import board_corners_3d, random_board_poses, render_board_view
from nodes.sources._lens import project_points
from nodes.sources._render import render_scene
from nodes.sources._rig import make_rig
from nodes.sources._scenes import make_scene
from nodes.sources.calib_files import CalibFilesParams, calib_files
from nodes.sources.synthetic import SyntheticParams, synthetic

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "opencv-stereo-chessboard"


def rot_deg(Ra, Rb):
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(Ra @ Rb.T)[0])))


def renderer(n):
    rig = make_rig()
    render_scene(rig, make_scene(rig, "plain", 0))  # warm the caches (ray grids, texture)
    scenes = [make_scene(rig, "plain", np.random.default_rng([1, i])) for i in range(n)]
    worst_c, worst_x, gaps = 0.0, 0.0, []
    tr = rig["truth"]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    P1, P2 = (
        np.hstack([np.eye(3), np.zeros((3, 1))]),
        np.hstack([tr["R"], tr["T_cm"].reshape(3, 1)]),
    )
    times = []
    for i, sc in enumerate(scenes):
        t0 = time.perf_counter()
        _, _, truth = render_scene(rig, sc, seed=i, coverage=True)
        times.append(time.perf_counter() - t0)
        for side in ("left", "right"):
            cov = truth[f"coverage_{side}"].astype(float)
            v, u = np.mgrid[: cov.shape[0], : cov.shape[1]]
            c = np.array([(cov * u).sum(), (cov * v).sum()]) / cov.sum()
            sil = truth[f"silhouette_{side}"]
            worst_c = max(worst_c, float(np.hypot(*(c - sil["centroid_px"]))))
            gaps.append(float(np.hypot(*np.subtract(sil["centroid_px"], sil["center_px"]))))
        nl = cv2.undistortPoints(
            np.array([[truth["center_px_left"]]]), tr["K1"], tr["D1"], criteria=crit
        ).reshape(2, 1)
        nr = cv2.undistortPoints(
            np.array([[truth["center_px_right"]]]), tr["K2"], tr["D2"], criteria=crit
        ).reshape(2, 1)
        X = cv2.triangulatePoints(P1, P2, nl, nr)
        worst_x = max(
            worst_x, float(np.linalg.norm((X[:3] / X[3]).ravel() - truth["center_left_cm"]))
        )
    poses = random_board_poses(rig, 5, 0)
    t0 = time.perf_counter()
    for p in poses:
        render_board_view(rig, p)
    tb = (time.perf_counter() - t0) / len(poses)
    print("## Synthetic renderer (640x480)")
    print(
        f"- ball pair: median {1000 * np.median(times):.0f} ms, max {1000 * max(times):.0f} ms "
        f"(incl. coverage); chessboard pair: {1000 * tb:.0f} ms"
    )
    print(
        f"- {n} placements x 2 cameras: max |rendered centroid - exact silhouette "
        f"centroid| = {worst_c:.4f} px "
        f"(target 0.05)"
    )
    print(
        f"- silhouette centroid vs image of the centre: median {np.median(gaps):.2f} px, "
        f"max {max(gaps):.2f} px"
    )
    print(f"- triangulating the true projected centres: max error {worst_x:.2e} cm (target 1e-4)\n")


def chessboard_synthetic(n_views):
    out = synthetic(SyntheticParams(n_scenes=0, n_views=n_views, seed=0))
    tr = out["truth"]
    print(f"## calibrator.chessboard on the synthetic rig ({n_views} views, noise 2 grey levels)")
    print(
        "| refine | RMS px | fx1 % | fy1 % | fx2 % | fy2 % | baseline % | rotation deg | "
        "rectified mean/max dy px |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for refine in ("joint", "fix_intrinsic"):
        cal = chessboard(ChessboardParams(refine=refine), views=out["views"])["calibration"]
        rect = opencv(RectifyParams(), calibration=cal)["rectification"]
        e = [100 * (cal[k][i, i] / tr[k][i, i] - 1) for k in ("K1", "K2") for i in (0, 1)]
        b = 100 * (np.linalg.norm(cal["T_cm"]) / np.linalg.norm(tr["T_cm"]) - 1)
        print(
            f"| {refine} | {cal['rms_px']:.3f} | "
            + " | ".join(f"{x:+.3f}" for x in e)
            + f" | {b:+.3f} | {rot_deg(cal['R'], tr['R']):.3f} | {rect['dy_mean_px']:.3f} / "
            f"{rect['dy_max_px']:.3f} |"
        )
    print("targets: fx, fy, baseline within 0.5 %, rotation within 0.1 deg\n")


def _target(rig, n=6):
    poses = random_board_poses(rig, n, 0)
    obj = board_corners_3d(9, 6, 2.5)
    T = rig["truth"]["T_table_from_left"]
    W, L, Rr = [], [], []
    for p in poses:
        pw = T @ p
        W.append(obj @ pw[:3, :3].T + pw[:3, 3])
        pl = obj @ p[:3, :3].T + p[:3, 3]
        L.append(project_points(rig["truth"]["K1"], rig["truth"]["D1"], pl))
        t = rig["truth"]
        Rr.append(project_points(t["K2"], t["D2"], pl @ t["R"].T + t["T_cm"]))
    return np.concatenate(W), np.concatenate(L), np.concatenate(Rr)


def tsai_table():
    print(
        "## calibrator.tsai (6 board poses in one world frame = a multi-plane target, "
        "324 points per camera)"
    )
    print(
        "k1 is Tsai's (distorted->undistorted, normalised units); 'true' = Tsai's own "
        "value for the Tsai-model "
        "camera, else the Tsai k1 that best fits the OpenCV camera's radial curve."
    )
    print(
        "| camera | principal point | noise px | f err % | k1 est / true | k1 err % | "
        "baseline % | rotation deg "
        "| RMS px |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    cases = [
        ("Tsai model (k1=+0.15)", None),
        (
            "OpenCV k1 only",
            dict(distortion_left=(-0.12, 0, 0, 0), distortion_right=(-0.10, 0, 0, 0)),
        ),
        ("default rig k1 k2 p1 p2", {}),
    ]
    for name, kw in cases:
        rig = make_rig(**(kw or {}))
        tr = rig["truth"]
        W, L, Rr = _target(rig)
        if kw is None:  # re-project with Tsai's own model (kappa = 0.15 in normalised units)
            T = tr["T_table_from_left"]
            Rw = T[:3, :3].T
            cams = []
            cams = (
                (tr["K1"], Rw, -Rw @ T[:3, 3]),
                (tr["K2"], tr["R"] @ Rw, tr["R"] @ (-Rw @ T[:3, 3]) + tr["T_cm"]),
            )
            for K, Rx, tx in cams:
                cams.append(
                    {
                        "f": K[1, 1],
                        "k1": 0.15 / K[1, 1] ** 2,
                        "sx": K[0, 0] / K[1, 1],
                        "R": Rx,
                        "t_cm": tx,
                        "u0": K[0, 2],
                        "v0": K[1, 2],
                        "dx": 1.0,
                        "dy": 1.0,
                        "ncx_over_nfx": 1.0,
                    }
                )
            L, Rr = tsai_project(cams[0], W), tsai_project(cams[1], W)
            k_true = 0.15
        else:
            r_max = np.hypot(320 / tr["K1"][0, 0], 240 / tr["K1"][1, 1])
            k_true = tsai_k1_of_opencv(tr["D1"], r_max)
        for pp in ("known", "centre"):
            for noise in (0.0, 0.2):
                rng = np.random.default_rng(1)
                Ln, Rn = L + rng.normal(0, noise, L.shape), Rr + rng.normal(0, noise, Rr.shape)
                ppl = tuple(tr["K1"][:2, 2]) if pp == "known" else None
                ppr = tuple(tr["K2"][:2, 2]) if pp == "known" else None
                cal = tsai_stereo(W, Ln, Rn, (640, 480), ppl, ppr)
                c = cal["tsai_left"]
                kn = c["k1"] * c["f"] ** 2
                print(
                    f"| {name} | {pp} | {noise} | "
                    f"{100 * (c['f'] / tr['K1'][1, 1] - 1):+.3f} | {kn:+.4f} / "
                    f"{k_true:+.4f} | {100 * (kn / k_true - 1):+.1f} | "
                    f"{100 * (np.linalg.norm(cal['T_cm']) / np.linalg.norm(tr['T_cm']) - 1):+.3f}"
                    " | "
                    f"{rot_deg(cal['R'], tr['R']):.3f} | {cal['rms_px']:.3f} |"
                )
    print("targets: f within 1 %, k1 sign and magnitude within 10 % on noise-free points\n")


def real_data():
    if not DATA.is_dir():
        print("## real data: ../shared/data not present, skipped")
        return
    views = calib_files(CalibFilesParams(folder=str(DATA)))["views"]
    ids, L, Rr, rej = detect_views(views["views"], 9, 6)
    obj = [board_points(9, 6, 1.0)] * len(ids)
    _, K1, D1, _, _ = cv2.calibrateCamera(obj, L, (640, 480), None, None)
    _, K2, D2, _, _ = cv2.calibrateCamera(obj, Rr, (640, 480), None, None)
    ref = cv2.stereoCalibrate(obj, L, Rr, K1, D1, K2, D2, (640, 480))[0]
    print(
        f"## Real data: OpenCV's left/right01-14 ({len(ids)} pairs, board 9x6, lengths in squares)"
    )
    print(
        "- plain OpenCV (calibrateCamera x2 + stereoCalibrate defaults) on the same "
        f"detections: RMS {ref:.4f} px"
    )
    for refine in ("joint", "fix_intrinsic"):
        cal = chessboard(ChessboardParams(refine=refine), views=views)["calibration"]
        line = (
            f"- calibrator.chessboard refine={refine}: RMS {cal['rms_px']:.4f} px "
            f"({100 * (cal['rms_px'] / ref - 1):+.1f} %)"
        )
        for alpha in (1.0, 0.0):
            r = opencv(RectifyParams(alpha=alpha), calibration=cal)["rectification"]
            line += (
                f"; alpha={alpha:g}: rectified |dy| mean {r['dy_mean_px']:.3f} / max "
                f"{r['dy_max_px']:.3f} px, "
                f"f {r['f_px']:.0f} px"
            )
        print(line + f", baseline {np.linalg.norm(cal['T_cm']):.3f} squares")
    print("targets: RMS within 5 % of plain OpenCV, rectified mean |dy| <= 0.5 px")


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--views", type=int, default=16)
    a = ap.parse_args()
    renderer(a.scenes)
    chessboard_synthetic(a.views)
    tsai_table()
    real_data()


if __name__ == "__main__":
    main()
