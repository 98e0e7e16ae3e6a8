"""Parallel runs and streaming memory (issue 13, items 3-5), all figures from one run.

    python benchmarks/bench_parallel.py                 # 120 pairs: 1 vs 2 workers, node-by-node,
                                                        # 480 pairs peak RSS, Dask LocalCluster
    python benchmarks/bench_parallel.py --skip 480,dask # the quick part only
    python benchmarks/bench_parallel.py --skip split,nodebynode,480,dask --repeat 5
                                                        # the 2-vs-1 ratio, median of 5 back-to-back
                                                        pairs

Each case is ``stereograph run pipelines/locate.yaml --no-cache`` in a child process; wall time
is measured around it, CPU time (user + system, the child and its worker processes) and peak
RSS (the largest of those processes, as ``/usr/bin/time -v`` reports it) from ``wait4``. On a
shared machine the wall-time ratio depends on what else runs: the CPU seconds printed beside it
say how much work each case did, so the ratio can be judged (and re-measured on a quiet machine).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_disk_startup import bytecode  # (this folder is on sys.path: the script's own)

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ROOT / "pipelines" / "locate.yaml"
MAPPED = {"remap", "segment", "disparity", "locate"}  # locate.yaml's per-item nodes


def run_case(label: str, args: list[str], out: Path, env: dict | None = None) -> dict:
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(PIPELINE),
        "--no-cache",
        "--out",
        str(out),
        *args,
    ]
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **(env or {})},
    )
    _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read() if proc.stderr else ""
    rc = os.waitstatus_to_exitcode(status)
    row = {
        "case": label,
        "rc": rc,
        "wall_s": wall,
        "cpu_s": ru.ru_utime + ru.ru_stime,
        "peak_rss_mb": ru.ru_maxrss / 1024,
        "out": str(out),
    }
    try:
        nodes = json.loads((out / "run.json").read_text())["nodes"]
        row["node_s"] = {n["node"]: n["seconds"] for n in nodes}
    except (OSError, ValueError, KeyError):
        row["error"] = err[-2000:]
    print(
        f"  {label:<34} rc {rc}  wall {wall:6.1f} s  cpu {row['cpu_s']:6.1f} s  "
        f"cpu/wall {row['cpu_s'] / wall:4.2f}  peak RSS {row['peak_rss_mb']:6.0f} MB",
        flush=True,
    )
    if rc:
        print(err[-2000:])
    return row


def split_cpu(pairs: int, out: Path) -> dict:
    """The 2-worker run in this process: CPU of the stereograph process itself (start-up, the
    head, the tail, its bookkeeping) apart from the CPU of its worker processes."""
    import resource

    from stereograph.core.executors import ProcessExecutor
    from stereograph.core.runner import run_pipeline

    s0, c0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    ex = ProcessExecutor(2)
    try:
        r = run_pipeline(
            PIPELINE, [f"rig.n_scenes={pairs}"], use_cache=False, executor=ex, out_dir=out
        )
    finally:
        ex.close()  # (the workers' CPU is counted once they are reaped)
    wall = time.perf_counter() - t0
    s1, c1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    parent = (s1.ru_utime - s0.ru_utime) + (s1.ru_stime - s0.ru_stime)
    workers = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    print(
        f"  {pairs} pairs, --workers 2, in this process: ok {r.ok}  wall {wall:6.1f} s  "
        "stereograph process "
        f"CPU {parent:5.1f} s  its 2 workers' CPU {workers:5.1f} s",
        flush=True,
    )
    return {"wall_s": wall, "parent_cpu_s": parent, "workers_cpu_s": workers}


def locations(out: str) -> list[dict]:
    return json.loads((Path(out) / "report" / "locations.json").read_text())


def max_difference(a: list[dict], b: list[dict]) -> tuple[float, list[str]]:
    """Largest |difference| of the numbers, and every non-number that differs."""
    worst, other = 0.0, []

    def walk(x, y, path):
        nonlocal worst
        if isinstance(x, dict) and isinstance(y, dict) and x.keys() == y.keys():
            for k in x:
                walk(x[k], y[k], f"{path}.{k}")
        elif isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
            for k, (u, v) in enumerate(zip(x, y)):
                walk(u, v, f"{path}[{k}]")
        elif isinstance(x, float) and isinstance(y, float):
            worst = max(worst, abs(x - y))
        elif x != y:
            other.append(path)

    walk(a, b, "")
    return worst, other


def same_files(a: str, b: str, sub: str) -> tuple[int, int]:
    folder = Path(a) / sub
    fa = (
        sorted(f for f in folder.iterdir() if f.suffix in (".png", ".jpg"))
        if folder.is_dir()
        else []
    )
    same = sum(
        (Path(b) / sub / f.name).is_file()
        and (Path(b) / sub / f.name).read_bytes() == f.read_bytes()
        for f in fa
    )
    return same, len(fa)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=120, help="pairs of the speed runs (default 120)")
    ap.add_argument("--big", type=int, default=480, help="pairs of the memory run (default 480)")
    ap.add_argument(
        "--skip", default="", help="comma list of cases to skip: split, nodebynode, 480, dask"
    )
    ap.add_argument("--keep", action="store_true", help="keep the run folders (printed at the end)")
    ap.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="pairs of 1- and 2-worker runs, back to back (order alternating); the median ratio is "
        "printed too: a shared VM's speed drifts between minutes (default 1)",
    )
    ap.add_argument(
        "--no-compile", action="store_true", help="leave the project's bytecode as it is"
    )
    a = ap.parse_args()
    skip = set(filter(None, a.skip.split(",")))
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start")
    # (start-up runs alone: stale bytecode would weigh on the 2-worker run most)
    bytecode(not a.no_compile)
    tmp = Path(tempfile.mkdtemp(prefix="bench_parallel-"))
    n = ["--set", f"rig.n_scenes={a.pairs}"]
    rows = {}
    rows["w1"] = run_case(f"{a.pairs} pairs, --workers 1", n, tmp / "w1")
    rows["w2"] = run_case(f"{a.pairs} pairs, --workers 2", n + ["--workers", "2"], tmp / "w2")
    ratios = [rows["w1"]["wall_s"] / rows["w2"]["wall_s"]]
    for k in range(1, a.repeat):
        # each pair back to back, the first run alternating
        order = ("2", "1") if k % 2 else ("1", "2")
        walls = {}
        for w in order:
            walls[w] = run_case(
                f"{a.pairs} pairs, --workers {w} (repeat {k + 1})",
                n + ["--workers", w],
                tmp / f"r{k}w{w}",
            )["wall_s"]
            shutil.rmtree(tmp / f"r{k}w{w}", ignore_errors=True)
        ratios.append(walls["1"] / walls["2"])
    if "split" not in skip:
        rows["split"] = split_cpu(a.pairs, tmp / "split")
    if "nodebynode" not in skip:
        rows["nbn"] = run_case(
            f"{a.pairs} pairs, node by node, serial", n, tmp / "nbn", {"STEREOGRAPH_STREAM": "0"}
        )
    if "480" not in skip:
        rows["big"] = run_case(
            f"{a.big} pairs, --workers 1", ["--set", f"rig.n_scenes={a.big}"], tmp / "big"
        )
    if "dask" not in skip:
        rows["dask"] = run_case(
            f"{a.pairs} pairs, --dask local (2 workers)",
            n + ["--dask", "local", "--workers", "2"],
            tmp / "dask",
        )
    print()
    w1, w2 = rows["w1"], rows["w2"]
    print(
        f"speed-up, 2 workers over 1: {w1['wall_s'] / w2['wall_s']:.2f}x wall "
        f"(target >= 1.7x); CPU {w1['cpu_s']:.1f} s vs {w2['cpu_s']:.1f} s"
    )
    if len(ratios) > 1:
        print(
            f"  {len(ratios)} back-to-back pairs: "
            + ", ".join(f"{r:.2f}x" for r in ratios)
            + f"; median {statistics.median(ratios):.2f}x"
        )
    print(
        f"  the 1-worker run used {w1['cpu_s'] / w1['wall_s']:.2f} cores (the libraries' "
        "threads), so 2 workers are "
        f"at most 2 x {w1['wall_s']:.1f} / {w2['cpu_s']:.1f} = "
        f"{2 * w1['wall_s'] / w2['cpu_s']:.2f}x faster "
        "even with nothing in the run alone"
    )
    if "node_s" in w1:
        print(
            "  node seconds, 1 worker :",
            json.dumps({k: round(v, 2) for k, v in w1["node_s"].items()}),
        )
        print(
            "  node seconds, 2 workers:",
            json.dumps({k: round(v, 2) for k, v in w2.get("node_s", {}).items()}),
            "(per-item nodes: summed over workers)",
        )
    if "split" in rows:
        sp = rows["split"]
        print(
            "CPU of a 2-worker run: the stereograph process itself "
            f"{sp['parent_cpu_s']:.1f} s (imports, the "
            "head: views, calibration; the tail: the report), its workers "
            f"{sp['workers_cpu_s']:.1f} s"
        )
    if "node_s" in w2:
        # the tail (nodes after the last per-item node: the report) runs alone; the rest can use
        # both cores
        names = list(w2["node_s"])
        last = max((k for k, n in enumerate(names) if n in MAPPED), default=-1)
        tail = sum(w2["node_s"][n] for n in names[last + 1 :])
        bound = tail + (w2["cpu_s"] - tail) / 2
        print(
            "on an idle 2-core machine the 2-worker run needs at least tail + (CPU - "
            f"tail) / 2 = {tail:.1f} + "
            f"({w2['cpu_s']:.1f} - {tail:.1f}) / 2 = {bound:.1f} s against the 1-worker run's "
            f"{w1['wall_s']:.1f} s: a speed-up of at most {w1['wall_s'] / bound:.2f}x (a "
            "bound, not a measurement: "
            "it leaves out start-up, which runs alone, and the wait for the last task)"
        )
    if "nbn" in rows:
        r = rows["nbn"]
        print(
            f"serial, streamed vs node by node: {w1['wall_s']:.1f} s vs {r['wall_s']:.1f} s wall, "
            f"{w1['cpu_s']:.1f} vs {r['cpu_s']:.1f} s CPU; peak RSS {w1['peak_rss_mb']:.0f} vs "
            f"{r['peak_rss_mb']:.0f} MB"
        )
    if "big" in rows:
        r = rows["big"]
        print(
            f"peak RSS, {a.big} vs {a.pairs} pairs: {r['peak_rss_mb']:.0f} MB / "
            f"{w1['peak_rss_mb']:.0f} MB = "
            f"{r['peak_rss_mb'] / w1['peak_rss_mb']:.2f} (target <= 1.2)"
        )
    for key in ("w2", "nbn", "dask"):
        if key in rows and rows[key]["rc"] == 0 and w1["rc"] == 0:
            d, other = max_difference(locations(w1["out"]), locations(rows[key]["out"]))
            same, total = same_files(w1["out"], rows[key]["out"], "segment/overlay")
            print(
                f"{rows[key]['case']} vs 1 worker: locations max |difference| {d:.2g} cm, "
                f"{len(other)} non-numbers differ; segment overlays byte-identical {same}/{total}"
            )
    print("(two serial runs differ by ~1e-10 cm too: OpenCV's calibration uses threads)")
    if a.keep:
        print(f"run folders under {tmp}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)  # ~1 GB of overlays for 480 pairs
    return 0


if __name__ == "__main__":
    sys.exit(main())
