"""Latency of the live pick loop: from the frame grab to the first servo goal written, per stage.

    .venv/bin/python benchmarks/bench_latency.py [--cycles 60] [--core 0] [--sim-time-scale 50]
    [--set NODE.PARAM=V]

Runs ``pipelines/pick-live.yaml --repeat`` (the embedded default: a recorded synthetic 640x480
camera, the saved calibration / compensation / hand-eye, the AX-12A emulator on a pseudo-terminal
driven by the real dynamixel-sdk) in this process, pinned to one CPU core (OpenCV single-threaded),
and for every cycle that picks, times:

    grab               source.camera: grab() both sides, retrieve (decode), timestamps, skew check
    calibration check  rectifier.gate: features matched on the first pair and every 10th (else 0 ms)
    rectify+segment    the segmenter, rectifying on request only what it reads
    locate+compensate  centroid disparity, triangulation, depth compensation
    IK+plan            analytic IK, pick plan (limits checked)
    servo I/O          actuator up to the first goal written, split into
      check, port        plan check, the emulator (port: sim) and the open port (kept from cycle 1)
      reads, write       setup of each servo (cycle 1 and after a fault: ping, model, limits), its
                         present position, the first GROUP SYNC WRITE
    grab -> first goal the sum: from the camera node's start to the first goal packet written

Stage times are wall-clock between the engine's node starts (so engine overhead is counted, in
the stage it falls in) and the first sync write returning; the motion itself is excluded. Cycle 1
(loading the files, recording the camera) is not counted; nor are cycles where nothing was picked
(reported). Prints median and p95 per stage in ms, with the main thread's CPU time beside them:
on a shared machine the wall figure includes waiting for the core, the CPU figure does not.
The main thread's CPU figure excludes the emulator, which runs in a thread of this process; the
last column, the whole process's CPU time (pipeline + emulator), is what the stage would take on
a core of its own, waits on the port aside.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STAGES = [
    ("grab", "cam", "gate"),
    ("calibration check", "gate", "segment"),
    ("rectify+segment", "segment", "disparity"),
    ("locate+compensate", "disparity", "ik"),
    ("IK+plan", "ik", "act"),
    ("servo I/O", "act", None),
]


def _now() -> tuple[float, float, float]:
    """Wall clock, this thread's CPU clock, the whole process's CPU clock (s)."""
    return time.perf_counter(), time.thread_time(), time.process_time()


def _ms(a: tuple, b: tuple) -> tuple[float, ...]:
    return tuple((y - x) * 1000 for x, y in zip(a, b))


class Stamps:
    """The engine's progress hook: when each node started (wall and this thread's CPU clock)."""

    def __init__(self):
        self.start: dict[str, tuple[float, float, float]] = {}

    def node_started(self, name: str, n_items: int) -> None:
        self.start[name] = _now()

    def advance(self, name: str) -> None:
        pass


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--cycles",
        type=int,
        default=60,
        help="cycles measured (after the first), >= 50 for the figure",
    )
    ap.add_argument("--core", type=int, default=0, help="CPU core to run on (-1: do not pin)")
    ap.add_argument(
        "--emulator-core",
        type=int,
        default=None,
        help="CPU core of the servo emulator's thread (default: --core, all on one core; "
        "another core "
        "models servos that do not share our CPU)",
    )
    ap.add_argument(
        "--sim-time-scale",
        type=float,
        default=50.0,
        help="emulated motion speed-up (the motion is not timed; this only shortens the run)",
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="NODE.PARAM=VALUE", help="pipeline override"
    )
    a = ap.parse_args(argv)
    if a.core >= 0 and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {a.core})  # this thread (and threads it starts) on one core
    import cv2

    cv2.setNumThreads(1)
    import nodes.actuators._bus as bus_mod
    import simbench.servo_sim as sim_mod

    emu_core = a.emulator_core if a.emulator_core is not None else (a.core if a.core >= 0 else None)
    sim_start = sim_mod.ServoSim.start

    def pinned_start(self):
        out = sim_start(self)
        if emu_core is not None and self._thread is not None and hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(self._thread.native_id, {emu_core})
        return out

    sim_mod.ServoSim.start = pinned_start
    from stereograph.app.loop import Loop
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph
    from stereograph.core.runner import run_graph

    # (wall, cpu) when the first sync write of a cycle returned
    first_goal: list[tuple[float, float, float]] = []
    # (wall, cpu) when the plan started on the open port
    port_open: list[tuple[float, float, float]] = []
    sync_write, bus_begin = bus_mod.Bus.sync_write, bus_mod.Bus.begin

    def timed_begin(self, t0):
        out = bus_begin(self, t0)
        self._bench_stamped = False  # a new plan on a bus kept open: stamp its first write
        port_open.append(_now())
        return out

    def timed_sync_write(self, data):  # instrumentation only: the real write, then a timestamp
        out = sync_write(self, data)
        if not getattr(self, "_bench_stamped", False):
            self._bench_stamped = True
            first_goal.append(_now())
        return out

    bus_mod.Bus.sync_write = timed_sync_write
    bus_mod.Bus.begin = timed_begin
    stamps = Stamps()
    rows: list[dict[str, tuple[float, float, float]]] = []
    not_picked: dict[str, int] = {}

    def on_cycle(c) -> None:
        goal = first_goal.pop() if first_goal else None
        opened = port_open[0] if port_open else None
        first_goal.clear()
        port_open.clear()
        if c.index == 1:
            return
        if c.status != "ok" or goal is None:
            key = f"{c.failed_node}: {(c.error or '')[:80]}"
            not_picked[key] = not_picked.get(key, 0) + 1
            return
        row = {}
        for name, a_node, b_node in STAGES:
            t0 = stamps.start[a_node]
            t1 = stamps.start[b_node] if b_node else goal
            row[name] = _ms(t0, t1)
        t0 = stamps.start["act"]
        row["  check, port"] = _ms(t0, opened)
        row["  reads, write"] = _ms(opened, goal)
        t0 = stamps.start["cam"]
        row["grab -> first goal"] = _ms(t0, goal)
        rows.append(row)
        print(
            f"\rcycle {c.index}: {row['grab -> first goal'][0]:.1f} ms",
            end="",
            file=sys.stderr,
            flush=True,
        )

    doc = load_pipeline(
        ROOT / "pipelines" / "pick-live.yaml", [f"act.sim_time_scale={a.sim_time_scale}", *a.set]
    )
    loop = Loop(a.cycles + 1, on_cycle=on_cycle)
    t_run = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        run_graph(build_graph(doc), cycles=loop, out_dir=Path(tmp) / "run", progress=stamps)
    print(file=sys.stderr)
    w, h = (
        doc.nodes["scenes"]["params"].get("image_width_px", 640),
        doc.nodes["scenes"]["params"].get("image_height_px", 480),
    )
    pinned = (
        f"pipeline pinned to core {a.core}, emulator on core {emu_core}"
        if a.core >= 0
        else "not pinned"
    )
    print(
        f"pick-live latency: {len(rows)} picking cycles of {len(loop.cycles) - 1} "
        f"measured, {w}x{h}, {pinned}, "
        f"OpenCV 1 thread, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores "
        f"({time.time() - t_run:.0f} s)"
    )
    if not rows:
        print("no cycle picked anything:", not_picked)
        return 1
    print(
        f"{'stage':<22}{'median ms':>11}{'p95 ms':>9}   "
        f"{'CPU median':>10}{'CPU p95':>9}{'process CPU median':>20}"
    )
    for name in [s[0] for s in STAGES] + ["  check, port", "  reads, write", "grab -> first goal"]:
        wall = np.array([r[name][0] for r in rows])
        cpu = np.array([r[name][1] for r in rows])
        proc = np.array([r[name][2] for r in rows])
        print(
            f"{name:<22}{np.median(wall):>11.1f}{np.percentile(wall, 95):>9.1f}   "
            f"{np.median(cpu):>10.1f}{np.percentile(cpu, 95):>9.1f}{np.median(proc):>20.1f}"
        )
    total = np.median([r["grab -> first goal"][0] for r in rows])
    print(f"grab -> first goal written: median {total:.1f} ms (target <= 30 ms, motion excluded)")
    if not_picked:
        print(
            "cycles without a pick (not timed): "
            + "; ".join(f"{n}x {k}" for k, n in not_picked.items())
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
