"""report.html / compare.html opened in headless Chromium: every image decodes, the key figures are
there.

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it when it runs as root with apt);
where it is missing the browser tests skip, saying so. The page checks its own images on load
(``img.complete && naturalWidth > 0``) and writes the result into ``#sg-images``, which
``--dump-dom`` returns. Screenshots go to ``$STEREOGRAPH_REPORT_SHOTS`` when set (for a person to
look at), else into the test's temporary folder.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from stereograph.app.cli import main
from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parents[1]
PIPES = ROOT / "pipelines"
CHESS = ROOT.parent / "shared" / "data" / "opencv-stereo-chessboard"


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if shutil.which(name):
            return shutil.which(name)
    return None


CHROMIUM = _chromium()
needs_browser = pytest.mark.skipif(
    CHROMIUM is None,
    reason="headless Chromium not installed (Debian: apt-get install chromium; .ci/run installs it "
    "when it runs as root with apt): report.html is not checked in a browser here",
)


def _shots(tmp_path: Path) -> Path:
    d = Path(os.environ.get("STEREOGRAPH_REPORT_SHOTS") or tmp_path / "shots")
    d.mkdir(parents=True, exist_ok=True)
    return d


def _browser(page: Path, tmp_path: Path, shot: Path, height: int = 3000) -> str:
    """Screenshot ``page`` to ``shot`` and return the DOM after the page's scripts ran."""
    common = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        "--no-first-run",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
        "--virtual-time-budget=15000",
    ]
    shot.unlink(missing_ok=True)  # (the check below reads this launch's screenshot, no older one)
    # one launch does both: the screenshot to its file, the DOM to stdout
    return subprocess.run(
        [*common, f"--window-size=1400,{height}", f"--screenshot={shot}", "--dump-dom"]
        + [page.resolve().as_uri()],
        check=True,
        capture_output=True,
        timeout=180,
        text=True,
    ).stdout


def _check(dom: str, shot: Path, figures: list[str]) -> None:
    m = re.search(
        r'id="sg-images"[^>]*data-ok="(\w+)"[^>]*data-loaded="(\d+)"[^>]*data-total="(\d+)"', dom
    )
    assert m, "the page's image check did not run (no data-ok on #sg-images)"
    ok, loaded, total = m.group(1), int(m.group(2)), int(m.group(3))
    assert ok == "true" and loaded == total, f"{total - loaded} of {total} images did not load"
    for f in figures:
        assert f'data-file="{f}' in dom, f"{f} is not on the page"
    assert shot.stat().st_size > 20_000  # a real render, not a blank page


@pytest.mark.slow
@needs_browser
@pytest.mark.skipif(not CHESS.is_dir(), reason="OpenCV's chessboard pairs not in ../shared/data")
def test_calibration_report_real_pairs(tmp_path):
    res = run_pipeline(
        PIPES / "calibrate.yaml",
        ["rig.type=source.calib_files", f"rig.folder={CHESS}"],
        cache_dir=tmp_path / "cache",
        out_dir=tmp_path / "cal",
    )
    assert res.ok
    shot = _shots(tmp_path) / "calibrate-opencv-pairs.png"
    dom = _browser(res.out_dir / "report.html", tmp_path, shot, 3800)
    _check(
        dom,
        shot,
        [
            "calib_report/reprojection_errors.png",
            "calib_report/corners.png",
            "calib_report/poses.png",
            "rectify/check_image.png",
        ],
    )
    # the RMS is in the check image, drawn, not text
    assert "sg-graph" in dom and "stereo RMS" not in dom
    # `stereograph report` rebuilds the page from run.json alone
    (res.out_dir / "report.html").unlink()
    assert main(["report", str(res.out_dir)]) == 0
    assert "calib_report/corners.png" in (res.out_dir / "report.html").read_text()


@pytest.mark.slow
@needs_browser
def test_locate_hard_report(tmp_path):
    res = run_pipeline(
        PIPES / "locate-hard.yaml",
        ["rig.n_hard_each=1", "rig.n_views=10"],
        cache_dir=tmp_path / "cache",
        out_dir=tmp_path / "hard",
    )
    shot = _shots(tmp_path) / "locate-hard.png"
    dom = _browser(res.out_dir / "report.html", tmp_path, shot)
    _check(dom, shot, ["report/figure.png", "segment/overlay/"])
    assert "Hard scenes, ball centre error" in dom  # the accuracy table's markdown


@pytest.mark.slow
@needs_browser
def test_compare_report(tmp_path):
    from stereograph.app.compare import compare

    res = compare(
        PIPES / "compare-compensation.yaml",
        ["fit.type=none,polynomial,xyz"],
        tmp_path / "cmp",
        overrides=["rig.n_scenes=24", "rig.n_views=10"],
        cache_dir=tmp_path / "cache",
    )
    page = res.out_dir / "compare.html"
    shot = _shots(tmp_path) / "compare-compensation.png"
    dom = _browser(page, tmp_path, shot, 1800)
    _check(dom, shot, ["metrics.png"])  # one bar per variant and metric: no variant hides another
    assert "z_rms_cm" in dom and "found_rate" in dom  # the metrics the nodes declared, as columns
    # every variant's full settings, the shared --set overrides in the title and in each row
    assert all(f"fit.type={t}" in dom for t in ("none", "polynomial", "xyz"))
    assert dom.count("--set rig.n_scenes=24") >= 4
    # each variant is a compensate.yaml run with its fit's figure on its page
    for vr in res.variants:
        assert 'data-file="fit/figure.png"' in (vr.out_dir / "report.html").read_text()
    # one of them opened: the compensation figure (curve over the training placements) loads
    xyz = next(vr for vr in res.variants if "fit.type=xyz" in vr.variant.label)
    shot = _shots(tmp_path) / "compensate-xyz.png"
    dom = _browser(xyz.out_dir / "report.html", tmp_path, shot, 6400)
    _check(dom, shot, ["fit/figure.png", "report/figure.png"])


