"""IK solve rate and accuracy: analytic (scalar and vectorised batch) and damped least squares.

    .venv/bin/python benchmarks/bench_ik.py [--n 10000] [--seed 0]

Targets are the tool points of random joint poses drawn uniformly within the default arm's joint
limits (so every target is reachable). Prints, per solver, solves/s in this one process and the
worst |FK(IK(p)) - p| in cm.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nodes.contracts.arm import fk, limits_rad
from nodes.ik._solvers import OK, analytic_ik, analytic_ik_batch, numeric_ik, numeric_ik_batch
from nodes.ik.arm import ArmParams, build_arm_model


def timed(fn, repeat: int = 3):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="number of random reachable targets")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--n-scalar-numeric", type=int, default=500, help="targets for the (slow) scalar DLS timing"
    )
    a = ap.parse_args(argv)
    model = build_arm_model(ArmParams())
    lo, hi = limits_rad(model)
    P = fk(model, np.random.default_rng(a.seed).uniform(lo, hi, size=(a.n, 3)))
    rows = []

    dt, (q, st) = timed(lambda: analytic_ik_batch(model, P))
    err = np.linalg.norm(fk(model, q) - P, axis=1)
    rows.append(("analytic, vectorised batch", a.n / dt, (st == OK).mean(), err.max()))

    def scalar_all():
        return np.array([analytic_ik(model, p) for p in P])

    dt, q = timed(scalar_all, repeat=1)
    err = np.linalg.norm(fk(model, q) - P, axis=1)
    rows.append(("analytic, scalar (one call per target)", a.n / dt, 1.0, err.max()))

    dt, (q, st, err) = timed(lambda: numeric_ik_batch(model, P), repeat=1)
    err = np.linalg.norm(fk(model, q) - P, axis=1)
    rows.append(("numeric DLS, vectorised batch", a.n / dt, (st == OK).mean(), err[st == OK].max()))

    m = min(a.n_scalar_numeric, a.n)
    dt, q = timed(lambda: np.array([numeric_ik(model, p) for p in P[:m]]), repeat=1)
    err = np.linalg.norm(fk(model, q) - P[:m], axis=1)
    rows.append(("numeric DLS, scalar (one call per target)", m / dt, 1.0, err.max()))

    print(
        f"IK benchmark: {a.n} random reachable targets, arm '{model['name']}' (reach "
        f"{model['reach_cm']:.1f} cm), "
        f"one process"
    )
    print(f"{'solver':44s} {'solves/s':>12s} {'solved':>8s} {'max |FK(IK(p))-p| cm':>22s}")
    for name, rate, solved, err in rows:
        print(f"{name:44s} {rate:12,.0f} {100 * solved:7.2f}% {err:22.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
