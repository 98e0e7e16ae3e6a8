"""Second run with no change vs first run: every node cached, and how much faster.

    python benchmarks/bench_cache.py [PIPELINE] [--set node.param=value ...]

Default pipeline: pipelines/locate.yaml if it exists, else pipelines/hello.yaml (toy nodes
doing real matrix work). Uses a fresh temporary cache. Prints both wall times and the ratio
(target: second run <= 20 % of the first).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser()
    default = (
        ROOT
        / "pipelines"
        / ("locate.yaml" if (ROOT / "pipelines" / "locate.yaml").exists() else "hello.yaml")
    )
    ap.add_argument("pipeline", nargs="?", default=str(default))
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        times, results = [], []
        for i in range(2):
            t0 = time.perf_counter()
            r = run_pipeline(
                a.pipeline, a.set, cache_dir=Path(tmp) / "cache", out_dir=Path(tmp) / f"out{i}"
            )
            times.append(time.perf_counter() - t0)
            results.append(r)
            if not r.ok:
                print(
                    f"run {i + 1} failed: {[(n, x.error) for n, x in r.reports.items() if x.error]}"
                )
                return 1
        statuses = set(results[1].status.values())
        print(f"pipeline: {a.pipeline} {' '.join(a.set)}")
        print(f"first run:  {times[0]:.3f} s  ({len(results[0].ran)} nodes ran)")
        print(f"second run: {times[1]:.3f} s  (statuses: {sorted(statuses)})")
        print(f"ratio second/first: {times[1] / times[0]:.3f}  (target <= 0.20)")
        return 0 if statuses == {"cached"} else 1


if __name__ == "__main__":
    sys.exit(main())