@pytest.mark.slow
@needs_browser
def test_pick_report(tmp_path):
    res = run_pipeline(
        PIPES / "pick.yaml",
        ["rig.n_scenes=16", "rig.n_views=10", "act.sim_time_scale=20"],
        cache_dir=tmp_path / "cache",
        out_dir=tmp_path / "pick",
    )
    assert res.ok
    shot = _shots(tmp_path) / "pick.png"
    # tall: the arm is the last node
    dom = _browser(res.out_dir / "report.html", tmp_path, shot, 7600)
    _check(dom, shot, ["pick_report/arm_figure.png", "locate/overlay/"])
    assert "Joints and servos at the grasp" in dom and "goal (units)" in dom


PAYLOAD = (
    "<img src=x onerror=\"document.body.setAttribute('data-pwned','img')\">"
    "<script>document.body.setAttribute('data-pwned','script')</script>"
)


def _leaves(x, path=()):
    """Every value of a JSON document (and every key of its objects), as paths."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield (*path, ("key", k))
            yield from _leaves(v, (*path, k))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, (*path, i))
    else:
        yield path


def _plant(doc, path):
    """A copy of ``doc`` with the payload at ``path`` (appended to a string, in place of anything
    else)."""
    doc = json.loads(json.dumps(doc))
    *head, last = path
    box = doc
    for p in head:
        box = box[p]
    if isinstance(last, tuple):  # a key
        box[last[1] + PAYLOAD] = box.pop(last[1])
    else:
        box[last] = (box[last] + PAYLOAD) if isinstance(box[last], str) else PAYLOAD
    return doc


def test_markup_planted_in_any_run_json_field_is_shown_as_text(tmp_path):
    """run.json may come from someone else (`stereograph report DIR`): whatever field carries
    markup, the page either shows it as text or is refused -- and in a browser no planted script
    runs."""
    from stereograph.app.report import write_report
    from stereograph.core.errors import ConfigError

    res = run_pipeline(
        PIPES / "hello.yaml", ["numbers.n=3"], cache_dir=tmp_path / "c", out_dir=tmp_path / "run"
    )
    summary = json.loads((res.out_dir / "run.json").read_text())
    paths = list(_leaves(summary))
    assert len(paths) > 80
    planted_all, refused = summary, []
    for path in reversed(paths):  # (a key after everything below it: its children's paths name it)
        (res.out_dir / "run.json").write_text(json.dumps(_plant(summary, path)))
        try:
            page = write_report(res.out_dir).read_text()
        except ConfigError:
            refused.append(path)
            continue
        assert "<img src=x" not in page and "<script>document" not in page, path
        # (keys one at a time only: a renamed 'nodes' hides the rest)
        if not isinstance(path[-1], tuple):
            planted_all = _plant(planted_all, path)
    assert len(refused) < len(paths) // 4  # most fields are shown, escaped
    # every value that is shown, planted at once, opened in the browser: nothing ran
    (res.out_dir / "run.json").write_text(json.dumps(planted_all))
    assert main(["report", str(res.out_dir)]) == 0
    page = (res.out_dir / "report.html").read_text()
    assert page.count("&lt;img src=x") >= 20
    if CHROMIUM is None:
        pytest.skip("headless Chromium not installed: the page was checked as text only")
    dom = _browser(res.out_dir / "report.html", tmp_path, tmp_path / "planted.png", 1200)
    body = re.search(r"<body[^>]*>", dom).group(0)
    assert "data-pwned" not in body, body  # no planted handler or script ran
    assert 'data-ok="true"' in dom  # (the page's own script did run)


@pytest.mark.slow
def test_a_loops_page_leads_with_its_result_and_its_cycles(tmp_path):
    """pick-live --repeat 3 --save-cycles: the result (the pick's summary), then the cycles (counts,
    time per stage, the last cycles' pictures), then the graph and the nodes; each cycle's servo log
    kept."""
    from stereograph.app.loop import Loop
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph
    from stereograph.core.runner import run_graph

    doc = load_pipeline(PIPES / "pick-live.yaml", ["act.sim_time_scale=20", "segment.overlay=true"])
    loop = Loop(3, save_cycles=True)
    res = run_graph(
        build_graph(doc), cycles=loop, out_dir=tmp_path / "run", cache_dir=tmp_path / "cache"
    )
    page = (res.out_dir / "report.html").read_text()
    at = {k: page.index(k) for k in ('id="sg-result"', 'id="sg-cycles"', 'id="sg-details"')}
    assert at['id="sg-result"'] < at['id="sg-cycles"'] < at['id="sg-details"']
    result = page[at['id="sg-result"'] : at['id="sg-cycles"']]
    assert "act: summary" in result and "picks[0].ok" in result
    cycles = page[at['id="sg-cycles"'] : at['id="sg-details"']]
    assert "time per cycle" in cycles and ">segment<" in cycles and "cycle 3: ok" in cycles
    assert 'data-file="cycles/00003/segment/overlay' in cycles
    logs = (res.out_dir / "act" / "log.cycles.jsonl").read_text().splitlines()
    assert [json.loads(line)["cycle"] for line in logs] == [1, 2, 3]
    if CHROMIUM is None:
        pytest.skip("headless Chromium not installed: the page was checked as text only")
    shot = _shots(tmp_path) / "pick-live.png"
    dom = _browser(res.out_dir / "report.html", tmp_path, shot, 800)
    _check(dom, shot, ["cycles/00003/"])
