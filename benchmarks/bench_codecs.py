"""Which lossless codec a recorded "camera" should use: decode time per frame, file size, pixel
identity.

    .venv/bin/python benchmarks/bench_codecs.py [--frames 12] [--core 0]

Renders pick-live's synthetic rig (640x480 by default), writes the left frames with each lossless
codec ``recorder.stereo_video`` offers (``cv2.VideoWriter``, .avi), reads them back through
``cv2.VideoCapture`` the way ``source.camera`` does (``grab()`` then ``retrieve()``), and prints per
codec the median wall and CPU time to grab + decode one frame, the file size per frame, and whether
every frame read back equals the one written. Pinned to one core, OpenCV single-threaded; on a
shared machine the CPU column is the one to compare.
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
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12, help="scenes rendered and recorded")
    ap.add_argument("--width-px", type=int, default=640)
    ap.add_argument("--height-px", type=int, default=480)
    ap.add_argument(
        "--repeat", type=int, default=5, help="passes over the file (median over all frames read)"
    )
    ap.add_argument("--core", type=int, default=0, help="CPU core to run on (-1: do not pin)")
    a = ap.parse_args(argv)
    if a.core >= 0 and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {a.core})
    import cv2

    cv2.setNumThreads(1)
    from nodes.contracts.recording import LOSSLESS, write_video
    from nodes.sources.synthetic import SyntheticParams, synthetic

    pairs = synthetic(
        SyntheticParams(
            n_scenes=a.frames,
            n_views=0,
            train_fraction=0.0,
            seed=11,
            image_width_px=a.width_px,
            image_height_px=a.height_px,
        )
    )["pairs"]
    frames = [p["left"] for p in pairs.values()]
    print(
        f"{len(frames)} frames {a.width_px}x{a.height_px}, OpenCV {cv2.__version__}, 1 thread, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(f"{'codec':<6}{'decode median ms':>18}{'CPU median ms':>15}{'kB / frame':>12}  identical")
    with tempfile.TemporaryDirectory() as tmp:
        for codec in LOSSLESS:
            path = Path(tmp) / f"{codec}.avi"
            write_video(frames, path, 30.0, codec)
            wall, cpu, same = [], [], True
            for _ in range(a.repeat):
                cap = cv2.VideoCapture(str(path))
                for want in frames:
                    t0, c0 = time.perf_counter(), time.thread_time()
                    ok = cap.grab()
                    ok, got = cap.retrieve() if ok else (False, None)
                    wall.append((time.perf_counter() - t0) * 1000)
                    cpu.append((time.thread_time() - c0) * 1000)
                    same = same and ok and np.array_equal(got, want)
                cap.release()
            kb = path.stat().st_size / len(frames) / 1024
            print(
                f"{codec:<6}{np.median(wall):>18.2f}{np.median(cpu):>15.2f}{kb:>12.0f}  "
                f"{'yes' if same else 'NO'}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
