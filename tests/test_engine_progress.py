"""Progress everywhere (issue 14 item 2): per-item counts with an ETA, plain lines in a pipe."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stereograph.app.progress import PlainProgress, RichProgress, eta_seconds

ROOT = Path(__file__).resolve().parents[1]


def test_eta_is_the_mean_rate_so_far():
    assert eta_seconds(30, 120, 15.0) == 45.0
    assert eta_seconds(0, 120, 15.0) is None  # nothing done yet: no rate to extrapolate
    assert eta_seconds(120, 120, 15.0) is None


def test_plain_progress_prints_counts_eta_and_no_ansi():
    out = io.StringIO()
    prog = PlainProgress(out, interval_s=0.0)  # every report gives a line
    prog.node_started("rig", 1)
    prog.item_progress("rig", 0, 120, "scenes")
    time.sleep(0.05)
    prog.item_progress("rig", 37, 120, "scenes")
    prog.advance("rig")
    prog.node_started("segment", 3)
    prog.advance("segment")
    prog.advance("segment")
    prog.advance("segment")
    text = out.getvalue()
    assert "rig: started" in text and "rig 37/120 scenes" in text and "ETA" in text
    assert "segment 1/3 items" in text and "segment: finished (3/3 items" in text
    assert "\x1b" not in text


def test_plain_progress_heartbeat_names_a_silent_running_node():
    out = io.StringIO()
    with PlainProgress(out, interval_s=0.1) as prog:
        prog.node_started("calib", 1)
        time.sleep(0.6)  # the node reports nothing: the heartbeat still says it runs
        prog.advance("calib")
    lines = out.getvalue().splitlines()
    assert sum(1 for ln in lines if ln.startswith("calib,") and "elapsed" in ln) >= 2, lines
    assert lines[-1].startswith("calib: finished")


def test_rich_progress_takes_the_node_count_and_back():
    from rich.console import Console

    prog = RichProgress(Console(file=io.StringIO(), force_terminal=True, width=120))
    with prog:
        prog.node_started("rig", 1)
        prog.item_progress("rig", 10, 120, "scenes")
        prog.item_progress("rig", 3, 16, "views")  # a second phase restarts the count
        task = prog.p.tasks[0]
        assert (task.completed, task.total, task.fields["unit"]) == (3, 16, "views")
        prog.advance("rig")
        assert prog.p.tasks[0].completed == 1 and prog.p.tasks[0].total == 1


@pytest.mark.slow
def test_a_piped_run_prints_progress_lines_while_it_runs(tmp_path):
    """`stereograph run pipelines/locate.yaml > log.txt`: lines arrive before the run ends."""
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(ROOT / "pipelines" / "locate.yaml"),
        "--only",
        "rig",
        "--set",
        "rig.n_scenes=12",
        "--set",
        "rig.n_views=2",
        "--no-cache",
        "--progress-interval",
        "0.2",
        "--out",
        str(tmp_path / "out"),
    ]
    # a terminal type, yet stdout is a pipe: still plain lines
    env = {**os.environ, "TERM": "xterm-256color"}
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env
    )
    first_progress_while_running = None
    lines = []
    for line in proc.stdout:
        lines.append(line.rstrip("\n"))
        if first_progress_while_running is None and (" scenes" in line or " items" in line):
            first_progress_while_running = proc.poll() is None
    proc.wait(timeout=300)
    err = proc.stderr.read()
    assert proc.returncode == 0, err
    text = "\n".join(lines)
    assert "rig: started" in text and "rig: finished" in text, text
    # the pairs are rendered one per call (items=): 12 items, counted as 12 (the whole part, the
    # views, was counted as a 13th: "scenes: started (14 items)" where the table said 13)
    assert any(
        ln.startswith("rig ") and ("/12 scenes" in ln or "/12 items" in ln) for ln in lines
    ), text
    assert (
        "rig: started (12 items)" in text
        and "rig: finished (12/12 items" in text
        and "/13 items" not in text
    )
    assert first_progress_while_running, "progress lines came only after the run had ended"
    assert "\x1b" not in text + err


def test_plain_progress_ending_lines_say_failed_and_interrupted():
    """A node that failed, or whose items partly failed, or a run stopped by Ctrl-C, does not end on
    'finished' in a log."""
    out = io.StringIO()
    prog = PlainProgress(out, interval_s=60)
    prog.node_started("calib", 1)
    prog.item_failed("calib")
    prog.advance("calib")
    prog.node_started("segment", 3)
    for ok in (True, False, True):
        if not ok:
            prog.item_failed("segment")
        prog.advance("segment")
    try:
        with prog:
            prog.node_started("locate", 3)
            prog.advance("locate")
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    lines = out.getvalue().splitlines()
    assert any(ln.startswith("calib: failed (") for ln in lines), lines
    assert any(ln.startswith("segment: finished (3/3 items, 1 failed,") for ln in lines), lines
    assert lines[-1].startswith("locate: interrupted (1/3 items"), lines


@pytest.mark.slow
def test_a_failed_node_ends_on_failed_in_a_piped_run(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(ROOT / "pipelines" / "locate.yaml"),
        "--only",
        "calib",
        "--set",
        "rig.n_scenes=2",
        "--set",
        "rig.n_views=8",
        "--set",
        "calib.max_rms_px=0.001",
        "--no-cache",
        "--out",
        str(tmp_path / "out"),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stdout.splitlines()
    assert any(ln.startswith("calib: failed (") for ln in lines), proc.stdout
    assert not any(ln.startswith("calib: finished") for ln in lines), proc.stdout
    # the summary's note is cut after a whole word, marked '…' (the whole error follows the table)
    assert "…" in proc.stdout and "max_rms_px" in proc.stderr, proc.stdout


def test_clip_cuts_after_a_whole_word():
    from stereograph.app.run_summary import clip as _clip

    text = "the views do not fit one pair of cameras; worst views v03 (0.07 px), v00 (0.07 px)"
    assert _clip(text, 200) == text
    short = _clip(text, 40)
    assert len(short) <= 40 and short.endswith("…") and text.startswith(short[:-1])
    assert text[len(short) - 1] in " ,;(", short  # cut at a word's end, not inside one


def test_progress_interval_must_be_a_positive_number_of_seconds(capsys):
    # (0 or a negative interval printed a progress line per millisecond: 560 000 lines for a 7-pair
    # run)
    from stereograph.app.cli import main

    pipeline = str(Path(__file__).resolve().parents[1] / "pipelines" / "locate.yaml")
    for bad in ("0", "-1", "nan", "inf", "soon"):
        assert main(["run", pipeline, "--progress-interval", bad]) == 2
        err = capsys.readouterr().err
        assert "--progress-interval" in err and "Traceback" not in err, err
