"""`stereograph compare`: variants share the cache, a new variant computes only its own nodes,
and the table / files report the metrics the pipeline's nodes declare (``Out("Metrics")``)."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from stereograph.app.cli import main as cli_main
from stereograph.app.compare import collect_metrics, compare, metrics_outputs
from stereograph.app.variants import expand_variants, parse_vary
from stereograph.core.config import load_pipeline
from stereograph.core.errors import ConfigError, UsageError
from stereograph.core.graph import build_graph

PLUGIN = Path(__file__).resolve().parent / "plugins" / "toy_locations.py"

PIPELINE = f"""
name: toycompare
plugins: [{PLUGIN}]
defaults:
  compensator.polynomial: {{degree: 2, cv_folds: 3}}
variants:
  fit.type: [none, polynomial]
nodes:
  scenes: {{type: toy.scenes, params: {{n: 60, disparity_offset_px: 0.5}}}}
  locate: {{type: toy.triangulate, params: {{baseline_scale: 1.02}},
           inputs: {{scene: scenes.scenes}}}}
  fit: {{type: compensator.none, inputs: {{train: locate.location}}}}
  compensate: {{type: compensator.apply, inputs: {{model: fit.model, location: locate.location}}}}
  report: {{type: report.accuracy, params: {{figure: false}},
           inputs: {{locations: compensate.location}}}}
