"""Mis-detected training placements cannot poison a compensation fit (issue 15, item 5).

A third of the training placements carry the truth of one ball but the measurement of a
distractor 15-40 cm away, seen through the same imperfect rig (2 % baseline error, 0.5 px
disparity offset). Every fitting compensator must leave exactly those out, list them with their
residual, and give test-placement accuracy within 10 % of the fit on the clean training set.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from compensation_data import errors, make_locations

from nodes.compensators import disparity_curve, lookup, polynomial, xyz
from nodes.compensators.apply import ApplyParams, apply
from stereograph.core.api import NodeError, RunContext

FIT_NODES = {
    "polynomial": polynomial.polynomial,
    "disparity_curve": disparity_curve.disparity_curve,
    "lookup": lookup.lookup,
    "xyz": xyz.xyz,
}
RIG = {"n": 160, "seed": 3, "baseline_scale": 1.02, "disparity_offset_px": 0.5, "noise_px": 0.1}


def fit(kind, locations, ctx=None, **params):
    fn = FIT_NODES[kind]
    params.setdefault("figure", False)  # the figure has its own test (test_compensation_figure.py)
    return fn(fn.spec.params(**params), train=locations, ctx=ctx)["model"]


def test_rms_3d(model, locations):
    out = {
        k: apply(ApplyParams(), model=model, location=v)["location"] for k, v in locations.items()
    }
    e = errors(out, "test")
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


test_rms_3d.__test__ = False  # a helper, not a test


@pytest.fixture(scope="module")
def clean():
    return make_locations(**RIG)


@pytest.fixture(scope="module")
def poisoned():
    return make_locations(**RIG, misdetect_fraction=1 / 3)


def test_the_poisoned_data_differs_only_in_the_misdetected_items(clean, poisoned):
    bad = [k for k, v in poisoned.items() if v["misdetected"]]
    n_train = sum(v["split"] == "train" for v in poisoned.values())
    assert len(bad) == round(n_train / 3)
    for k, v in poisoned.items():
        if k in bad:
            off = np.linalg.norm(np.subtract([v["x_cm"], v["y_cm"], v["z_cm"]], v["truth_cm"]))
            assert off > 10.0  # tens of cm off: a distractor, not noise
        else:
            assert v == dict(clean[k], misdetected=False) or v == clean[k]


@pytest.mark.parametrize("kind", list(FIT_NODES))
def test_misdetections_are_left_out_and_accuracy_holds(clean, poisoned, kind):
    bad = {k for k, v in poisoned.items() if v["misdetected"]}
    ctx = RunContext(node_name="fit", item=None, out_dir=Path("."), pipeline_dir=Path("."))
    robust = fit(kind, poisoned, ctx=ctx)
    reference = fit(kind, clean)
    naive = fit(kind, poisoned, outlier_mad=None)

    assert {o["item"] for o in robust["outliers"]} == bad
    assert robust["n_train"] == robust["n_candidates"] - len(bad) and robust["n_outliers"] == len(
        bad
    )
    assert all(o["residual_cm"] > robust["outlier_threshold_cm"] for o in robust["outliers"])
    assert "NaN" not in json.dumps(robust)
    # The run summary names them with their residuals.
    assert (
        len(ctx.messages) == 1
        and f"left {len(bad)} of" in ctx.messages[0]
        and " cm)" in ctx.messages[0]
    )

    rms_clean, rms_robust, rms_naive = (
        test_rms_3d(m, d) for m, d in ((reference, clean), (robust, poisoned), (naive, poisoned))
    )
    assert rms_robust <= 1.10 * rms_clean, (rms_robust, rms_clean)
    assert rms_naive > 10 * rms_clean  # without the screening the fit really is poisoned


@pytest.mark.parametrize("kind", list(FIT_NODES))
def test_too_few_inliers_is_a_clear_refusal(poisoned, kind):
    # A third left out, but the user asked for 80 % agreement.
    with pytest.raises(NodeError) as exc:
        fit(kind, poisoned, min_inlier_fraction=0.8)
    msg = exc.value.message
    assert f"compensator.{kind}" in msg and "agree with one another" in msg and "residual >" in msg
    assert "colour" in exc.value.hint


@pytest.mark.parametrize("kind", list(FIT_NODES))
def test_a_majority_of_misdetections_is_refused(kind):
    # Beyond one half the median cannot single them out; the fit they leave is far worse than
    # the measurements' stated uncertainty, and that is refused rather than fitted.
    mostly_bad = make_locations(**RIG, misdetect_fraction=0.6)
    with pytest.raises(NodeError) as exc:
        fit(kind, mostly_bad)
    msg = exc.value.message
    assert f"compensator.{kind}" in msg and "disagree" in msg and "stated depth uncertainty" in msg
    assert "colour" in exc.value.hint


def test_a_clean_fit_is_unchanged_by_the_screening(clean):
    for kind in FIT_NODES:
        a, b = fit(kind, clean), fit(kind, clean, outlier_mad=None)
        if a["n_outliers"] == 0:
            assert a["coefficients"] == b["coefficients"]
        assert a["n_outliers"] <= 1  # a clean set loses at most a stray placement


def test_screening_off_keeps_every_placement(poisoned):
    model = fit("polynomial", poisoned, outlier_mad=None)
    assert model["n_outliers"] == 0 and model["n_train"] == model["n_candidates"]


@pytest.mark.slow
def test_the_run_summary_and_model_file_list_the_left_out_placements(tmp_path):
    # Through the CLI: toy placements (a third of the train split mis-detected) -> compensator.xyz.
    from stereograph.app.cli import main

    plugin = Path(__file__).resolve().parent / "plugins" / "toy_locations.py"
    pipeline = tmp_path / "p.yaml"
    pipeline.write_text(
        f"name: robust\nplugins: [{plugin}]\nnodes:\n"
        "  scenes: {type: toy.scenes, params: {n: 120, seed: 3, misdetect_fraction: 0.334}}\n"
        "  locate: {type: toy.triangulate, params: {baseline_scale: 1.02}, inputs: "
        "{scene: scenes.scenes}}\n"
        "  fit: {type: compensator.xyz, inputs: {train: locate.location}}\n"
    )
    out = tmp_path / "run"
    assert (
        main(["run", str(pipeline), "--out", str(out), "--cache-dir", str(tmp_path / "cache")]) == 0
    )
    model = json.loads((out / "fit" / "model.json").read_text())
    truth = make_locations(n=120, seed=3, misdetect_fraction=0.334)
    assert {o["item"] for o in model["outliers"]} == {
        k for k, v in truth.items() if v["misdetected"]
    }
    fit_report = next(
        n for n in json.loads((out / "run.json").read_text())["nodes"] if n["node"] == "fit"
    )
    worst = model["outliers"][0]
    assert any(
        f"left {model['n_outliers']} of {model['n_candidates']}" in m and worst["item"] in m
        for m in fit_report["messages"]
    )
