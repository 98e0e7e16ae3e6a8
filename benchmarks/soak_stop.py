"""Soak test of the live loop's stop: SIGINT / SIGTERM at chosen moments must end it cleanly.

    .venv/bin/python benchmarks/soak_stop.py [--trials 200] [--jobs 2] [--seed 0] [--json FILE]
        [--target segment] [--signal SIGTERM] [--started background]   # one kind of trial only

Each trial starts ``stereograph run pipelines/pick-live.yaml --repeat 0`` on the embedded default
(recorded camera, AX-12A emulator), in the foreground (signals as inherited from this process) or
as a background job of a non-interactive shell (``sh -c 'cmd & wait'``: SIGINT inherited *ignored*),
reads its progress lines and aims at a moment: the start of the grab (``cam``), the segmenting, IK
or the servo I/O (``act``) in a later cycle, plus a random part of that stage's time; the end of a
cycle (``between``); or a random 0-4 s after cycle 1. It then sends SIGINT or SIGTERM to the process
and times its exit; where the signal really landed is read back from ``run.json``. A trial is clean
when the process exits 130 within ``--max-exit-s`` (1 s), ``run.json`` records the interrupted loop,
and an interrupt during the servo I/O left ``servo_log_interrupted.json`` saying the arm was held
(every servo's goal := its present position) and the port closed.

Prints one line per trial and a summary: trials, clean exits, median and worst time to exit, and
where the interrupts landed. Exit status 1 if any trial was not clean. Only the trials that were
not clean are kept (folder and log, ~30 MB each; the path is printed); the rest is removed.
``tests/test_live_stop.py`` runs a few trials in CI; the full figure comes from this script.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ROOT / "pipelines" / "pick-live.yaml"
TARGETS = ["cam", "segment", "ik", "act", "between", "random"]
# ~ each stage's time
JITTER_S = {"cam": 0.003, "segment": 0.008, "ik": 0.001, "act": 1.5, "between": 0.002}


@dataclass
class Trial:
    index: int
    signal: str  # SIGINT | SIGTERM
    started: str  # foreground | background
    target: str  # a live node, "between" (a cycle's end) or "random" (any moment after cycle 1)
    delay_s: float  # after the target's start line
    exit_code: int | None = None
    exit_s: float | None = None
    landed: str = ""  # the node interrupted, or "between cycles"
    problems: str = ""

    @property
    def clean(self) -> bool:
        return not self.problems


def _command(out: Path, cache: Path, repeat: int = 0) -> list[str]:
    return [sys.executable, "-m", "stereograph", "run", str(PIPELINE), "--repeat", str(repeat),
            "--out", str(out), "--cache-dir", str(cache), "--verbose"]  # fmt: skip


def _start(cmd: list[str], background: bool, work: Path) -> tuple[subprocess.Popen, int]:
    """The process, its output as a text pipe, and the PID to signal (stereograph's, not a
    shell's)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if not background:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT
        )
        return proc, proc.pid
    # a non-interactive shell starts `&` jobs with SIGINT and SIGQUIT ignored, as a launcher script
    # would
    pid_file = work / f"pid-{time.monotonic_ns()}"
    script = '"$@" 2>&1 & echo $! >"$PID_FILE"; wait $!'
    proc = subprocess.Popen(["sh", "-c", script, "sh", *cmd], stdout=subprocess.PIPE, text=True,
                            env={**env, "PID_FILE": str(pid_file)}, cwd=ROOT)  # fmt: skip
    while not (pid_file.exists() and pid_file.read_text().strip()):
        time.sleep(0.005)
    return proc, int(pid_file.read_text())


def _aim(t: Trial, lines: Iterator[str], log) -> bool:
    """Read the run's output up to the moment to signal: the target node's start in cycle 2 or later
    (``between``, ``random``: cycle 1's end line), then wait ``delay_s``. False if the run ended
    first."""
    after_cycle_1 = False
    for line in lines:
        log.write(line)
        if line.startswith("cycle "):
            after_cycle_1 = True
            if t.target in ("random", "between"):
                break
        elif after_cycle_1 and line.startswith(f"{t.target}: started"):
            break
    else:
        return False
    time.sleep(t.delay_s)
    return True


def _check(t: Trial, out: Path, max_exit_s: float) -> None:
    problems = []
    if t.exit_code != 130:
        problems.append(f"exit code {t.exit_code}")
    if t.exit_s is None or t.exit_s > max_exit_s:
        problems.append(f"exit took {t.exit_s} s")
    try:
        loop = json.loads((out / "run.json").read_text()).get("loop") or {}
    except (OSError, ValueError) as e:
        t.problems = "; ".join(problems + [f"no run.json ({e})"])
        return
    if not loop.get("interrupted"):
        problems.append(f"run.json does not record an interrupt: {loop.get('stopped')}")
    stopped = loop.get("stopped", "")
    m = re.search(r"\(node '([^']+)'\)", stopped)
    # (in the engine as it went to a node: that node had not begun, so it has nothing to log)
    before = re.search(r"before node '([^']+)' began", stopped)
    t.landed = m.group(1) if m else f"before {before.group(1)}" if before else "between cycles"
    if t.landed == "act":
        try:
            stop = json.loads((out / "act" / "servo_log_interrupted.json").read_text())["stop"]
            nothing_moved = stop.get("action") == "none" and stop.get("during") == "setup"
            if not (stop.get("action") == "hold" or nothing_moved) or not stop.get("port_closed"):
                problems.append(f"arm not held / port open: {stop}")
        except (OSError, ValueError, KeyError) as e:
            problems.append(f"no servo log of the interrupt ({e})")
    t.problems = "; ".join(problems)


