"""report.html (engine side, no browser) and `stereograph graph --format png|svg`."""

from __future__ import annotations

import json
from pathlib import Path

import cv2

from stereograph.app.cli import main
from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parents[1]
HELLO = ROOT / "pipelines" / "hello.yaml"


def test_every_run_writes_a_self_contained_report(tmp_path):
    res = run_pipeline(HELLO, ["numbers.n=4"], cache_dir=tmp_path / "c", out_dir=tmp_path / "out")
    page = (res.out_dir / "report.html").read_text()
    summary = json.loads((res.out_dir / "run.json").read_text())
    # the graph is drawn from run.json
    assert summary["nodes"][1]["inputs"] == {"m": ["numbers", "items"]}
    assert "<svg" in page and 'data-node="power"' in page
    for n in summary["nodes"]:
        assert f'id="node-{n["node"]}"' in page
    assert (
        "http://" not in page.replace("http://www.w3.org/2000/svg", "") and "https://" not in page
    )
    # rebuilt from run.json alone; a folder without one is a clear error, not a traceback
    (res.out_dir / "report.html").unlink()
    assert main(["report", str(res.out_dir)]) == 0 and (res.out_dir / "report.html").is_file()
    assert main(["report", str(tmp_path)]) == 2


def test_report_renders_tables_and_embeds_images(tmp_path):
    from stereograph.app.report import build_html

    (tmp_path / "n").mkdir()
    img = (255 * (cv2.getGaussianKernel(40, 8) @ cv2.getGaussianKernel(40, 8).T)).astype("uint8")
    cv2.imwrite(str(tmp_path / "n" / "fig.png"), img)
    (tmp_path / "n" / "t.json").write_text(
        json.dumps(
            {
                "title": "servo goals",
                "columns": ["joint", "deg"],
                "rows": [["yaw", 1.5], ["elbow", -3.25]],
            }
        )
    )
    html = build_html(
        {
            "pipeline": "x.yaml",
            "run_id": "r",
            "ok": True,
            "nodes": [
                {
                    "node": "n",
                    "type": "k.t",
                    "status": "ran",
                    "seconds": 1.0,
                    "files": ["n/fig.png", "n/t.json"],
                }
            ],
        },
        tmp_path,
    )
    assert 'src="data:image/png;base64,' in html
    assert "<caption>servo goals</caption>" in html and "<td>-3.25</td>" in html


def test_graph_picture_png_and_svg(tmp_path):
    png, svg = tmp_path / "g.png", tmp_path / "g.svg"
    assert main(["graph", str(HELLO), "--format", "png", "-o", str(png)]) == 0
    assert main(["graph", str(HELLO), "--format", "svg", "-o", str(svg)]) == 0
    im = cv2.imread(str(png))
    assert im is not None and im.shape[0] > 100 and im.shape[1] > 100
    text = svg.read_text()
    assert (
        text.startswith("<svg")
        and text.count('class="sg-node"') == 4
        and text.count("<path d=") >= 3
    )


def test_report_says_how_many_messages_it_left_out(tmp_path):
    from stereograph.app.report import MESSAGES_SHOWN, build_html

    msgs = [f"pair{i:03d}: no region found" for i in range(MESSAGES_SHOWN + 7)]
    html = build_html(
        {
            "pipeline": "x.yaml",
            "run_id": "r",
            "ok": True,
            "nodes": [{"node": "seg", "type": "k.t", "status": "ran", "messages": msgs}],
        },
        tmp_path,
    )
    assert msgs[MESSAGES_SHOWN - 1] in html and msgs[MESSAGES_SHOWN] not in html
    assert "7 more messages in" in html and 'href="run.json"' in html


def test_report_sections_follow_the_data_flow(tmp_path):
    from stereograph.app.report import build_html

    # as an including file leaves them: 'report' rewired to read 'compensate', listed before it
    nodes = [
        {"node": "locate", "inputs": {}},
        {"node": "report", "inputs": {"locations": ["compensate", "location"]}},
        {"node": "fit", "inputs": {"train": ["locate", "location"]}},
        {
            "node": "compensate",
            "inputs": {"model": ["fit", "model"], "location": ["locate", "location"]},
        },
    ]
    html = build_html(
        {
            "pipeline": "x.yaml",
            "run_id": "r",
            "ok": True,
            "nodes": [dict(n, type="k.t", status="ran") for n in nodes],
        },
        tmp_path,
    )
    at = [
        html.index(f'<section class="sg-node-section" data-node="{n}"')
        for n in ("locate", "fit", "compensate", "report")
    ]
    assert at == sorted(at)


