"""source.camera on files written by cv2.VideoWriter from the synthetic rig: the same code path as a
device."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from nodes.contracts.recording import write_video
from nodes.recorders.stereo_video import StereoVideoParams, stereo_video
from nodes.sources.camera import CameraParams, camera
from nodes.sources.synthetic import SyntheticParams, synthetic
from stereograph.core.api import NodeError, RunContext
from stereograph.core.calls import close_resources


@pytest.fixture(scope="module")
def scenes():
    """Four small synthetic scenes (320x240), rendered once."""
    out = synthetic(
        SyntheticParams(
            n_scenes=4,
            n_views=0,
            image_width_px=320,
            image_height_px=240,
            focal_length_px=280.0,
            seed=5,
        )
    )["pairs"]
    return list(out.values())


def _record(folder, scenes, fps_left=30.0, fps_right=30.0, codec="FFV1"):
    left, right = folder / "left.avi", folder / "right.avi"
    write_video((s["left"] for s in scenes), left, fps_left, codec)
    write_video((s["right"] for s in scenes), right, fps_right, codec)
    return left, right


@pytest.mark.parametrize("codec", ["FFV1", "HFYU", "RGBA"])
def test_video_files_give_exactly_the_frames_written(tmp_path, scenes, codec):
    left, right = _record(tmp_path, scenes, codec=codec)
    pairs = camera(CameraParams(left=str(left), right=str(right), n_frames=4))["pairs"]
    assert list(pairs) == ["cam00000", "cam00001", "cam00002", "cam00003"]
    for pair, s in zip(pairs.values(), scenes):
        assert np.array_equal(pair["left"], s["left"]) and np.array_equal(pair["right"], s["right"])
        assert pair["skew_clock"] == "stream" and pair["skew_ms"] == 0.0
    assert [p["left_ms"] for p in pairs.values()] == pytest.approx(
        [0, 1000 / 30, 2000 / 30, 3000 / 30], abs=0.01
    )


def test_image_sequence_pattern_and_relative_paths(tmp_path, scenes):
    for k, s in enumerate(scenes):
        cv2.imwrite(str(tmp_path / f"left_{k:03d}.png"), s["left"])
        cv2.imwrite(str(tmp_path / f"right_{k:03d}.png"), s["right"])
    # paths resolve from the pipeline's folder
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path)
    pairs = camera(CameraParams(left="left_%03d.png", right="right_%03d.png", n_frames=4), ctx=ctx)[
        "pairs"
    ]
    assert all(
        np.array_equal(p["left"], s["left"]) and np.array_equal(p["right"], s["right"])
        for p, s in zip(pairs.values(), scenes)
    )


def test_side_by_side_stereo_device(tmp_path, scenes):
    path = tmp_path / "sbs.avi"
    write_video((np.hstack([s["left"], s["right"]]) for s in scenes), path, 30.0)
    pairs = camera(CameraParams(left=str(path), right=None, n_frames=2))["pairs"]
    for p, s in zip(pairs.values(), scenes):
        assert np.array_equal(p["left"], s["left"]) and np.array_equal(p["right"], s["right"])
        assert p["skew_ms"] == 0.0


def test_skew_check_refuses_a_shifted_stream(tmp_path, scenes):
    # The right recording runs at 20 fps against the left's 30: frame 1 is 50 ms into the right
    # stream but 33 ms into the left one, and the gap grows by 17 ms a frame.
    left, right = _record(tmp_path, scenes, 30.0, 20.0)
    p = CameraParams(left=str(left), right=str(right), n_frames=2, max_skew_ms=10.0, skew_retries=1)
    with pytest.raises(
        NodeError, match=r"refusing frame 2: left and right are 33\.3 ms apart"
    ) as e:
        camera(p)
    assert (
        "stream time codes 66.7 / 100.0 ms" in e.value.message
        and "max_skew_ms 10 ms" in e.value.message
    )
    # within the limit, the same streams pass and say how far apart they are
    pairs = camera(p.model_copy(update={"max_skew_ms": 40.0}))["pairs"]
    assert [round(x["skew_ms"], 1) for x in pairs.values()] == [0.0, 16.7]


def test_the_capture_stays_open_across_cycles_and_ends_clearly(tmp_path, scenes):
    left, right = _record(tmp_path, scenes[:2])
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path, resources={})
    p = CameraParams(left=str(left), right=str(right))
    first = camera(p, ctx=ctx)["pairs"]
    second = camera(p, ctx=ctx)["pairs"]  # the next cycle reads the next frame
    assert list(first) == ["cam00000"] and list(second) == ["cam00001"]
    with pytest.raises(NodeError, match="recording ended after 2 frames") as e:
        camera(p, ctx=ctx)
    assert "at_end: rewind" in e.value.hint
    close_resources(ctx.resources)
    assert ctx.resources == {}
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path, resources={})
    rewind = p.model_copy(update={"at_end": "rewind", "n_frames": 3})
    got = camera(rewind, ctx=ctx)["pairs"]
    assert list(got) == ["cam00000", "cam00001", "cam00000@1"]  # the third pair is the first again
    assert np.array_equal(got["cam00000@1"]["left"], scenes[0]["left"])
    close_resources(ctx.resources)


def test_a_recording_plays_with_its_truth(tmp_path, scenes):
    pairs = {s["id"]: s for s in scenes}
    rec = stereo_video(StereoVideoParams(ids=[scenes[2]["id"], scenes[0]["id"]]), pairs=pairs)[
        "recording"
    ]
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path, resources={})
    got = camera(CameraParams(n_frames=2), recording=rec, ctx=ctx)["pairs"]
    assert list(got) == [scenes[2]["id"], scenes[0]["id"]]
    for g, s in zip(got.values(), (scenes[2], scenes[0])):
        assert np.array_equal(g["left"], s["left"])
        assert g["truth"]["center_left_cm"] == pytest.approx(s["truth"]["center_left_cm"])
    assert (tmp_path / "out" / "recording" / "left.avi").exists()
    close_resources(ctx.resources)
    # outside a run: a temporary folder, removed when the capture closes (nothing in the working
    # folder)
    cwd, here = os.getcwd(), tmp_path / "cwd"
    here.mkdir()
    os.chdir(here)
    try:
        assert list(camera(CameraParams(), recording=rec)["pairs"]) == [scenes[2]["id"]]
    finally:
        os.chdir(cwd)
    assert list(here.iterdir()) == []


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(
        NodeError, match=r"could not open the left source .*nope\.avi' \(no such file\)"
    ):
        camera(CameraParams(left=str(tmp_path / "nope.avi"), right=str(tmp_path / "nope2.avi")))


def test_what_counts_as_a_recording():
    from nodes.sources.camera import _is_file

    assert _is_file("left.avi") and _is_file("rec/left_%03d.png")
    assert not any(
        _is_file(s) for s in (0, "/dev/video2", "rtsp://cam/1", "v4l2src ! videoconvert ! appsink")
    )


def test_recordings_of_different_lengths_are_said_when_they_rewind(tmp_path, scenes):
    # (a 4-frame left and a 2-frame right both rewound after 2 frames: the left's last two, silently
    # unused)
    left, right = tmp_path / "left.avi", tmp_path / "right.avi"
    write_video((s["left"] for s in scenes), left, 30.0, "FFV1")
    write_video((s["right"] for s in scenes[:2]), right, 30.0, "FFV1")
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path, resources={})
    p = CameraParams(left=str(left), right=str(right), at_end="rewind", n_frames=3)
    assert list(camera(p, ctx=ctx)["pairs"]) == ["cam00000", "cam00001", "cam00000@1"]
    assert any(
        "the right recording ended after 2 frames while the other goes on" in m
        for m in ctx.messages
    )
    close_resources(ctx.resources)
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path, resources={})
    # (silently ignored on files)
    camera(p.model_copy(update={"width_px": 1280, "height_px": 960}), ctx=ctx)
    assert any("a video file or image sequence keeps its own size" in m for m in ctx.messages)
    close_resources(ctx.resources)


def test_an_empty_or_corrupt_video_file_is_named_as_such(tmp_path):
    # (both said "could not open ... with backend any")
    (tmp_path / "empty.avi").write_bytes(b"")
    (tmp_path / "junk.avi").write_text("not a video")
    with pytest.raises(NodeError, match=r"the file is empty: 0 bytes"):
        camera(CameraParams(left=str(tmp_path / "empty.avi"), right=None))
    with pytest.raises(NodeError, match=r"not a video it can read"):
        camera(CameraParams(left=str(tmp_path / "junk.avi"), right=None))


def test_a_dropped_frame_is_invisible_to_the_skew_check_but_the_lengths_are_said(tmp_path, scenes):
    # (docs/live.md said a dropped frame "shows" in the skew: OpenCV's time codes are index / fps,
    # so it does not -- pair 1 below holds left frame 1 and right frame 2 with skew 0; the lengths
    # differ)
    left, right = tmp_path / "left.avi", tmp_path / "right.avi"
    write_video((s["left"] for s in scenes), left, 30.0, "FFV1")
    # frame 1 dropped
    write_video((s["right"] for k, s in enumerate(scenes) if k != 1), right, 30.0, "FFV1")
    ctx = RunContext("cam", None, tmp_path / "out", tmp_path, resources={})
    pairs = camera(
        CameraParams(left=str(left), right=str(right), n_frames=2, max_skew_ms=1.0), ctx=ctx
    )["pairs"]
    second = pairs["cam00001"]
    # shifted, unseen
    assert second["skew_ms"] == 0.0 and np.array_equal(second["right"], scenes[2]["right"])
    assert any(
        "the left recording has 4 frames, the right 3: a frame dropped in one of them" in m
        for m in ctx.messages
    ), ctx.messages
    close_resources(ctx.resources)
