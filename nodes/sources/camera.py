"""``source.camera``: stereo pairs grabbed live from two cameras (``cv2.VideoCapture``); never cached."""

from __future__ import annotations

import time

import cv2
from pydantic import model_validator

from stereograph.api import Field, NodeError, Out, Params, node

__all__ = ["CameraParams", "camera", "grab_pairs"]


class CameraParams(Params):
    left_index: int = Field(0, ge=0, description="Device index of the left camera (integer).")
    right_index: int = Field(1, ge=0, description="Device index of the right camera (integer).")
    width_px: int | None = Field(None, ge=16, description="Requested frame width, pixels (default: the camera's).")
    height_px: int | None = Field(None, ge=16, description="Requested frame height, pixels.")
    n_frames: int = Field(1, ge=1, le=10000, description="Pairs to grab (count).")
    interval_s: float = Field(0.0, ge=0, description="Pause between pairs, seconds.")
    warmup_frames: int = Field(5, ge=0, le=100, description="Frames dropped first while exposure settles (count).")

    @model_validator(mode="after")
    def _check_indices(self):
        # Checked here so `stereograph validate` reports it (exit 2) before any camera is opened.
        if self.left_index == self.right_index:
            raise ValueError(f"left_index and right_index are both {self.left_index}; give the two cameras' "
                             "different device indices")
        return self


def _open(index: int, which: str, p: CameraParams) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(index)
    if not cap.isOpened():
        cap.release()
        raise NodeError(f"source.camera: no {which} camera at device index {index} (cv2.VideoCapture could not open "
                        "it).", hint=f"plug the camera in or set {which}_index to an existing device "
                                     "(ls /dev/video*); use source.files for recorded images")
    if p.width_px:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, p.width_px)
    if p.height_px:
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, p.height_px)
    return cap


def grab_pairs(p: CameraParams) -> dict:
    """Grab ``n_frames`` stereo pairs. ``grab`` both devices first, then ``retrieve``, to keep them close in time."""
    caps = []
    try:
        caps.append(_open(p.left_index, "left", p))
        caps.append(_open(p.right_index, "right", p))
        for _ in range(p.warmup_frames):
            for c in caps:
                c.grab()
        out = {}
        for k in range(p.n_frames):
            ok = [c.grab() for c in caps]
            frames = [c.retrieve()[1] if g else None for c, g in zip(caps, ok)]
            for which, f in zip(("left", "right"), frames):
                if f is None:
                    raise NodeError(f"source.camera: the {which} camera stopped delivering frames (pair {k}).",
                                    hint="check the cable/USB bandwidth; two cameras on one hub may need a lower "
                                         "resolution")
            pid = f"cam{k:04d}"
            out[pid] = {"id": pid, "left": frames[0], "right": frames[1], "truth": None, "split": "test",
                        "timestamp_s": time.time()}
            if p.interval_s and k + 1 < p.n_frames:
                time.sleep(p.interval_s)
        return out
    finally:
        for c in caps:
            c.release()


@node(
    "source.camera",
    outputs={"pairs": Out("StereoPair", collection=True, description="Live stereo pairs.")},
    params=CameraParams,
    version="1",
    cacheable=False,
)
def camera(params: CameraParams) -> dict:
    """Grab stereo pairs from two live cameras (device indices)."""
    return {"pairs": grab_pairs(params)}
