"""`stereograph compare`: variants share the cache, a new variant computes only its own nodes,
and the table / files report the accuracy of the final Location outputs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from stereograph.cli import main as cli_main
from stereograph.compare import compare, expand_variants, final_location_outputs, parse_vary
from stereograph.config import load_pipeline
from stereograph.errors import ConfigError, UsageError
from stereograph.graph import build_graph

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
  locate: {{type: toy.triangulate, params: {{baseline_scale: 1.02}}, inputs: {{scene: scenes.scenes}}}}
  fit: {{type: compensator.none, inputs: {{train: locate.location}}}}
  compensate: {{type: compensator.apply, inputs: {{model: fit.model, location: locate.location}}}}
"""


@pytest.fixture()
def pipeline(tmp_path):
    p = tmp_path / "toy.yaml"
    p.write_text(PIPELINE)
    return p


def test_second_compare_computes_only_the_new_variant(pipeline, tmp_path):
    cache = tmp_path / "cache"
    first = compare(pipeline, [], tmp_path / "out1", cache_dir=cache, plots=False)
    assert [v.variant.label for v in first.variants] == ["fit.type=none", "fit.type=polynomial"]
    # The shared upstream runs once: only the first variant computes the source and the locator.
    assert first.variants[0].ran == {"scenes", "locate", "fit", "compensate"}
    assert first.variants[1].ran == {"fit", "compensate"}

    second = compare(pipeline, ["fit.type=none,polynomial,lookup"], tmp_path / "out2", cache_dir=cache, plots=True)
    ran = {v.variant.label: v.ran for v in second.variants}
    assert ran == {"fit.type=none": set(), "fit.type=polynomial": set(), "fit.type=lookup": {"fit", "compensate"}}
    # Same numbers from the cache as when computed.
    assert second.row(**{"fit.type": "polynomial"})["z_rms_cm"] == first.row(**{"fit.type": "polynomial"})["z_rms_cm"]
    for name in ("compare.csv", "compare.json", "z_error_vs_distance.png", "error_boxplots.png"):
        assert (tmp_path / "out2" / name).stat().st_size > 0


def test_table_reports_test_split_accuracy(pipeline, tmp_path):
    res = compare(pipeline, ["fit.type=none,polynomial"], tmp_path / "out", cache_dir=tmp_path / "c", plots=False)
    none, poly = res.row(**{"fit.type": "none"}), res.row(**{"fit.type": "polynomial"})
    assert none["split"] == "test" and 0 < none["n"] < 60 and none["n_truth"] == none["n"]
    assert none["z_mean_cm"] > 0.5  # a 2 % baseline error biases z
    assert abs(poly["z_mean_cm"]) < 0.05 and poly["z_rms_cm"] < 0.2 * none["z_rms_cm"]
    assert poly["fit_time_s"] is not None and poly["per_pair_s"] > 0
    assert none["output"] == "compensate.location"
    with open(tmp_path / "out" / "compare.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["fit.type"] for r in rows] == ["none", "polynomial"]
    assert float(rows[1]["z_rms_cm"]) == pytest.approx(poly["z_rms_cm"], rel=1e-4)
    doc = json.loads((tmp_path / "out" / "compare.json").read_text())
    assert doc["variants"][1]["overrides"] == ['fit.type="compensator.polynomial"']
    # The train split gives other numbers (the compensator was fitted on it).
    tr = compare(pipeline, ["fit.type=polynomial"], tmp_path / "o2", cache_dir=tmp_path / "c", split="train",
                 plots=False)
    assert tr.rows[0]["n"] + none["n"] == 60


def test_param_variation_and_type_first(pipeline, tmp_path):
    # cv_folds is given before the type change; it must survive the type's param reset.
    res = compare(pipeline, ["fit.cv_folds=4", "fit.type=lookup"], tmp_path / "o", cache_dir=tmp_path / "c",
                  plots=False)
    v = res.variants[0]
    assert v.ok, v.error
    model = json.loads((v.out_dir / "fit" / "model.json").read_text())
    assert model["type"] == "lookup" and model["cv"]["k"] == 4


def test_metrics_from_a_non_terminal_location_output(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(PIPELINE + "  count: {type: toy.count_found, inputs: {locations: compensate.location}}\n")
    graph = build_graph(load_pipeline(p))
    assert final_location_outputs(graph) == [("compensate", "location")]
    res = compare(p, [], tmp_path / "o", cache_dir=tmp_path / "c", plots=False)
    assert all(r["n_truth"] > 0 for r in res.rows)


def test_parse_vary():
    assert parse_vary("fit.type=none,polynomial") == ("fit.type", ["none", "polynomial"])
    assert parse_vary("fit.degree=1, 2,3") == ("fit.degree", [1, 2, 3])
    assert parse_vary("fit.bin_edges_cm=[30, 40, 60],[30, 60, 90]")[1] == [[30, 40, 60], [30, 60, 90]]
    for bad in ("fit.type", "fit=none", "fit.type="):
        with pytest.raises(UsageError):
            parse_vary(bad)


def test_product_of_block_and_cli(pipeline):
    doc = load_pipeline(pipeline)
    vs = expand_variants(doc, ["locate.baseline_scale=1.0,1.02"])
    assert [v.settings for v in vs] == [
        {"fit.type": "none", "locate.baseline_scale": 1.0}, {"fit.type": "none", "locate.baseline_scale": 1.02},
        {"fit.type": "polynomial", "locate.baseline_scale": 1.0},
        {"fit.type": "polynomial", "locate.baseline_scale": 1.02},
    ]


def test_invalid_variant_is_a_config_error(pipeline, tmp_path):
    with pytest.raises(ConfigError) as exc:
        compare(pipeline, ["fit.type=none,polynomal"], tmp_path / "o", cache_dir=tmp_path / "c")
    assert "variant fit.type=polynomal" in str(exc.value) and "compensator.polynomal" in str(exc.value)
    # A param the other type does not take: refused, or left out with skip_invalid.
    with pytest.raises(ConfigError, match="degree"):
        compare(pipeline, ["fit.type=polynomial,lookup", "fit.degree=1"], tmp_path / "o", cache_dir=tmp_path / "c")
    res = compare(pipeline, ["fit.type=polynomial,lookup", "fit.degree=1"], tmp_path / "o", cache_dir=tmp_path / "c",
                  skip_invalid=True, plots=False)
    assert [v.variant.label for v in res.variants] == ["fit.type=polynomial, fit.degree=1"]


def test_cli(pipeline, tmp_path, capsys):
    rc = cli_main(["compare", str(pipeline), "--vary", "fit.type=none,xyz", "--cache-dir", str(tmp_path / "c"),
                   "--out", str(tmp_path / "o"), "--no-plots"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "xyz" in out.out and "z RMS" in out.out and "compare.csv" in out.out
    assert "[2/2] fit.type=xyz" in out.err  # progress lines when not on a terminal
    assert cli_main(["compare", str(pipeline), "--vary", "nodot=1"]) == 2
    assert cli_main(["compare", str(pipeline), "--vary", "ghost.type=a,b"]) == 2
