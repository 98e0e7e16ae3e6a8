"""Lossless stereo video files: write pairs with ``cv2.VideoWriter``, and the ``StereoRecording``
artifact.

``StereoRecording`` (one artifact)::

    {"left_video": uint8 (n,), "right_video": uint8 (n,),  # the two files' bytes
     "container": "avi" | "mkv", "codec": "HFYU" | "FFV1" | "RGBA", "fps": float, "image_size": [w,
     h],
     "ids": [str, ...], "truth": [StereoPair.truth | None, ...]}   # per frame

The bytes travel in the artifact (and the cache) so that a camera source can write them into its
run folder and open them with ``cv2.VideoCapture`` — the same path as a real camera's recording.
HuffYUV, FFV1 and uncompressed RGBA are lossless: frames read back are pixel-identical to the
frames written. Grabbing and decoding a 640x480 frame on one core (CPU time, on the development
machine, ``benchmarks/bench_codecs.py``): RGBA ~0.7 ms, HuffYUV ~9 ms, FFV1 ~39 ms; sizes ~1200,
~460 and ~410 kB. A recording is a camera in a latency-bound loop, so RGBA is the default.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from stereograph.api import NodeError

LOSSLESS = ("HFYU", "FFV1", "RGBA")  # RGBA: uncompressed (fastest to decode, ~2.6x larger)


def write_video(frames: Iterable[np.ndarray], path: Path, fps: float, codec: str = "FFV1") -> int:
    """Write BGR uint8 frames (all one size) to ``path``; returns the number written.

    Raises
    ------
    NodeError
        OpenCV's build cannot write this codec / container, or the frames differ in size.
    """
    writer, size, n = None, None, 0
    try:
        for f in frames:
            f = np.ascontiguousarray(f if f.ndim == 3 else cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
            if writer is None:
                size = (f.shape[1], f.shape[0])
                writer = cv2.VideoWriter(
                    str(path), cv2.VideoWriter_fourcc(*codec), float(fps), size
                )
                if not writer.isOpened():
                    raise NodeError(
                        f"cv2.VideoWriter cannot write {codec} into {path.name}.",
                        hint=f"use codec {' or '.join(LOSSLESS)} with an .avi or .mkv file",
                    )
            if (f.shape[1], f.shape[0]) != size:
                raise NodeError(
                    f"frame {n} is {f.shape[1]}x{f.shape[0]} px, the video {size[0]}x{size[1]} px.",
                    hint="record pairs of one image size",
                )
            writer.write(f)
            n += 1
    finally:
        if writer is not None:
            writer.release()
    return n


def encode_recording(
    pairs: list[dict], fps: float = 30.0, codec: str = "RGBA", container: str = "avi"
) -> dict:
    """A ``StereoRecording`` of ``pairs`` (StereoPair dicts, in playing order)."""
    if not pairs:
        raise NodeError(
            "nothing to record: no stereo pairs.", hint="wire a source with at least one pair"
        )
    out: dict = {
        "container": container,
        "codec": codec,
        "fps": float(fps),
        "ids": [str(p["id"]) for p in pairs],
        "truth": [p.get("truth") for p in pairs],
    }
    with tempfile.TemporaryDirectory(prefix="stereograph-rec-") as tmp:
        for side in ("left", "right"):
            path = Path(tmp) / f"{side}.{container}"
            write_video((p[side] for p in pairs), path, fps, codec)
            out[f"{side}_video"] = np.frombuffer(path.read_bytes(), dtype=np.uint8).copy()
    h, w = pairs[0]["left"].shape[:2]
    out["image_size"] = [int(w), int(h)]
    return out


def write_recording(recording: dict, folder: Path) -> tuple[Path, Path]:
    """Write a ``StereoRecording``'s two files into ``folder``; their paths (left, right)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for side in ("left", "right"):
        path = folder / f"{side}.{recording.get('container', 'avi')}"
        path.write_bytes(np.asarray(recording[f"{side}_video"], dtype=np.uint8).tobytes())
        paths.append(path)
    return paths[0], paths[1]
