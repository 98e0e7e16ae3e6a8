"""Issue 13's disk, rerun and start-up figures, measured through the ``stereograph`` command.

    python benchmarks/bench_disk_startup.py                 # everything (several minutes)
    python benchmarks/bench_disk_startup.py --only startup  # start-up only (seconds)

Prints, each measured in this run:

- start-up: wall and CPU seconds of ``stereograph --help`` and ``stereograph nodes`` (best of 3),
  and of ``python -c pass`` beside them (the interpreter's own share). Targets: 0.25 s and 0.6 s.
- disk: ``pipelines/pick.yaml`` from a cold cache (a fresh ``STEREOGRAPH_CACHE_DIR``): bytes of
  the cache and the run folder together (a hard-linked file counted once, as the disk holds it),
  and each apart. Target: <= 250 MB for 120 pairs.
- reruns with nothing changed, wall seconds including start-up: ``locate.yaml`` (target <= 0.5 s)
  and ``pick.yaml`` (target <= the actuator node's own seconds + 0.5 s, from that rerun's run.json;
  three reruns, the table shows the median). Each is a replay from the memo the cold run recorded
  (``stereograph/app/rerun.py``, docs/cache.md).
- with PYTHONDONTWRITEBYTECODE set, the project's modules are compiled first (see :func:`bytecode`).

Ends with every figure in one table (measured, target, met).

On a machine shared with other work, wall times include waiting for a core: compare the CPU
seconds too, and the ratios, taken in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXE = str(Path(sys.executable).with_name("stereograph"))
PICK_RERUNS = 3


def timed(cmd: list[str], env: dict | None = None) -> tuple[float, float, int]:
    """(wall s, CPU s of the child, exit code)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    rc = subprocess.run(
        cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT
    ).returncode
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), rc


def best(cmd: list[str], n: int = 3) -> tuple[float, float]:
    runs = [timed(cmd) for _ in range(n)]
    return min(r[0] for r in runs), min(r[1] for r in runs)


def disk_bytes(*roots: Path) -> int:
    """Bytes of the files under ``roots``, each inode once (hard links share their blocks)."""
    seen, total = set(), 0
    for root in roots:
        for dirpath, _dirs, files in os.walk(root):
            for f in files:
                st = os.lstat(os.path.join(dirpath, f))
                if (st.st_dev, st.st_ino) not in seen:
                    seen.add((st.st_dev, st.st_ino))
                    total += st.st_size
    return total


ROWS: list[tuple[str, str, str, bool]] = []  # (figure, measured, target, met) for the closing table


def row(figure: str, measured: str, target: str, met: bool) -> None:
    ROWS.append((figure, measured, target, met))


def startup() -> None:
    timed([EXE, "--help"])  # (first call builds the entry-point index)
    timed([EXE, "nodes"])
    py = best([sys.executable, "-c", "pass"])
    hlp = best([EXE, "--help"])
    nodes = best([EXE, "nodes"])
    print(f"python -c pass     wall {py[0]:.3f} s  cpu {py[1]:.3f} s")
    print(f"stereograph --help wall {hlp[0]:.3f} s  cpu {hlp[1]:.3f} s  (target 0.25 s)")
    print(f"stereograph nodes  wall {nodes[0]:.3f} s  cpu {nodes[1]:.3f} s  (target 0.6 s)")
    row(
        "`stereograph --help`",
        f"{hlp[0]:.2f} s wall ({hlp[1]:.2f} s cpu)",
        "<= 0.25 s",
        hlp[0] <= 0.25,
    )
    row(
        "`stereograph nodes`",
        f"{nodes[0]:.2f} s wall ({nodes[1]:.2f} s cpu)",
        "<= 0.6 s",
        nodes[0] <= 0.6,
    )


def run(pipeline: str, cache: Path, out: Path) -> tuple[float, float, dict]:
    env = dict(os.environ, STEREOGRAPH_CACHE_DIR=str(cache))
    wall, cpu, rc = timed([EXE, "run", f"pipelines/{pipeline}", "--out", str(out)], env)
    summary = json.loads((out / "run.json").read_text()) if (out / "run.json").exists() else {}
    if rc != 0:
        bad = [(n["node"], n["error"]) for n in summary.get("nodes", []) if n.get("error")]
        print(f"  {pipeline}: exit {rc} {bad}")
    return wall, cpu, summary


