"""``recorder.stereo_video``: record stereo pairs as two lossless videos (a ``StereoRecording``).

What it is for: a camera you can replay. ``source.camera`` plays the recording through
``cv2.VideoCapture`` exactly as it reads a device, so a pipeline written for live cameras runs,
and is tested, on recorded or synthetic scenes (``pipelines/pick-live.yaml``'s default).
"""

from __future__ import annotations

from typing import Literal

from nodes.contracts.recording import LOSSLESS, encode_recording
from stereograph.api import Field, In, NodeError, Out, Params, node


class StereoVideoParams(Params):
    fps: float = Field(
        30.0, gt=0, le=1000, description="Frame rate written into the files, frames per second."
    )
    codec: Literal[LOSSLESS] = Field(
        "RGBA",
        description="Lossless codec (FourCC): frames read back are identical. "
        "RGBA (uncompressed) decodes a 640x480 frame in <1 ms, ~10x "
        "faster than HFYU (HuffYUV) and ~50x faster than FFV1, for "
        "files ~2.6x / ~3x larger (benchmarks/bench_codecs.py).",
    )
    container: Literal["avi", "mkv"] = Field("avi", description="File format.")
    split: Literal["all", "train", "test"] = Field(
        "all", description="Record only the pairs of this split."
    )
    ids: list[str] | None = Field(
        None, description="Record these pair ids, in this order (default: all, in order)."
    )


@node(
    "recorder.stereo_video",
    params=StereoVideoParams,
    version="1",
    inputs={"pairs": In("StereoPair", gather=True, description="The pairs to record, in order.")},
    outputs={
        "recording": Out(
            "StereoRecording", description="Two lossless video files and each frame's truth."
        )
    },
)
def stereo_video(params: StereoVideoParams, pairs) -> dict:
    """Record stereo pairs as two lossless videos (uncompressed RGBA, HuffYUV or FFV1), playable by
    source.camera."""
    order = params.ids if params.ids is not None else list(pairs)
    missing = [i for i in order if i not in pairs]
    if missing:
        raise NodeError(
            f"recorder.stereo_video: no pair {missing[0]!r} to record ({len(pairs)} pairs: "
            f"{', '.join(list(pairs)[:5])}{', ...' if len(pairs) > 5 else ''}).",
            hint="list ids the source produces, or leave ids empty",
        )
    chosen = [
        pairs[i] for i in order if params.split == "all" or pairs[i].get("split") == params.split
    ]
    if not chosen:
        raise NodeError(
            f"recorder.stereo_video: no pair of split {params.split!r} to record.",
            hint="set split: all",
        )
    return {"recording": encode_recording(chosen, params.fps, params.codec, params.container)}
