"""Clear many random tables with pipelines/clear-table.yaml and say how it went.

    python benchmarks/clear_table.py --n 50            # 50 tables of 2-6 balls, 2-3 colours, some
    touching python benchmarks/clear_table.py --n 5 --seed 100  # a quick look

Each table is one `stereograph run` of the pipeline (its own run folder under --out) with
source.sim_bench's seed, ball count and the declared objects set on the command line. Read back:
the world file (where every ball ended: the truth), the planner's status per cycle, the servo
log. Printed: tables fully cleared, balls placed in the wrong place, goals the servos refused
(outside their limits), gripper paths through another ball (a push in the simulated world),
retries, seconds per ball placed, and grab -> first goal latency per cycle (median, p95).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PALETTE = [
    ("orange", [20, 120, 245], [-15.0, -6.0, 3.0]),
    ("blue", [200, 90, 30], [15.0, -6.0, 3.0]),
    ("green", [60, 170, 50], [0.0, -15.0, 3.0]),
]
GOAL_POSITION = 30


def table_sets(seed: int, touching: float = 0.4, most: int = 6) -> tuple[list[str], int, int]:
    rng = np.random.default_rng([seed, 2029])
    n_balls, n_colours = int(rng.integers(2, most + 1)), int(rng.integers(2, 4))
    objects = [
        {"name": n, "radius_cm": 2.0, "color_bgr": c, "drop_place_cm": p}
        for n, c, p in PALETTE[:n_colours]
    ]
    sets = [
        f"objects.objects={json.dumps(objects)}",
        f"bench.seed={seed}",
        f"bench.n_balls=[{n_balls}, {n_balls}]",
        f"bench.touching_fraction={touching}",
    ]
    return sets, n_balls, n_colours


def judge(out: Path) -> dict:
    world = json.loads((out / "bench" / "world.json").read_text())
    cycles = [json.loads(line) for line in (out / "cycles.jsonl").read_text().splitlines()]
    placed = [b for b in world["balls"] if b["state"] == "placed"]
    wrong = [b for b in placed if b["place"] != f"{b['object']}_place"]
    pushes = [e for e in world["events"] if e["what"] == "push"]
    refused_goals, latencies = 0, []
    logs = out / "act" / "log.cycles.jsonl"
    by_cycle = {}
    if logs.is_file():
        for line in logs.read_text().splitlines():
            rec = json.loads(line)
            by_cycle[rec["cycle"]] = rec["log"]
    for c in cycles:
        for p in (by_cycle.get(c["cycle"]) or {}).get("picks", []):
            sim = p.get("sim") or {}
            refused_goals += sum(
                1
                for w in sim.get("writes", [])
                if w["address"] == GOAL_POSITION and not w["accepted"]
            )
            first = next((k["t_s"] for k in p["commands"] if k["address"] == GOAL_POSITION), None)
            if first is not None:
                before = sum(d["seconds"] for n, d in c["nodes"].items() if n != "act")
                latencies.append(before + first)
    status = cycles[-1]["values"].get("plan.status") or {}
    return {
        "balls": len(world["balls"]),
        "placed": len(placed),
        "wrong": len(wrong),
        "pushes": len(pushes),
        "refused_goals": refused_goals,
        "retries": int(status.get("retries") or 0),
        "cycles": len(cycles),
        "latencies": latencies,
        "left": [b["id"] for b in world["balls"] if b["state"] != "placed"],
        "failed_cycles": sum(c["status"] != "ok" for c in cycles),
        "why": status.get("why"),
        "not_pickable": status.get("not_pickable"),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="tables (count)")
    ap.add_argument("--seed", type=int, default=0, help="first table's seed")
    ap.add_argument(
        "--out", type=Path, default=None, help="where the run folders go (default: a temporary one)"
    )
    ap.add_argument(
        "--touching", type=float, default=0.4, help="share of balls put against another (0..1)"
    )
    ap.add_argument("--most-balls", type=int, default=6, help="most balls on a table (2..n)")
    a = ap.parse_args()
    base = a.out or Path(tempfile.mkdtemp(prefix="clear-bench-"))
    rows, t_all = [], 0.0
    for k in range(a.n):
        seed = a.seed + k
        sets, n_balls, n_colours = table_sets(seed, a.touching, a.most_balls)
        out = base / f"table{seed:04d}"
        cmd = [
            sys.executable,
            "-m",
            "stereograph",
            "run",
            str(ROOT / "pipelines" / "clear-table.yaml"),
            "--out",
            str(out),
            "--cache-dir",
            str(base / "cache"),
        ]
        for s in sets:
            cmd += ["--set", s]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        dt = time.perf_counter() - t0
        if not (out / "bench" / "world.json").is_file():
            print(
                f"table {seed}: the run failed: {(proc.stderr.strip().splitlines() or ['?'])[-1]}",
                flush=True,
            )
            rows.append(
                {
                    "balls": n_balls,
                    "placed": 0,
                    "wrong": 0,
                    "pushes": 0,
                    "refused_goals": 0,
                    "retries": 0,
                    "cycles": 0,
                    "latencies": [],
                    "left": ["all"],
                    "seconds": dt,
                }
            )
            t_all += dt
            continue
        r = judge(out)
        r.update(seed=seed, colours=n_colours, seconds=dt)
        t_all += dt
        rows.append(r)
        print(
            f"table {seed}: {r['placed']}/{r['balls']} placed ({n_colours} colours), "
            f"wrong {r['wrong']}, "
            f"pushes {r['pushes']}, retries {r['retries']}, {r['cycles']} cycles, {dt:.1f} s"
            + (f"; left {r['left']}: {r['why']} {r['not_pickable']}" if r["left"] else ""),
            flush=True,
        )
    lat = np.array([x for r in rows for x in r["latencies"]]) * 1000
    placed = sum(r["placed"] for r in rows)
    print(f"\n{len(rows)} tables, {sum(r['balls'] for r in rows)} balls")
    print(f"tables fully cleared: {sum(r['placed'] == r['balls'] for r in rows)}/{len(rows)}")
    print(f"balls placed: {placed}; in the wrong place: {sum(r['wrong'] for r in rows)}")
    print(f"goals outside limits (refused by the servos): {sum(r['refused_goals'] for r in rows)}")
    print(f"gripper paths through another ball (pushes): {sum(r['pushes'] for r in rows)}")
    print(
        f"retries: {sum(r['retries'] for r in rows)}; failed cycles: "
        f"{sum(r.get('failed_cycles', 0) for r in rows)}"
    )
    print(f"seconds per ball placed (whole run, incl. process start): {t_all / max(placed, 1):.2f}")
    if lat.size:
        print(
            f"grab -> first goal per cycle: median {np.median(lat):.0f} ms, p95 "
            f"{np.percentile(lat, 95):.0f} ms "
            f"({lat.size} cycles)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