def test_a_markdown_value_is_shown_as_html_with_its_table():
    # (it was shown as monospace text: `| axis | mean error (cm) | ...` to read by eye)
    from stereograph.app.page import markdown_html

    md = "### Error <b>\n\nsplit: test\n\n| axis | mean (cm) |\n|---|---:|\n| z | -0.059 |\n"
    page = markdown_html(md)
    assert page.startswith("<h5>Error &lt;b&gt;</h5><p>split: test</p><table")
    assert (
        "<th>axis</th><th>mean (cm)</th>" in page
        and "<td>z</td><td>-0.059</td>" in page
        and "---" not in page
    )


def test_report_on_a_malformed_run_json_is_a_clear_error(tmp_path, capsys):
    # (a run.json of the wrong shape -- edited by hand, another tool's -- was "internal error:
    # TypeError")
    bad = [
        {"stereograph_run": {}, "nodes": 5},
        {"nodes": [{"node": "a", "files": 7}]},
        {"nodes": [{"node": "a", "seconds": "slow"}]},
        {"nodes": [{"node": "a", "inputs": [1]}]},
    ]
    for summary in bad:
        (tmp_path / "run.json").write_text(json.dumps(summary))
        assert main(["report", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "run.json" in err and "internal error" not in err, (summary, err)
        assert not (tmp_path / "report.html").exists()


def test_no_wire_of_the_graph_picture_crosses_a_box():
    """(long wires ran down shared lanes on the left and tangled; they now pass beside the boxes)"""
    import numpy as np

    from stereograph.app.graph_picture import BOX_H, BOX_W, describe, layout
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    for name in ("pick.yaml", "pick-live.yaml", "locate.yaml", "bench-fit.yaml"):
        nodes = describe(build_graph(load_pipeline(ROOT / "pipelines" / name)))
        pos, wires, (w, h) = layout(nodes)
        for src, _out, dst, _port, pts in wires:
            for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
                for t in np.linspace(0.02, 0.98, 25):
                    x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
                    inside = [
                        n
                        for n, (bx, by) in pos.items()
                        if bx + 1 < x < bx + BOX_W - 1
                        and by + 1 < y < by + BOX_H - 1
                        and n not in (src, dst)
                    ]
                    assert not inside, (name, src, dst, inside)
            assert all(0 <= x <= w and 0 <= y <= h for x, y in pts), (name, src, dst)


def test_the_graph_pictures_wires_cross_each_other_rarely():
    """Wire crossings of the shipped pipelines' pictures (the shared left lanes gave pick.yaml 38,
    pick-live 27, locate 19, bench-fit 27; the layered layout 10, 8, 3, 6)."""
    from stereograph.app.graph_picture import describe, layout
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    def cross(p1, p2, p3, p4) -> bool:
        def side(a, b, c):
            return (c[1] - a[1]) * (b[0] - a[0]) - (b[1] - a[1]) * (c[0] - a[0])

        return side(p3, p4, p1) * side(p3, p4, p2) < 0 and side(p1, p2, p3) * side(p1, p2, p4) < 0

    # (locate.yaml and bench-fit.yaml one more since their objects declaration: a wire into the
    # segmenter)
    for name, most in (
        ("pick.yaml", 14),
        ("pick-live.yaml", 12),
        ("locate.yaml", 7),
        ("bench-fit.yaml", 11),
        ("clear-table.yaml", 16),
    ):
        _, wires, _ = layout(describe(build_graph(load_pipeline(ROOT / "pipelines" / name))))
        segs = [(i, a, b) for i, w in enumerate(wires) for a, b in zip(w[4], w[4][1:])]
        n = sum(
            cross(s[1], s[2], t[1], t[2])
            for k, s in enumerate(segs)
            for t in segs[k + 1 :]
            if s[0] != t[0]
        )
        assert n <= most, (name, n)
