"""``source.camera``: stereo pairs grabbed from anything ``cv2.VideoCapture`` opens; never cached.

Each side is a device index (``0``), a video file (``left.avi``), an image-sequence pattern
(``left_%03d.png``), a stream URL (``rtsp://...``) or a GStreamer pipeline string; or one stereo
device that delivers side-by-side frames (``right: null``). Files go through the same code path as
devices, which is what makes the node testable: the tests record the synthetic rig with
``cv2.VideoWriter`` and read it back here.

Keeping a pair close in time: both sides are ``grab()``-bed first (cheap: the frame stays in the
driver) and only then ``retrieve()``-d (decoding), so the two exposures are as close as the
devices allow. Each frame's timestamp is recorded and the pair's left/right *skew* measured on one
of two clocks:

- ``stream``: the time code each stream gives its frame (``CAP_PROP_POS_MSEC``). For recordings
  this is the only meaningful clock (a file is read as fast as it decodes); two recordings whose
  time codes disagree — different frame rates — show it here. A frame dropped in one recording does
  not: OpenCV gives a file's frame the time code index / frame rate, so both sides keep equal time
  codes while every later pair is one frame apart. Two recordings of different lengths are said when
  they open (the one sign of it). In a shifted pair the segmenter's left/right checks can catch a
  ball that moved up or down between the two frames (off the epipolar line); one that moved sideways
  only changes the disparity, and so the depth, unseen.
- ``host``: when each ``grab()`` returned on this computer's monotonic clock. For live devices,
  whose stream time bases are unrelated to each other.

A pair whose skew exceeds ``max_skew_ms`` is dropped and the next one grabbed (``skew_retries``
times); then the node fails with the figures. Inside a ``stereograph run --repeat`` loop the
devices stay open from one cycle to the next (``ctx.resource``), so a recording plays on and a
camera does not warm up again.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Literal, NoReturn

import cv2
from pydantic import model_validator

from nodes.contracts.recording import write_recording
from stereograph.api import Field, In, NodeError, Out, Params, node

__all__ = ["CameraParams", "StereoCapture", "camera", "grab_pairs"]

BACKENDS = {
    "any": cv2.CAP_ANY,
    "ffmpeg": cv2.CAP_FFMPEG,
    "gstreamer": cv2.CAP_GSTREAMER,
    "v4l2": cv2.CAP_V4L2,
    "dshow": cv2.CAP_DSHOW,
    "msmf": cv2.CAP_MSMF,
    "avfoundation": cv2.CAP_AVFOUNDATION,
    "images": cv2.CAP_IMAGES,
}


MAX_DEVICE_INDEX = 255


class CameraParams(Params):
    left: int | str = Field(
        0,
        description="Left camera: a device index, a video file, an image-sequence pattern "
        "(left_%03d.png), a stream URL or a GStreamer pipeline (ending in "
        "appsink). Paths are relative to the pipeline file.",
    )
    right: int | str | None = Field(
        1,
        description="Right camera, as `left`; null: `left` is one stereo device "
        "delivering side-by-side frames (left image in the left half).",
    )
    backend: Literal[tuple(BACKENDS)] = Field(
        "any", description="cv2.VideoCapture backend (any: OpenCV chooses)."
    )
    width_px: int | None = Field(
        None,
        ge=16,
        description="Requested frame width, pixels (side-by-side: the whole "
        "frame; default: the camera's).",
    )
    height_px: int | None = Field(None, ge=16, description="Requested frame height, pixels.")
    n_frames: int = Field(
        1, ge=1, le=10000, description="Pairs to grab per run (per cycle of --repeat), count."
    )
    interval_s: float = Field(0.0, ge=0, description="Pause between pairs, seconds.")
    warmup_frames: int | None = Field(
        None,
        ge=0,
        le=100,
        description="Frames dropped after opening while exposure "
        "settles (count); default 5 for devices and "
        "streams, 0 for files.",
    )
    stream_timeout_s: float = Field(
        10.0,
        gt=0,
        le=600,
        description="A stream (URL) that does not open, or "
        "delivers no frame, within this many seconds is refused (s).",
    )
    max_skew_ms: float = Field(
        20.0, gt=0, description="Largest left/right time difference of a pair, ms."
    )
    skew_clock: Literal["auto", "stream", "host"] = Field(
        "auto",
        description="Clock the skew is measured on: stream = the streams' own time codes "
        "(CAP_PROP_POS_MSEC), "
        "host = when each grab() returned; auto = stream for files, host otherwise.",
    )
    skew_retries: int = Field(
        2, ge=0, le=100, description="Skewed pairs dropped before the node fails (count)."
    )
    use_recording: bool = Field(
        True,
        description="Play the wired `recording` input, if any; false: open left/right "
        "(real cameras in a pipeline that ships a recording).",
    )
    at_end: Literal["fail", "rewind"] = Field(
        "fail",
        description="When a file ends: fail (the loop stops, saying "
        "so) or rewind both sides to the first frame.",
    )

    @model_validator(mode="after")
    def _check_sides(self):
        # Checked here so `stereograph validate` reports it (exit 2) before any camera is opened.
        if self.left == self.right:
            raise ValueError(
                f"left and right are both {self.left!r}; give the two cameras' different sources "
                "(or right: null for one side-by-side stereo device)"
            )
        for side, src in (("left", self.left), ("right", self.right)):
            # (OpenCV takes -1 as 'any camera' and its V4L2 backend can crash on it: refused before
            # it is called)
            if isinstance(src, int) and not 0 <= src <= MAX_DEVICE_INDEX:
                raise ValueError(
                    f"{side} is {src}: a device index is 0 to {MAX_DEVICE_INDEX} (/dev/video<n>)"
                )
        return self


def _check_before_opening(src: int | str, which: str, field: str) -> None:
    """Refuse what OpenCV would crash or hang on, before it is called: a device index with no device
    (Linux: no /dev/video<n>), a path that is a FIFO, socket or folder (a FIFO blocks the open
    forever, deaf to Ctrl-C)."""
    if isinstance(src, int):
        if sys.platform.startswith("linux") and not Path(f"/dev/video{src}").exists():
            raise NodeError(
                f"source.camera: no {which} camera at device index {src} (/dev/video{src} does not "
                "exist).",
                hint=f"plug the camera in or set {field} to an existing device (ls "
                "/dev/video*), a video file or an image-sequence pattern",
            )
        return
    if _is_file(src) and "%" not in src and Path(src).exists() and not Path(src).is_file():
        raise NodeError(
            f"source.camera: the {which} source {src!r} is a folder, FIFO or socket, not "
            "a video file.",
            hint=f"set {field} to a video file, an image pattern such as {field}_%03d.png, a "
            "device "
            "index or a stream URL",
        )


def _is_file(src: int | str) -> bool:
    """A recording (file or image sequence) rather than a device (index or /dev/ path), URL or
    pipeline."""
    if isinstance(src, int) or "://" in src or "!" in src or src.startswith("/dev/"):
        return False
    return True


def _resolve(src: int | str, base: Path | None) -> int | str:
    if isinstance(src, str) and src.strip().isdigit():
        return int(src)
    if (
        isinstance(src, str)
        and _is_file(src)
        and base is not None
        and not Path(src).expanduser().is_absolute()
    ):
        return str(base / src)
    return src


class StereoCapture:
    """Two ``cv2.VideoCapture`` (or one side-by-side device) delivering time-stamped pairs.

    Parameters
    ----------
    p : CameraParams
    base : Path or None
        Folder relative file paths are resolved from.
    truth : list or None
        Ground truth per frame index (a recording made from the synthetic rig), attached to each
        pair.
    ids : list of str or None
        Pair ids per frame index (default ``cam00000``...).
    """

    def __init__(
        self,
        p: CameraParams,
        base: Path | None = None,
        truth: list | None = None,
        ids: list[str] | None = None,
    ):
        self.p, self.truth, self.ids = p, truth, ids
        self.sources = [_resolve(p.left, base)] + (
            [] if p.right is None else [_resolve(p.right, base)]
        )
        self.files = all(_is_file(s) for s in self.sources)
        self.clock = (
            p.skew_clock if p.skew_clock != "auto" else ("stream" if self.files else "host")
        )
        self.caps: list[cv2.VideoCapture] = []
        self.frame = -1  # index of the last frame grabbed from each side
        self.lap = 0  # times a recording was rewound (keeps pair ids unique)
        self.notes: list[str] = []  # said once, then taken by the node (ctx.warn)
        self.tmp: tempfile.TemporaryDirectory | None = None  # a recording's folder outside a run
        try:
            for which, src in zip(("left", "right"), self.sources):
                self.caps.append(self._open(src, which if p.right is not None else "stereo"))
            self._compare_lengths()
            warm = p.warmup_frames if p.warmup_frames is not None else (0 if self.files else 5)
            for _ in range(warm):
                self._grab()
        except BaseException:
            self.close()
            raise

    def _compare_lengths(self) -> None:
        """Say when two recordings differ in length: the one sign of a frame dropped in one of them.
        OpenCV gives a file's frame the time code index / frame rate, so the skew check cannot see a
        dropped frame: every later pair holds a left and a right image one frame apart, with equal
        time codes."""
        if not self.files or len(self.caps) != 2:
            return
        n = [int(c.get(cv2.CAP_PROP_FRAME_COUNT)) for c in self.caps]
        if min(n) > 0 and n[0] != n[1]:  # (0 or -1: a count the backend does not know)
            self.notes.append(
                f"the left recording has {n[0]} frames, the right {n[1]}: a frame dropped "
                "in one of "
                "them (or a late start) pairs every later image with another moment's, which the "
                "stream time codes cannot show (OpenCV computes them from the frame "
                "index and rate); "
                "check the recordings, or record both sides together and trim them to one length"
            )

    def _open(self, src: int | str, which: str) -> cv2.VideoCapture:
        _check_before_opening(src, which, "left" if which in ("left", "stereo") else "right")
        stream = isinstance(src, str) and "://" in src
        if stream:  # (OpenCV's own default waits 30 s to open, deaf to Ctrl-C meanwhile)
            ms = int(self.p.stream_timeout_s * 1000)
            cap = cv2.VideoCapture(
                src,
                BACKENDS[self.p.backend],
                [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms],
            )
        else:
            cap = cv2.VideoCapture(src, BACKENDS[self.p.backend])
        if not cap.isOpened():
            cap.release()
            self._refuse_unopened(src, which, stream)
        if (self.p.width_px or self.p.height_px) and _is_file(src) and which != "right":
            self.notes.append(
                "width_px / height_px set the resolution of a camera; a video file or "
                "image sequence "
                "keeps its own size"
            )
        if self.p.width_px:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.p.width_px)
        if self.p.height_px:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.p.height_px)
        return cap

    def _refuse_unopened(self, src: int | str, which: str, stream: bool) -> NoReturn:
        """Why ``src`` did not open, in the words of what it is: a device, a stream, a file."""
        field = "left" if which in ("left", "stereo") else "right"
        if isinstance(src, int):
            raise NodeError(
                f"source.camera: no {which} camera at device index {src} "
                "(cv2.VideoCapture could not "
                "open it).",
                hint=f"plug the camera in or set {field} to an existing device "
                "(ls /dev/video*), a video file or an image-sequence pattern",
            )
        if stream:
            raise NodeError(
                f"source.camera: the {which} stream {src!r} did not open within "
                f"{self.p.stream_timeout_s:g} s (nothing answered, or not a video stream).",
                hint="check the camera's URL and that it streams (open it in a player); raise "
                "stream_timeout_s for a slow network",
            )
        plain = _is_file(src) and "%" not in src
        missing = plain and not Path(src).exists()
        empty = plain and not missing and Path(src).is_file() and Path(src).stat().st_size == 0
        why = (
            " (no such file)."
            if missing
            else " (the file is empty: 0 bytes)."
            if empty
            else f" with backend {self.p.backend}"
            + (
                ": the file is not a video it can read (corrupt, or a "
                "codec this OpenCV build lacks)."
                if plain
                else "."
            )
        )
        raise NodeError(
            f"source.camera: cv2.VideoCapture could not open the {which} source {src!r}{why}",
            hint=f"set {field} to an existing video file, an image pattern such as "
            f"{field}_%03d.png, "
            "a stream URL or a GStreamer pipeline ending in appsink; check the codec is one "
            "OpenCV's build reads (cv2.getBuildInformation())",
        )

    def _grab(self) -> list[float]:
        """``grab()`` every side back to back; host times (s) when each returned. Rewinds files on
        request."""
        times, ok = [], []
        for c in self.caps:
            ok.append(c.grab())
            times.append(time.monotonic())
        if not all(ok) and self.files and self.p.at_end == "rewind" and self.frame >= 0:
            if any(ok) and self.lap == 0:  # one side went on: its later frames are never played
                ended = [w for w, g in zip(("left", "right"), ok) if not g]
                self.notes.append(
                    f"the {ended[0]} recording ended after {self.frame + 1} frames while "
                    "the other goes "
                    "on: both rewind there, so the longer one's later frames are never "
                    "used (record "
                    "both sides together, or trim them to one length)"
                )
            for c in self.caps:
                c.set(cv2.CAP_PROP_POS_FRAMES, 0)
            self.frame = -1
            self.lap += 1
            return self._grab()
        if not all(ok):
            sides = [
                w
                for w, g in zip(("left", "right") if len(self.caps) == 2 else ("stereo",), ok)
                if not g
            ]
            if self.files:
                raise NodeError(
                    f"source.camera: the {' and '.join(sides)} recording ended after "
                    f"{self.frame + 1} "
                    "frames.",
                    hint="set at_end: rewind to play it again, or record more frames",
                )
            raise NodeError(
                f"source.camera: the {' and '.join(sides)} camera stopped delivering frames (frame "
                f"{self.frame + 1}).",
                hint="check the cable/USB bandwidth; two cameras on one hub may "
                "need a lower resolution or frame rate",
            )
        self.frame += 1
        return times

    def read_pair(self) -> dict[str, Any]:
        """The next pair whose skew is within ``max_skew_ms`` (StereoPair plus timing keys)."""
        p = self.p
        for attempt in range(p.skew_retries + 1):
            host = self._grab()
            frames = self._retrieve()
            stream = [c.get(cv2.CAP_PROP_POS_MSEC) for c in self.caps]
            if len(frames) == 1:  # one side-by-side device: one exposure, no skew
                f = frames[0]
                half = f.shape[1] // 2
                frames, skew, stream = (
                    [f[:, :half].copy(), f[:, half : 2 * half].copy()],
                    0.0,
                    stream * 2,
                )
                host = host * 2
            elif self.clock == "stream":
                skew = abs(stream[0] - stream[1])
            else:
                skew = abs(host[0] - host[1]) * 1000.0
            if skew <= p.max_skew_ms:
                break
            if attempt == p.skew_retries:
                self._refuse_skew(skew, stream)
        k = self.frame
        pid = (self.ids[k] if self.ids and k < len(self.ids) else f"cam{k:05d}") + (
            f"@{self.lap}" if self.lap else ""
        )
        truth = self.truth[k] if self.truth and k < len(self.truth) else None
        return {
            "id": pid,
            "left": frames[0],
            "right": frames[1],
            "truth": truth,
            "split": "test",
            "frame": k,
            "timestamp_s": time.time(),
            "left_ms": round(float(stream[0]), 3),
            "right_ms": round(float(stream[1]), 3),
            "skew_ms": round(float(skew), 3),
            "skew_clock": self.clock,
            "grab_monotonic_s": host[0],
        }

    def _retrieve(self) -> list[Any]:
        """The grabbed frame of each capture, decoded."""
        frames = []
        for c in self.caps:
            ok, f = c.retrieve()
            if not ok or f is None:
                raise NodeError(
                    f"source.camera: frame {self.frame} was grabbed but could not be decoded.",
                    hint="check the video codec / camera pixel format (backend, width_px, "
                    "height_px)",
                )
            frames.append(f)
        return frames

    def _refuse_skew(self, skew: float, stream: list[float]) -> NoReturn:
        """Left and right stayed too far apart in time for every pair tried."""
        p = self.p
        clock = (
            f"stream time codes {stream[0]:.1f} / {stream[1]:.1f} ms"
            if self.clock == "stream"
            else "grab() calls on this computer"
        )
        raise NodeError(
            f"source.camera: refusing frame {self.frame}: left and right are "
            f"{skew:.1f} ms apart ({clock}), "
            f"more than max_skew_ms {p.max_skew_ms:g} ms ({p.skew_retries + 1} "
            "pair(s) tried).",
            hint="recordings: the two files must have the same frame rate and start "
            "(re-record or trim them); "
            "cameras: use synchronised cameras, a lower resolution or frame "
            "rate, or raise max_skew_ms",
        )

    def close(self) -> None:
        for c in self.caps:
            c.release()
        self.caps = []
        if self.tmp is not None:
            self.tmp.cleanup()
            self.tmp = None


def grab_pairs(p: CameraParams, cap: StereoCapture) -> dict:
    """Grab ``n_frames`` pairs from an open :class:`StereoCapture`; ``{pair_id: StereoPair}``."""
    out = {}
    for k in range(p.n_frames):
        pair = cap.read_pair()
        out[pair["id"]] = pair
        if p.interval_s and k + 1 < p.n_frames:
            time.sleep(p.interval_s)
    return out


@node(
    "source.camera",
    inputs={
        "recording": In(
            "StereoRecording",
            optional=True,
            description="Play this recording (written into the run folder) instead of left/right.",
        )
    },
    outputs={
        "pairs": Out(
            "StereoPair", collection=True, description="Stereo pairs with timestamps and skew."
        )
    },
    params=CameraParams,
    version="2",
    cacheable=False,
)
def camera(params: CameraParams, recording=None, ctx=None) -> dict:
    """Grab stereo pairs from two cameras, a side-by-side stereo camera, video files or image
    sequences."""
    base = ctx.pipeline_dir if ctx is not None else None

    def open_capture() -> StereoCapture:
        if recording is None or not params.use_recording:
            return StereoCapture(params, base)
        # into the run folder; called outside a run, into a temporary folder removed on close
        tmp = None if ctx is not None else tempfile.TemporaryDirectory(prefix="stereograph-camera-")
        folder = (ctx.out_dir if ctx is not None else Path(tmp.name)) / "recording"
        left, right = write_recording(recording, folder)
        p = params.model_copy(update={"left": str(left), "right": str(right)})
        cap = StereoCapture(p, None, truth=recording.get("truth"), ids=recording.get("ids"))
        cap.tmp = tmp
        return cap

    cap = ctx.resource("capture", open_capture) if ctx is not None else None
    if cap is not None:
        pairs = grab_pairs(params, cap)
        while cap.notes:
            ctx.warn(cap.notes.pop(0))
        return {"pairs": pairs}
    cap = open_capture()
    try:
        return {"pairs": grab_pairs(params, cap)}
    finally:
        cap.close()