def run_trial(t: Trial, work: Path, cache: Path, max_exit_s: float) -> Trial:
    out = work / f"trial{t.index:04d}"
    with open(work / f"trial{t.index:04d}.log", "w") as log:
        proc, pid = _start(_command(out, cache), t.started == "background", work)
        try:
            if not _aim(t, iter(proc.stdout.readline, ""), log):
                t.problems = f"the run ended before the moment aimed at (exit code {proc.wait()})"
                return t
            os.kill(pid, getattr(signal, t.signal))
            t0 = time.monotonic()
            log.write(proc.stdout.read())  # to its end: the process has closed its output
            try:
                t.exit_code = proc.wait(timeout=30)
                t.exit_s = round(time.monotonic() - t0, 3)
            except subprocess.TimeoutExpired:
                t.problems = "still running 30 s after the signal"
                return t
        finally:
            if proc.poll() is None:
                os.kill(pid, signal.SIGKILL)
                proc.kill()
                proc.wait()
    _check(t, out, max_exit_s)
    return t


def warm_cache(work: Path, cache: Path) -> None:
    """Cycle 1's files and recording, computed once for every trial."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run(
        _command(work / "warm", cache, repeat=1), check=True, capture_output=True, env=env, cwd=ROOT
    )


SIGNALS, STARTS = ("SIGINT", "SIGTERM"), ("foreground", "background")


def plan_trials(
    trials: int,
    seed: int = 0,
    targets: list[str] = TARGETS,
    signals: tuple[str, ...] = SIGNALS,
    starts: tuple[str, ...] = STARTS,
) -> list[Trial]:
    """Each signal, start mode and target in turn, in every combination alike (by default SIGINT
    and SIGTERM, foreground and background, every target)."""
    rng = random.Random(seed)
    plan = []
    for i in range(trials):
        target = targets[(i // 4) % len(targets)]
        delay = rng.uniform(0.0, 4.0) if target == "random" else rng.uniform(0.0, JITTER_S[target])
        started = starts[(i // 2) % len(starts)]
        plan.append(Trial(i, signals[i % len(signals)], started, target, round(delay, 4)))
    return plan


def soak(
    plan: list[Trial], jobs: int = 2, max_exit_s: float = 1.0, work: Path | None = None, echo=print
):
    """Run the trials, ``jobs`` at a time, on one cache warmed first; each trial filled in."""
    work = Path(work or tempfile.mkdtemp(prefix="soak-stop-"))
    cache = work / "cache"
    warm_cache(work, cache)

    def one(t: Trial) -> Trial:
        run_trial(t, work, cache, max_exit_s)
        if t.clean:  # (a trial's folder holds its recording, ~30 MB: only failed ones are kept)
            shutil.rmtree(work / f"trial{t.index:04d}", ignore_errors=True)
        echo(f"trial {t.index:4d} {t.signal:7s} {t.started:10s} at {t.target}+{t.delay_s:.3f} s: "
             f"in {t.landed or '?':14s} exit {t.exit_code} in {t.exit_s} s "
             f"{'ok' if t.clean else 'NOT CLEAN: ' + t.problems}")  # fmt: skip
        return t

    with ThreadPoolExecutor(jobs) as pool:
        return list(pool.map(one, plan))


def summary(results: list[Trial]) -> str:
    times = [t.exit_s for t in results if t.exit_s is not None] or [float("nan")]
    where: dict[str, int] = {}
    for t in results:
        where[t.landed or "?"] = where.get(t.landed or "?", 0) + 1
    kinds = {k: sum(1 for t in results if t.started == k) for k in ("foreground", "background")}
    landed = ", ".join(f"{k} {v}" for k, v in sorted(where.items(), key=lambda kv: -kv[1]))
    return (f"{len(results)} trials ({kinds['foreground']} foreground, "
            f"{kinds['background']} background), {sum(t.clean for t in results)} clean; "
            f"time to exit median {statistics.median(times):.3f} s, "
            f"worst {max(times):.3f} s; interrupted in: {landed}")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--jobs", type=int, default=2, help="trials at a time")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-exit-s", type=float, default=1.0)
    ap.add_argument("--json", type=Path, help="write every trial here")
    ap.add_argument("--target", choices=TARGETS, help="aim at this moment only")
    ap.add_argument("--signal", choices=SIGNALS, help="send this signal only")
    ap.add_argument("--started", choices=STARTS, help="start every trial this way")
    a = ap.parse_args(argv)
    plan = plan_trials(
        a.trials,
        a.seed,
        [a.target] if a.target else TARGETS,
        (a.signal,) if a.signal else SIGNALS,
        (a.started,) if a.started else STARTS,
    )
    work = Path(tempfile.mkdtemp(prefix="soak-stop-"))
    results = soak(plan, a.jobs, a.max_exit_s, work)
    print(summary(results))
    if all(t.clean for t in results):
        shutil.rmtree(work, ignore_errors=True)
    else:
        print(f"the trials that were not clean are kept in {work} (folder and .log each)")
    if a.json:
        a.json.write_text(json.dumps([asdict(t) for t in results], indent=1))
    return 0 if all(t.clean for t in results) else 1


if __name__ == "__main__":
    sys.exit(main())
