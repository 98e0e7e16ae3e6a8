"""The compensation fit's figure: what it plots is the model's data (points, outliers, curve, valid
range).

Content is checked on the numbers the picture is drawn from (:func:`fit_picture`), not on pixels;
the node's output is checked to be a real rendered image.
"""

from __future__ import annotations

import numpy as np
import pytest
from compensation_data import make_locations

from nodes.compensators import disparity_curve, lookup, none, polynomial, xyz
from nodes.compensators._table import PREDICTORS
from nodes.contracts.compensator._common import training_samples
from nodes.contracts.compensator._figure import fit_picture, held_out

FIT_NODES = {
    "polynomial": polynomial.polynomial,
    "disparity_curve": disparity_curve.disparity_curve,
    "lookup": lookup.lookup,
    "xyz": xyz.xyz,
}
VIEW = {
    "polynomial": ("z_cm", ("z",)),
    "disparity_curve": ("disparity_px", ("z",)),
    "lookup": ("z_cm", ("z",)),
    "xyz": ("disparity_px", ("x", "y", "z")),
}


@pytest.fixture(scope="module")
def poisoned():
    return make_locations(
        n=120,
        seed=3,
        baseline_scale=1.02,
        disparity_offset_px=0.5,
        noise_px=0.1,
        misdetect_fraction=0.1,
    )


def _picture(kind, locations, out):
    predict, needs = PREDICTORS[kind]
    candidates = training_samples(locations, "test", needs, 1)
    variable, axes = VIEW[kind]
    return fit_picture(
        out["model"], candidates, predict, held_out(locations, needs), variable, axes
    )


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(FIT_NODES))
def test_the_figure_shows_the_fitted_placements_outliers_and_model(poisoned, kind):
    fn = FIT_NODES[kind]
    out = fn(fn.spec.params(), train=poisoned)
    model = out["model"]
    pic = _picture(kind, poisoned, out)
    bad = sorted(k for k, v in poisoned.items() if v["misdetected"])
    n_test = sum(v["split"] != "train" for v in poisoned.values())

    assert len(bad) >= 4 and model["n_outliers"] == len(bad)
    assert (
        len(pic.train_x) == model["n_train"]
        and len(pic.outlier_x) == len(bad)
        and len(pic.test_x) == n_test
    )
    # outliers named, largest residual first, as the model lists them
    assert [lab.split(" ")[0] for lab in pic.outlier_labels] == [
        o["item"] for o in model["outliers"]
    ]
    assert sorted(lab.split(" ")[0] for lab in pic.outlier_labels) == bad
    assert (
        f"n_train = {model['n_train']}" in pic.title
        and f"outliers left out = {len(bad)}" in pic.title
    )
    assert f"{out['metrics']['cv_z_rms_cm']:.3g} cm" in pic.title
    # the shaded range is the model's valid range, and the curve is drawn beyond it on both sides
    # (dashed)
    variable = VIEW[kind][0]
    rng = model["valid_range"][variable]
    assert pic.valid == (rng["min"], rng["max"])
    assert pic.grid_x[0] < rng["min"] and pic.grid_x[-1] > rng["max"]
    assert [p.axis for p in pic.panels] == list(VIEW[kind][1])
    for p in pic.panels:
        k = "xyz".index(p.axis)
        assert (
            len(p.train_y) == model["n_train"]
            and len(p.outlier_y) == len(bad)
            and len(p.test_y) == n_test
        )
        assert np.all(
            np.isfinite(p.curve_y[(pic.grid_x >= rng["min"]) & (pic.grid_x <= rng["max"])])
        )
        # the points' distance from the model drawn is the model's own training residual
        at_points = (
            p.fitted_y if p.fitted_y is not None else np.interp(pic.train_x, pic.grid_x, p.curve_y)
        )
        rms = float(np.sqrt(np.mean((p.train_y - at_points) ** 2)))
        assert rms == pytest.approx(
            model["train_residual_cm"]["xyz"[k]]["rms_cm"], rel=0.05, abs=2e-3
        )
        # the outliers' errors are what the model recorded for them (truth - measured = -error_cm)
        recorded = np.array([-o["error_cm"][k] for o in model["outliers"]])
        assert np.allclose(p.outlier_y, recorded)
    # a model of more than its x variable shows its value at every training placement
    assert (pic.panels[0].fitted_y is not None) == (kind == "xyz")

    img = out["figure"]
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[1] == 720 and img.shape[0] > 350
    assert img.std() > 20  # drawn, not blank


def test_figure_can_be_switched_off_and_the_model_is_the_same(poisoned):
    fn = FIT_NODES["polynomial"]
    on, off = fn(fn.spec.params(), train=poisoned), fn(fn.spec.params(figure=False), train=poisoned)
    assert off["figure"].shape[0] < 60 and on["figure"].shape[0] > 350
    assert off["model"]["coefficients"] == on["model"]["coefficients"]


def test_baseline_figure_has_no_range_and_a_zero_correction(poisoned):
    out = none.none(none.none.spec.params(), train=poisoned)
    candidates = training_samples(poisoned, "test", (), 0)
    pic = fit_picture(
        out["model"], candidates, PREDICTORS["none"][0], held_out(poisoned, ()), "z_cm", ("z",)
    )
    assert (
        pic.valid is None and not pic.outlier_x.size and len(pic.train_x) == out["model"]["n_train"]
    )
    assert np.all(pic.panels[0].curve_y == 0)


def test_no_training_placements_still_gives_a_picture(poisoned):
    only_test = {k: v for k, v in poisoned.items() if v["split"] == "test"}
    out = none.none(none.none.spec.params(), train=only_test)
    assert out["model"]["n_train"] == 0 and out["figure"].shape[0] > 300


def test_held_out_takes_found_non_train_placements_with_truth(poisoned):
    locs = {k: dict(v) for k, v in list(poisoned.items())[:20]}
    test_ids = [k for k, v in locs.items() if v["split"] == "test"]
    locs[test_ids[0]]["found"] = False
    locs[test_ids[1]]["truth_cm"] = None
    locs[test_ids[2]]["disparity_px"] = None
    got = held_out(locs, ("disparity_px",))
    assert got is not None and sorted(got.ids) == sorted(test_ids[3:])
    assert held_out({k: v for k, v in locs.items() if v["split"] == "train"}, ()) is None