def disk_and_reruns() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        wall, cpu, _ = run("pick.yaml", t / "cache", t / "pick1")
        both = disk_bytes(t / "cache", t / "pick1")
        print(
            f"pick.yaml cold: {wall:.1f} s wall, {cpu:.1f} s cpu; cache + run folder "
            f"{both / 1e6:.0f} MB "
            f"(cache {disk_bytes(t / 'cache') / 1e6:.0f} MB, run folder "
            f"{disk_bytes(t / 'pick1') / 1e6:.0f} MB "
            f"apart; target 250 MB)"
        )
        row(
            "`pick.yaml` cold, cache + run folder (120 pairs)",
            f"{both / 1e6:.0f} MB",
            "<= 250 MB",
            both <= 250e6,
        )
        reruns = []
        # the first hashes the files the cold run wrote last again
        for k in range(2, 2 + PICK_RERUNS):
            wall, cpu, s = run("pick.yaml", t / "cache", t / f"pick{k}")
            act = sum(n["seconds"] for n in s.get("nodes", []) if n["status"] in ("ran", "partial"))
            ran = [n["node"] for n in s.get("nodes", []) if n["status"] != "cached"]
            print(
                f"pick.yaml rerun {k - 1}: {wall:.2f} s wall, {cpu:.2f} s cpu; nodes that "
                f"ran {ran} {act:.2f} s; "
                f"rest {wall - act:.2f} s wall (target 0.5 s)"
            )
            reruns.append((wall - act, wall, cpu, act))
        rest, wall, cpu, act = sorted(reruns)[len(reruns) // 2]  # the median rerun by its rest
        row(
            f"`pick.yaml` rerun (median of {len(reruns)})",
            f"{wall:.2f} s wall ({cpu:.2f} s cpu), actuator {act:.2f} s: rest {rest:.2f} s "
            f"(all: {', '.join(f'{r[0]:.2f}' for r in reruns)})",
            "<= actuator + 0.5 s",
            rest <= 0.5,
        )
        run("locate.yaml", t / "cache", t / "loc1")
        wall, cpu, s = run("locate.yaml", t / "cache", t / "loc2")
        ran = [n["node"] for n in s.get("nodes", []) if n["status"] != "cached"]
        print(
            f"locate.yaml rerun: {wall:.2f} s wall, {cpu:.2f} s cpu (target 0.5 s); not "
            f"cached: {ran}"
        )
        row(
            "`locate.yaml` rerun, nothing changed",
            f"{wall:.2f} s wall ({cpu:.2f} s cpu)",
            "<= 0.5 s wall",
            wall <= 0.5,
        )


def bytecode(compile_now: bool) -> None:
    """With PYTHONDONTWRITEBYTECODE set (this sandbox sets it), Python compiles every project module
    from source on every command (~0.1-0.2 s of a replayed rerun), as no installed copy does: pip
    compiles a package as it installs it, and any Python without the variable writes ``__pycache__``
    on the first import. So the project's bytecode is compiled first, as an installed copy has it
    (--no-compile measures without)."""
    if not (sys.flags.dont_write_bytecode or os.environ.get("PYTHONDONTWRITEBYTECODE")):
        return
    if compile_now:
        import compileall

        ok = all(compileall.compile_dir(ROOT / d, quiet=1) for d in ("stereograph", "nodes"))
        print(
            "PYTHONDONTWRITEBYTECODE is set: compiled the project's modules as an "
            f"install does ({ok=})"
        )
    else:
        print(
            "PYTHONDONTWRITEBYTECODE is set and --no-compile given: modules without "
            "__pycache__ are compiled "
            "from source on every command"
        )


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=["startup", "disk"])
    ap.add_argument(
        "--no-compile", action="store_true", help="leave the project's bytecode as it is"
    )
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    bytecode(not a.no_compile)
    if a.only in (None, "startup"):
        startup()
    if a.only in (None, "disk"):
        disk_and_reruns()
    print("\n| figure | measured | target | met |\n|---|---|---|---|")
    for figure, measured, target, met in ROWS:
        print(f"| {figure} | {measured} | {target} | {'yes' if met else 'NO'} |")
    print(
        f"(load average {os.getloadavg()[0]:.1f} at the end: on a shared machine wall "
        "times include waiting "
        "for a core; compare the cpu figures)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