"""


@pytest.fixture()
def pipeline(tmp_path):
    p = tmp_path / "toy.yaml"
    p.write_text(PIPELINE)
    return p


@pytest.mark.slow
def test_second_compare_computes_only_the_new_variant(pipeline, tmp_path):
    cache = tmp_path / "cache"
    first = compare(pipeline, [], tmp_path / "out1", cache_dir=cache, plots=False)
    assert [v.variant.label for v in first.variants] == ["fit.type=none", "fit.type=polynomial"]
    # The shared upstream runs once: only the first variant computes the source and the locator.
    assert first.variants[0].ran == {"scenes", "locate", "fit", "compensate", "report"}
    assert first.variants[1].ran == {"fit", "compensate", "report"}

    second = compare(
        pipeline,
        ["fit.type=none,polynomial,lookup"],
        tmp_path / "out2",
        cache_dir=cache,
        plots=True,
    )
    ran = {v.variant.label: v.ran for v in second.variants}
    assert ran == {
        "fit.type=none": set(),
        "fit.type=polynomial": set(),
        "fit.type=lookup": {"fit", "compensate", "report"},
    }
    # Same numbers from the cache as when computed.
    assert (
        second.row(**{"fit.type": "polynomial"})["z_rms_cm"]
        == first.row(**{"fit.type": "polynomial"})["z_rms_cm"]
    )
    for name in ("compare.csv", "compare.json", "metrics.png"):
        assert (tmp_path / "out2" / name).stat().st_size > 0


@pytest.mark.slow
def test_table_reports_test_split_accuracy(pipeline, tmp_path):
    res = compare(
        pipeline,
        ["fit.type=none,polynomial"],
        tmp_path / "out",
        cache_dir=tmp_path / "c",
        plots=False,
    )
    none, poly = res.row(**{"fit.type": "none"}), res.row(**{"fit.type": "polynomial"})
    assert 0 < none["n"] < 60 and none["n_truth"] == none["n"] and none["found_rate"] == 1.0
    assert none["z_mean_cm"] > 0.5  # a 2 % baseline error biases z
    assert abs(poly["z_mean_cm"]) < 0.05 and poly["z_rms_cm"] < 0.2 * none["z_rms_cm"]
    assert poly["fit_time_s"] is not None and poly["per_pair_s"] > 0
    # The columns are the declared metrics, in declaration order (fit's, then report's), then the
    # per-pair time.
    assert res.metric_names[:4] == ["fit_time_s", "n_train", "n_outliers", "cv_z_rms_cm"]
    assert res.metric_names[-1] == "per_pair_s" and "x_max_abs_cm" in res.metric_names
    with open(tmp_path / "out" / "compare.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["fit.type"] for r in rows] == ["none", "polynomial"]
    assert float(rows[1]["z_rms_cm"]) == pytest.approx(poly["z_rms_cm"], rel=1e-4)
    doc = json.loads((tmp_path / "out" / "compare.json").read_text())
    assert doc["variants"][1]["overrides"] == ['fit.type="compensator.polynomial"']
    # The train split gives other numbers (the compensator was fitted on it).
    tr = compare(
        pipeline,
        ["fit.type=polynomial"],
        tmp_path / "o2",
        cache_dir=tmp_path / "c",
        split="train",
        plots=False,
    )
    assert tr.rows[0]["n"] + none["n"] == 60


@pytest.mark.slow
def test_param_variation_and_type_first(pipeline, tmp_path):
    # cv_folds is given before the type change; it must survive the type's param reset.
    res = compare(
        pipeline,
        ["fit.cv_folds=4", "fit.type=lookup"],
        tmp_path / "o",
        cache_dir=tmp_path / "c",
        plots=False,
    )
    v = res.variants[0]
    assert v.ok, v.error
    model = json.loads((v.out_dir / "fit" / "model.json").read_text())
    assert model["type"] == "lookup" and model["cv"]["k"] == 4


def test_metrics_are_what_nodes_declare(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(
        PIPELINE + "  report2: {type: report.accuracy, params: {figure: false, split: train}, "
        "inputs: {locations: locate.location}}\n"
    )
    graph = build_graph(load_pipeline(p))
    assert sorted(metrics_outputs(graph)) == [
        ("fit", "metrics"),
        ("report", "metrics"),
        ("report2", "metrics"),
    ]
    res = compare(p, ["fit.type=polynomial"], tmp_path / "o", cache_dir=tmp_path / "c", plots=False)
    row = res.rows[0]
    # Names two nodes both report get the node's name in front; the others stay bare.
    assert row["report.z_rms_cm"] < 0.2 * row["report2.z_rms_cm"] and "z_rms_cm" not in row
    assert row["report.n"] + row["report2.n"] == 60 and row["fit_time_s"] is not None


def test_collect_metrics_keeps_numbers_only():
    row = collect_metrics(
        {
            ("a", "m"): {"x_s": 1.5, "k": 3, "bad": float("nan"), "txt": "no"},
            ("b", "m"): {"k": True},
            ("c", "m"): None,
        }
    )
    assert row == {"x_s": 1.5, "a.k": 3, "bad": None, "txt": None, "b.k": 1}


def test_a_pipeline_without_metrics_is_refused(tmp_path):
    p = tmp_path / "p.yaml"
    # Only a source, a locator and a count: nothing declares an Out("Metrics").
    p.write_text(
        PIPELINE.split("  fit:")[0].replace("variants:\n  fit.type: [none, polynomial]\n", "")
        + "  count: {type: toy.count_found, inputs: {locations: locate.location}}\n"
    )
    with pytest.raises(ConfigError, match="declares no metrics"):
        compare(p, ["locate.baseline_scale=1.0,1.02"], tmp_path / "o", cache_dir=tmp_path / "c")


def test_the_engine_knows_no_domain():
    # compare and the rest of the engine name no artifact type, coordinate or axis of the node
    # library.
    import re

    engine = Path(__file__).resolve().parents[1] / "stereograph"
    pattern = re.compile(
        r"\bLocation\b|\b[xyz]_cm\b|\b[xyz]_(mean|std|rms|max_abs)|AXES|fit_time_s|truth_cm"
    )
    hits = [
        f"{f.name}:{i}"
        for f in sorted(engine.glob("*.py"))
        for i, line in enumerate(f.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert not hits, hits


def test_parse_vary():
    assert parse_vary("fit.type=none,polynomial") == ("fit.type", ["none", "polynomial"])
    assert parse_vary("fit.degree=1, 2,3") == ("fit.degree", [1, 2, 3])
    assert parse_vary("fit.bin_edges_cm=[30, 40, 60],[30, 60, 90]")[1] == [
        [30, 40, 60],
        [30, 60, 90],
    ]
    for bad in ("fit.type", "fit=none", "fit.type="):
        with pytest.raises(UsageError):
            parse_vary(bad)


def test_product_of_block_and_cli(pipeline):
    doc = load_pipeline(pipeline)
    vs = expand_variants(doc, ["locate.baseline_scale=1.0,1.02"])
    assert [v.settings for v in vs] == [
        {"fit.type": "none", "locate.baseline_scale": 1.0},
        {"fit.type": "none", "locate.baseline_scale": 1.02},
        {"fit.type": "polynomial", "locate.baseline_scale": 1.0},
        {"fit.type": "polynomial", "locate.baseline_scale": 1.02},
    ]


@pytest.mark.slow
def test_invalid_variant_is_a_config_error(pipeline, tmp_path):
    with pytest.raises(ConfigError) as exc:
        compare(pipeline, ["fit.type=none,polynomal"], tmp_path / "o", cache_dir=tmp_path / "c")
    assert "variant fit.type=polynomal" in str(exc.value) and "compensator.polynomal" in str(
        exc.value
    )
    # A param the other type does not take: refused, or left out with skip_invalid.
    with pytest.raises(ConfigError, match="degree"):
        compare(
            pipeline,
            ["fit.type=polynomial,lookup", "fit.degree=1"],
            tmp_path / "o",
            cache_dir=tmp_path / "c",
        )
    res = compare(
        pipeline,
        ["fit.type=polynomial,lookup", "fit.degree=1"],
        tmp_path / "o",
        cache_dir=tmp_path / "c",
        skip_invalid=True,
        plots=False,
    )
    assert [v.variant.label for v in res.variants] == ["fit.type=polynomial, fit.degree=1"]


@pytest.mark.slow
def test_cli(pipeline, tmp_path, capsys):
    rc = cli_main(
        [
            "compare",
            str(pipeline),
            "--vary",
            "fit.type=none,xyz",
            "--cache-dir",
            str(tmp_path / "c"),
            "--out",
            str(tmp_path / "o"),
            "--no-plots",
        ]
    )
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert (
        "xyz" in out.out
        and "z_rms_cm" in out.out
        and "pair ms" in out.out
        and "compare.csv" in out.out
    )
    assert "[2/2] fit.type=xyz" in out.err  # progress lines when not on a terminal
    assert cli_main(["compare", str(pipeline), "--vary", "nodot=1"]) == 2
    assert cli_main(["compare", str(pipeline), "--vary", "ghost.type=a,b"]) == 2


@pytest.mark.slow
def test_cli_page_shows_the_plot_it_wrote(pipeline, tmp_path):
    # the CLI draws metrics.png after compare() wrote compare.html; the page must still show it
    assert (
        cli_main(
            [
                "compare",
                str(pipeline),
                "--cache-dir",
                str(tmp_path / "c"),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 0
    )
    page = (tmp_path / "o" / "compare.html").read_text()
    assert (tmp_path / "o" / "metrics.png").is_file() and 'data-file="metrics.png"' in page


@pytest.mark.slow
def test_variants_in_parallel_give_the_serial_table(pipeline, tmp_path):
    from stereograph.core.executors import ProcessExecutor

    vary = ["fit.type=none,polynomial,lookup"]
    serial = compare(pipeline, vary, tmp_path / "o1", cache_dir=tmp_path / "c1", plots=False)
    ex = ProcessExecutor(2)
    try:  # the first variant, then the other two at once, their per-item work in the same pool
        par = compare(
            pipeline, vary, tmp_path / "o2", cache_dir=tmp_path / "c2", plots=False, executor=ex
        )
    finally:
        ex.close()
    assert [v.variant.label for v in par.variants] == [v.variant.label for v in serial.variants]
    assert all(v.ok for v in par.variants)
    for v in serial.variants:
        assert (
            par.row(**v.variant.settings)["z_rms_cm"]
            == serial.row(**v.variant.settings)["z_rms_cm"]
        )
    assert [v.ran for v in par.variants] == [v.ran for v in serial.variants]


@pytest.mark.slow
def test_every_variant_writes_a_lossy_output_as_jpeg(tmp_path):
    # (the first variant wrote segment/overlay/*.jpg, the others lossless PNG: ~6x the disk, and
    # report.html pages of 16 MB)
    locate = Path(__file__).resolve().parent.parent / "pipelines" / "locate.yaml"
    code = cli_main(
        [
            "compare",
            str(locate),
            "--set",
            "rig.n_scenes=3",
            "--vary",
            "segment.type=segmenter.edge_morph,segmenter.otsu",
            "--vary",
            "disparity.type=disparity.centroid",
            "--out",
            str(tmp_path / "o"),
            "--cache-dir",
            str(tmp_path / "cache"),
            "--no-plots",
        ]
    )
    assert code == 0
    overlays = sorted((tmp_path / "o" / "variants").glob("*/segment/overlay/*"))
    assert len(overlays) == 6 and {p.suffix for p in overlays} == {".jpg"}


@pytest.mark.slow
def test_a_mistaken_best_or_metrics_still_prints_the_table_and_best_is_marked_in_plain_text(
    pipeline, tmp_path, capsys
):
    args = [
        "compare",
        str(pipeline),
        "--vary",
        "fit.type=none,xyz",
        "--cache-dir",
        str(tmp_path / "c"),
        "--out",
        str(tmp_path / "o"),
        "--no-plots",
    ]
    capsys.readouterr()
    assert cli_main([*args, "--best", "zz_rms"]) == 2  # (known only once the variants ran)
    out = capsys.readouterr()
    assert "z_rms_cm" in out.out and "xyz" in out.out and "no metric 'zz_rms'" in out.err
    assert cli_main([*args, "--metrics", "nothing*"]) == 2
    out = capsys.readouterr()
    assert "z_rms_cm" in out.out and "--metrics matches no metric" in out.err
    assert cli_main([*args, "--best", "z_rms_cm"]) == 0
    out = capsys.readouterr().out  # not a terminal: no colour, so the row says it
    assert out.count("<- best z_rms_cm") == 1


def test_a_variant_folder_is_named_by_the_settings_that_vary():
    # (keys with one value filled the 80 characters and the varying one was cut: 'fit.type-non')
    locate = Path(__file__).resolve().parent.parent / "pipelines" / "compare-compensation.yaml"
    slugs = [v.slug for v in expand_variants(load_pipeline(locate))]
    assert slugs[:2] == ["v01_fit.type-none", "v02_fit.type-polynomial"] and len(set(slugs)) == len(
        slugs
    )


def test_out_must_be_a_folder_of_its_own(pipeline, tmp_path, capsys):
    """--out on a file, under a file, or on a folder of someone else's files: a clear refusal (exit
    2), never an internal error, and no compare.csv or variants/ written among the user's files. An
    earlier comparison's folder, finished or interrupted, is reused."""
    (tmp_path / "a file").write_text("x")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "compare.csv").write_text("my numbers\n")
    base = [
        "compare",
        str(pipeline),
        "--vary",
        "fit.type=none",
        "--cache-dir",
        str(tmp_path / "c"),
        "--no-plots",
    ]
    for out, why in (
        (tmp_path / "a file", "is an existing file"),
        (tmp_path / "a file" / "sub", "is a file"),
        (foreign, "is not empty"),
    ):
        assert cli_main([*base, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert why in err and "internal error" not in err, err
    assert sorted(p.name for p in foreign.iterdir()) == ["compare.csv"]
    assert (foreign / "compare.csv").read_text() == "my numbers\n"
    with pytest.raises(ConfigError, match="not empty"):
        compare(pipeline, [], foreign, cache_dir=tmp_path / "c", plots=False)
    out = tmp_path / "o"
    assert cli_main([*base, "--out", str(out)]) == 0
    assert cli_main([*base, "--out", str(out)]) == 0  # its own earlier comparison
    # as if interrupted before the table: only variants/ of run folders
    (out / "compare.json").unlink()
    for f in ("compare.csv", "compare.html"):
        (out / f).unlink()
    assert cli_main([*base, "--out", str(out)]) == 0, capsys.readouterr().err


@pytest.mark.slow
def test_an_interrupt_drops_the_variants_not_begun(pipeline, tmp_path):
    """(Ctrl-C during `compare --workers N` waited for every queued variant to run, one after
    another, before the interrupt got through)"""
    from stereograph.core.executors import ProcessExecutor

    class StopAfterFirstParallel:
        def node_started(self, name, n_items):
            pass

        def advance(self, name):
            pass

        def variant_done(self, vr):
            if vr.variant.label != labels[0]:
                raise KeyboardInterrupt

    vary = ["fit.type=none,polynomial", "fit.cv_seed=0,1,2,3"]
    labels: list[str] = []
    ex = ProcessExecutor(2)
    prog = StopAfterFirstParallel()
    prog.variant_started = lambda i, n, label: labels.append(label)
    try:
        with pytest.raises(KeyboardInterrupt):
            compare(
                pipeline,
                vary,
                tmp_path / "o",
                cache_dir=tmp_path / "c",
                plots=False,
                executor=ex,
                progress=prog,
            )
    finally:
        ex.close(now=True)
    ran = [p for p in (tmp_path / "o" / "variants").iterdir() if (p / "run.json").is_file()]
    assert len(labels) > 4 and len(ran) < len(labels) - 1, (len(ran), len(labels))


GATE = '''
import os
from stereograph.core.api import Field, In, NodeError, Out, Params, node

class GateParams(Params):
    max_z_cm: float = Field(1000.0, gt=0, description="Farthest location let through (cm).")

@node("toygate.max_z", params=GateParams, inputs={"location": In("Location")},
      outputs={"location": Out("Location")})
def max_z(params, location, ctx=None):
    """Fails on a location farther than max_z_cm (as a node with a bug on the hard items would)."""
    if location["z_cm"] > params.max_z_cm:
        if os.environ.get("GATE_LOG"):  # a failure log of its own, in its folder (ctx.out_dir)
            ctx.out_dir.mkdir(parents=True, exist_ok=True)
            (ctx.out_dir / f"failed_{ctx.item}.txt").write_text("too far")
        raise NodeError("too far")
    return {"location": location}
'''


def gated(tmp_path: Path, head: str, locate: str, gate: str, report: str) -> Path:
    """A toy pipeline whose `gate` node fails on the far locations (GATE)."""
    (tmp_path / "gate.py").write_text(GATE)
    p = tmp_path / "gate.yaml"
    p.write_text(f"""
name: gated
plugins: [{PLUGIN}, gate.py]
{head}
nodes:
  scenes: {{type: toy.scenes, params: {{n: 60}}}}
  locate: {{type: toy.triangulate, params: {locate}, inputs: {{scene: scenes.scenes}}}}
  gate: {{type: toygate.max_z, params: {gate}, inputs: {{location: locate.location}}}}
  report: {{type: report.accuracy, params: {report}, inputs: {{locations: gate.location}}}}
""")
    return p


def test_a_failed_variant_is_never_best_and_is_marked_failed(tmp_path, capsys):
    """(a variant that failed on its far -- worst -- items had the lowest z RMS over the items left,
    and `--best z_rms_cm` marked it best; in a log nothing told its row from the others)"""
    p = gated(
        tmp_path,
        "variants:\n  gate.max_z_cm: [1000, 60]",
        "{baseline_scale: 1.02}",
        "{}",
        "{figure: false}",
    )
    args = [
        "compare",
        str(p),
        "--allow-plugins",
        "--cache-dir",
        str(tmp_path / "c"),
        "--out",
        str(tmp_path / "o"),
        "--no-plots",
        "--metrics",
        "n,z_mean_cm,z_rms_cm",
    ]
    assert cli_main([*args, "--best", "z_rms_cm"]) == 1
    got = capsys.readouterr()
    out = got.out
    rows = {
        line.strip("│ ").split()[0]: line
        for line in out.splitlines()
        if line.strip("│ ").startswith(("1000", "60"))
    }
    assert (
        "<- best z_rms_cm" in rows["1000"] and "FAILED" in rows["60"] and "best" not in rows["60"]
    ), out
    # how many items failed, not only the first (was "gate: item 's000': too far" alone)
    assert re.search(
        r"FAILED: gate: item 's\d+': too far \(\d+ of 60 items failed; run.json lists each\); "
        r"computed: gate, report",
        got.out + got.err,
    ), got.err
    # (the numbers that made it look best: fewer items, a lower error)
    res = json.loads((tmp_path / "o" / "compare.json").read_text())["rows"]
    assert res[1]["n"] < res[0]["n"] and res[1]["z_rms_cm"] < res[0]["z_rms_cm"]


def test_a_log_a_variants_node_wrote_itself_goes_when_its_folder_is_reused(tmp_path, monkeypatch):
    # (a variant's run.json listed its outputs only: a failure log the node wrote into its folder
    # stayed there after a later compare into the same --out, naming failures that compare did not
    # have)
    p = gated(tmp_path, "variants:\n  gate.max_z_cm: [1000, 60]", "{}", "{}", "{figure: false}")
    out = tmp_path / "o"
    monkeypatch.setenv("GATE_LOG", "1")
    compare(p, [], out, cache_dir=tmp_path / "c", plots=False)
    logs = sorted(out.rglob("failed_*.txt"))
    assert logs and all(log.parent.name == "gate" for log in logs)
    recorded = json.loads((logs[0].parent.parent / "run.json").read_text())
    assert str(logs[0].relative_to(logs[0].parent.parent)) in {
        f for n in recorded["nodes"] for f in n["files"]
    }
    monkeypatch.setenv("GATE_LOG", "")
    compare(p, [], out, cache_dir=tmp_path / "c", plots=False)
    assert not list(out.rglob("failed_*.txt"))


def test_pairs_that_failed_before_the_report_are_counted_as_lost_not_dropped(tmp_path):
    # (the report's n and errors covered the pairs that got through, and said nothing of the others:
    # a variant failing on its hardest pairs looked better)
    from stereograph.core.runner import run_pipeline

    p = gated(tmp_path, "", "{}", "{max_z_cm: 60}", "{figure: false, split: all}")
    r = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    n_failed = r.reports["gate"].items_failed
    assert 0 < n_failed < 60
    report, metrics = r.outputs("report", "report"), r.outputs("report", "metrics")
    assert report["n"] == 60 - n_failed and report["n_lost"] == metrics["n_lost"] == n_failed
    assert all(why == "gate: too far" for why in report["lost"].values()), report["lost"]
    assert f"{n_failed} pair(s) failed before reaching this report" in report["markdown"]
    assert any("failed before reaching this report" in m for m in r.reports["report"].messages)
    # a run whose pairs all get through says nothing of the kind, and its cache key is the one it
    # always had
    ok = run_pipeline(p, ["gate.max_z_cm=1000"], cache_dir=tmp_path / "c", out_dir=tmp_path / "o2")
    assert (
        ok.outputs("report", "metrics")["n_lost"] == 0
        and "lost" not in ok.outputs("report", "report")["markdown"]
    )


def test_a_variant_whose_node_failed_did_not_compute_nothing():
    # (a node that failed as a whole is not in `ran`: the progress line said "computed: nothing (all
    # cached)")
    from stereograph.app.compare_result import VariantResult
    from stereograph.app.variants import Variant

    def result(ok, status, ran):
        return VariantResult(
            variant=Variant(1, {"fit.type": "x"}),
            ok=ok,
            error=None if ok else "fit: too few",
            status=status,
            ran=set(ran),
            out_dir=Path("."),
            seconds=0.1,
            per_pair_s=None,
            metrics={},
        )

    assert (
        result(False, {"locate": "cached", "fit": "failed", "report": "skipped"}, []).computed
        == "fit (failed)"
    )
    assert (
        result(True, {"locate": "cached", "fit": "cached"}, []).computed == "nothing (all cached)"
    )
    assert result(True, {"locate": "cached", "fit": "ran"}, ["fit"]).computed == "fit"


def test_an_untimed_per_pair_column_says_why(capsys):
    from rich.console import Console

    from stereograph.app.compare import _rows
    from stereograph.app.compare_result import CompareResult, VariantResult
    from stereograph.app.compare_table import print_table
    from stereograph.app.variants import Variant

    def result(n, per_pair_s):
        return VariantResult(
            variant=Variant(n, {"fit.type": f"t{n}"}),
            ok=True,
            error=None,
            status={"fit": "ran"},
            ran={"fit"},
            out_dir=Path("."),
            seconds=0.1,
            per_pair_s=per_pair_s,
            metrics={"z_rms_cm": 0.1 * n},
        )

    def printed(*per_pair):
        variants = [result(n, s) for n, s in enumerate(per_pair, 1)]
        res = CompareResult("p.yaml", ["fit.type"], None, Path("."), variants, [], {})
        res.rows = _rows(res)
        print_table(res, Console(width=200, force_terminal=False))
        return capsys.readouterr().out

    assert "new --cache-dir times every node" in printed(None, None)
    assert "new --cache-dir" not in printed(0.004, 0.005)


@pytest.mark.slow
def test_best_of_a_signed_metric(pipeline, tmp_path, capsys):
    """--best NAME:abs ranks by closeness to zero; the plain lowest of a metric with negative values
    is said to be the most negative; an unknown way to rank is refused."""
    from stereograph.app.ranking import best_row, is_best

    res = compare(
        pipeline,
        ["fit.type=none,polynomial"],
        tmp_path / "o",
        cache_dir=tmp_path / "c",
        plots=False,
    )
    for r, v in zip(res.rows, (0.3, -0.01)):
        r["z_mean_cm"] = v
    res.rows.append({**res.rows[0], "z_mean_cm": -0.5})
    assert [is_best(best_row(res, "z_mean_cm:abs"), r) for r in res.rows] == [False, True, False]
    assert [is_best(best_row(res, "z_mean_cm"), r) for r in res.rows] == [False, False, True]
    with pytest.raises(UsageError, match="not a way to rank"):
        best_row(res, "z_mean_cm:ab")
    from stereograph.app.compare_table import print_table

    print_table(res, None, metrics=["z_mean_cm"], best="z_mean_cm")
    assert "most negative" in capsys.readouterr().out


def test_combinations_left_out_by_skip_invalid_are_named(pipeline, tmp_path, capsys):
    """(--skip-invalid dropped a combination with no word in the table, the progress lines or
    compare.html: only compare.json listed it)"""
    args = [
        "compare",
        str(pipeline),
        "--vary",
        "fit.type=polynomial,lookup",
        "--vary",
        "fit.degree=1",
        "--skip-invalid",
        "--cache-dir",
        str(tmp_path / "c"),
        "--out",
        str(tmp_path / "o"),
        "--no-plots",
    ]
    assert cli_main(args) == 0
    out = capsys.readouterr()
    for text in (out.out, out.err, (tmp_path / "o" / "compare.html").read_text()):
        assert "fit.type=lookup, fit.degree=1" in text and "degree" in text, text
    res = compare(
        pipeline,
        ["fit.type=polynomial,lookup", "fit.degree=1"],
        tmp_path / "o2",
        cache_dir=tmp_path / "c",
        skip_invalid=True,
        plots=False,
    )
    assert [label for label, _ in res.skipped] == ["fit.type=lookup, fit.degree=1"]


def test_a_problem_of_every_variant_is_not_blamed_on_the_first(
    pipeline, tmp_path, capsys, monkeypatch
):
    """(plugins not allowed, a plugin clashing with a built-in, a --vary key naming no node: each
    came out as 'variant fit.type=none: ...' with '--skip-invalid' offered, which would have left
    out every variant; a varied param the type does not take was called a --set)"""
    from stereograph.core.registry import plugins_allowed

    monkeypatch.delenv("STEREOGRAPH_ALLOW_PLUGINS")
    base = [
        "compare",
        str(pipeline),
        "--cache-dir",
        str(tmp_path / "c"),
        "--out",
        str(tmp_path / "o"),
        "--no-plots",
    ]
    assert cli_main(base) == 2  # no --allow-plugins
    err = capsys.readouterr().err
    assert "--allow-plugins" in err and "variant" not in err and "--skip-invalid" not in err, err
    (tmp_path / "clash.py").write_text(GATE.replace("toygate.max_z", "report.accuracy"))
    clash = tmp_path / "clash.yaml"
    clash.write_text(pipeline.read_text().replace("plugins: [", "plugins: [clash.py, "))
    with plugins_allowed(True), pytest.raises(ConfigError) as exc:
        compare(clash, [], tmp_path / "o", cache_dir=tmp_path / "c")
    assert "installed node type" in str(exc.value) and "skip-invalid" not in str(exc.value)
    with plugins_allowed(True), pytest.raises(UsageError) as exc:
        compare(pipeline, ["fitt.type=none,lookup"], tmp_path / "o", cache_dir=tmp_path / "c")
    assert "--vary 'fitt.type=none,lookup': no node named 'fitt'" in str(
        exc.value
    ) and "fit'?" in str(exc.value)
    assert "skip-invalid" not in str(exc.value)
    block = tmp_path / "block.yaml"
    block.write_text(
        pipeline.read_text().replace(
            "  fit.type: [none, polynomial]", "  fitt.type: [none, polynomial]"
        )
    )
    with plugins_allowed(True), pytest.raises(ConfigError) as exc:
        compare(block, [], tmp_path / "o", cache_dir=tmp_path / "c")
    assert "block.yaml:7" in str(exc.value) and "no node named 'fitt'" in str(exc.value)
    with plugins_allowed(True), pytest.raises(ConfigError) as exc:
        compare(pipeline, ["fit.degree=1"], tmp_path / "o", cache_dir=tmp_path / "c")
    assert str(exc.value).startswith("--vary fit.degree=1: node 'fit'") and "--set" not in str(
        exc.value
    )


TERM = '''
import os
import signal
from pathlib import Path
from stereograph.core.api import Field, In, Out, Params, node

class TermParams(Params):
    marker: str = Field(
        "", description="File whose absence makes the node send SIGTERM to its own process.")

@node("toyterm.once", params=TermParams, inputs={"location": In("Location")},
      outputs={"location": Out("Location")})
def once(params, location, ctx=None):
    """SIGTERM to this process on the first call (as a job scheduler's timeout would), then
    pass through."""
    if not Path(params.marker).exists():
        Path(params.marker).write_text("sent")
        os.kill(os.getpid(), signal.SIGTERM)
    return {"location": location}
'''


@pytest.mark.slow
def test_sigterm_ends_compare_like_ctrl_c_and_the_same_command_resumes(tmp_path):
    """(SIGTERM killed `compare` on the spot, exit 143 with nothing said, while `run` ended as
    Ctrl-C does: the variant's run.json written, "interrupted", exit 130)"""
    import subprocess
    import sys

    (tmp_path / "toyterm.py").write_text(TERM)
    p = tmp_path / "toy.yaml"
    p.write_text(
        PIPELINE.replace("plugins: [", f"plugins: [{tmp_path / 'toyterm.py'}, ").replace(
            "  report: {type: report.accuracy, params: {figure: false},\n"
            "           inputs: {locations: compensate.location}}",
            f"  term: {{type: toyterm.once, params: {{marker: {tmp_path / 'sent'}}}, "
            "inputs: {location: compensate.location}}\n"
            "  report: {type: report.accuracy, params: {figure: false}, inputs: "
            "{locations: term.location}}",
        )
    )
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "--allow-plugins",
        "compare",
        str(p),
        "--out",
        str(tmp_path / "o"),
        "--cache-dir",
        str(tmp_path / "c"),
    ]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert first.returncode == 130 and "interrupted" in first.stderr, (
        first.returncode,
        first.stderr[-800:],
    )
    run_json = json.loads((tmp_path / "o" / "variants").glob("*/run.json").__next__().read_text())
    assert run_json["ok"] is False and "interrupted" in " ".join(run_json["notes"])
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr[-800:]
    assert (tmp_path / "o" / "compare.json").is_file()


def test_the_named_metric_leads_and_constant_metrics_step_aside(tmp_path, capsys):
    """(the terminal table was split in two, the page ran off a 1280 px window and metrics.png had
    23 panels, several constant, with the compared figure as panel 20)"""
    from stereograph.app.compare_report import compare_table
    from stereograph.app.compare_table import print_table
    from stereograph.app.ranking import PER_PAIR

    p = tmp_path / "p.yaml"
    p.write_text(PIPELINE.replace("variants:", "compare: {metric: z_rms_cm}\nvariants:"))
    res = compare(p, [], tmp_path / "o", cache_dir=tmp_path / "c", plots=False)
    assert res.ranked_by == "z_rms_cm"
    shown, constant = res.shown_metrics()
    assert (
        shown[0] == "z_rms_cm"
        and shown[-1] == PER_PAIR
        and "n" in constant
        and "found_rate" in constant
    )
    for name in shown[1:-1]:  # every other column tells the variants apart
        assert len({round(r[name], 3) for r in res.rows}) > 1, name
    assert compare_table(res, [])["columns"][2] == "z_rms_cm"
    from rich.console import Console

    con = Console(width=400, record=True)
    print_table(res, con, best=res.ranked_by)
    text = con.export_text()
    assert (
        text.count("┏") == 1
        and "<- best z_rms_cm" in text
        and "the same in every variant: " in text
    )
    header = next(line for line in text.splitlines() if "fit.type" in line and "z_rms_cm" in line)
    assert header.index("z_rms_cm") < header.index("z_mean_cm")
    bad = tmp_path / "bad.yaml"
    bad.write_text(PIPELINE.replace("variants:", "compare: z_rms_cm\nvariants:"))
    with pytest.raises(ConfigError, match="'compare' must be a mapping"):
        load_pipeline(bad)


def test_a_vary_key_given_twice_is_refused_not_half_dropped(pipeline):
    doc = load_pipeline(pipeline)
    with pytest.raises(UsageError, match="--vary fit.type is given twice"):
        expand_variants(doc, ["fit.type=none,polynomial", "fit.type=lookup"])


def test_more_variants_than_one_compare_runs_are_refused_at_once(pipeline):
    import time

    doc = load_pipeline(pipeline)
    t0 = time.perf_counter()
    values = ",".join(str(1 + i / 1e3) for i in range(40))
    with pytest.raises(
        UsageError, match=r"128000 variants \(2 fit.type x 40 locate.baseline_scale"
    ):
        expand_variants(
            doc,
            [
                f"locate.baseline_scale={values}",
                f"scenes.disparity_offset_px={values}",
                f"fit.degree={values}",
            ],
        )
    assert time.perf_counter() - t0 < 10
