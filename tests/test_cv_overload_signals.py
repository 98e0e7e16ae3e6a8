"""A stop signal never crashes OpenCV's binding: node code the run can be stopped in calls OpenCV
through its first overload, or within ``nodes.contracts.cv_overloads.stop_signals_held``.

Each case runs in a child process that this one pelts with SIGTERM (every 0.5 ms; a thread of the
child's own could not: it sends only while it holds the child's GIL, never in the binding's
window), its handler raising ``KeyboardInterrupt`` as ``stereograph run`` does. Before the fix
each case died of a segmentation fault within a second (``Canny(dx, dy)``,
``findFundamentalMat`` without ``maxIters``, ``ellipse`` of a rotated box, ``FileStorage.write``
of a float).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_CHILD = textwrap.dedent(
    """
    import signal, sys, time
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    case = sys.argv[1]
    if case == "segment":
        from nodes.segmenters.edge_morph import EdgeMorphParams, edge_morph_mask
        img = np.full((240, 320, 3), 90, np.uint8)
        cv2.circle(img, (160, 120), 30, (40, 60, 200), -1)
        img = cv2.add(img, rng.integers(0, 20, img.shape, dtype=np.uint8))
        work = lambda: edge_morph_mask(img, EdgeMorphParams(), (20, 40))
    elif case == "epipolar":
        from nodes.rectifiers.check import _epipolar_inliers
        a = rng.uniform(0, 320, (60, 2))
        b = a + [-12.0, 0.0] + rng.normal(0, 0.3, a.shape)
        work = lambda: _epipolar_inliers(a, b)
    elif case == "partial":
        from nodes.contracts.segmenter._partial_pass import _filled_ellipse
        ell = {"center_px": (160.3, 120.7), "axes_px": (30.2, 28.9), "angle_deg": 12.0}
        work = lambda: _filled_ellipse((240, 320), ell, (0, 0))
    else:
        from nodes.contracts.calibration_export import opencv_text, rectify_params
        K = np.array([[500.0, 0, 160], [0, 500, 120], [0, 0, 1]])
        cal = {"image_size": [320, 240], "K1": K, "K2": K, "D1": np.zeros(5), "D2": np.zeros(5),
               "R": np.eye(3), "T_cm": np.array([-8.0, 0, 0]), "rms_px": 0.2, "method": "tsai"}
        rect = rectify_params(cal)
        work = lambda: opencv_text(cal, rect)

    armed = [False]

    def on_term(signum, frame):
        if armed[0]:
            armed[0] = False
            raise KeyboardInterrupt

    work()  # warm (imports, first-call set-up) before the signals start
    signal.signal(signal.SIGTERM, on_term)
    print("ready", flush=True)
    deadline = time.monotonic() + float(sys.argv[2])
    calls = interrupted = 0
    while time.monotonic() < deadline:
        try:
            armed[0] = True
            work()
            armed[0] = False
            calls += 1
        except KeyboardInterrupt:
            interrupted += 1
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    print(calls, interrupted)
    """
)


@pytest.mark.parametrize("case", ["segment", "epipolar", "partial", "export"])
def test_a_stop_signal_in_opencv_calls_is_an_interrupt_not_a_crash(case, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONFAULTHANDLER": "1"}
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD, case, os.environ.get("STEREOGRAPH_PELT_S", "1.5")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    assert child.stdout.readline().strip() == "ready", child.communicate(timeout=60)[1][-2000:]
    with contextlib.suppress(ProcessLookupError):
        while child.poll() is None:
            os.kill(child.pid, signal.SIGTERM)
            time.sleep(0.0005)
    out, err = child.communicate(timeout=60)
    assert child.returncode != -signal.SIGSEGV, f"{case}: segmentation fault\n{err[-2000:]}"
    assert child.returncode == 0, err[-2000:]
    calls, interrupted = (int(v) for v in out.split())
    assert interrupted > 20, f"{case}: the signals hardly landed ({calls} calls, {interrupted})"
