"""The live pick loop stops when told, however it was started (benchmarks/soak_stop.py, bounded).

One trial per moment (the grab, segmenting, IK, servo I/O, between cycles, any moment), SIGINT and
SIGTERM, in the foreground and as a background job of a non-interactive shell, which inherits SIGINT
ignored. The large version: ``python benchmarks/soak_stop.py --trials 200``.
"""

from __future__ import annotations

import importlib.util
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def _soak_module():
    spec = importlib.util.spec_from_file_location("soak_stop", ROOT / "benchmarks" / "soak_stop.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # (its dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


def test_a_background_job_inherits_sigint_ignored():
    """The premise of the background trials: `cmd &` in `sh -c` ignores SIGINT in cmd."""
    out = subprocess.run(
        ["sh", "-c", "grep SigIgn /proc/self/status & wait"], capture_output=True, text=True
    )
    if not out.stdout:
        pytest.skip("no /proc here")
    assert int(out.stdout.split()[1], 16) & (1 << (signal.SIGINT - 1))


def test_every_signal_at_every_moment_ends_the_loop_within_a_second(tmp_path):
    soak = _soak_module()
    # one trial per target; signals and start modes alternating
    plan = [
        soak.Trial(
            i,
            ("SIGINT", "SIGTERM")[i % 2],
            ("background", "foreground")[(i // 2) % 2],
            target,
            0.5 if target == "random" else soak.JITTER_S[target] / 2,
        )
        for i, target in enumerate(soak.TARGETS)
    ]
    results = soak.soak(plan, jobs=2, work=tmp_path, echo=lambda line: None)
    assert {t.target for t in results} == set(soak.TARGETS)
    assert {t.started for t in results} == {"foreground", "background"}
    bad = [f"{t.signal} {t.started} at {t.target}: {t.problems}" for t in results if not t.clean]
    assert not bad, bad
