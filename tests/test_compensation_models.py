"""Compensator fit/apply functions on synthetic Location records with a known systematic error."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from compensation_data import errors, make_locations

from nodes.compensators import disparity_curve, lookup, none, polynomial, xyz
from nodes.compensators.apply import ApplyParams, apply, apply_model
from nodes.compensators.disparity_curve import fit_disparity_curve
from nodes.contracts.compensator._common import samples_from_locations
from stereograph.core.api import NodeError

FIT_NODES = {
    "none": none.none,
    "polynomial": polynomial.polynomial,
    "disparity_curve": disparity_curve.disparity_curve,
    "lookup": lookup.lookup,
    "xyz": xyz.xyz,
}


def fit(kind, locations, **params):
    fn = FIT_NODES[kind]
    params.setdefault("figure", False)  # the figure has its own test (test_compensation_figure.py)
    return fn(fn.spec.params(**params), train=locations)["model"]


def apply_all(model, locations):
    return {
        k: apply(ApplyParams(), model=model, location=v)["location"] for k, v in locations.items()
    }


def rms(e):
    return np.sqrt(np.mean(e**2, axis=0))


@pytest.fixture(scope="module")
def biased():
    # 2 % baseline error and a 0.5 px disparity offset: z error ~ +1 cm, growing with distance.
    return make_locations(n=160, seed=3, baseline_scale=1.02, disparity_offset_px=0.5, noise_px=0.1)


@pytest.mark.parametrize("kind", ["polynomial", "disparity_curve", "lookup", "xyz"])
def test_fitted_models_remove_systematic_error(biased, kind):
    base = errors(apply_all(fit("none", biased), biased))
    out = errors(apply_all(fit(kind, biased), biased))
    assert abs(np.mean(base[:, 2])) > 0.5  # the data really is biased
    assert abs(np.mean(out[:, 2])) < 0.05
    assert rms(out)[2] < 0.3 * rms(base)[2]
    # x and y are no worse (the correction moves points along their rays / fits them).
    assert np.all(rms(out)[:2] <= rms(base)[:2] * 1.05)


@pytest.mark.parametrize("kind", list(FIT_NODES))
def test_model_artifact_is_plain_json_with_required_keys(biased, kind):
    model = fit(kind, biased, cv_folds=4)
    text = json.dumps(model)  # plain data only
    assert "NaN" not in text
    for key in (
        "type",
        "coefficients",
        "valid_range",
        "train_residual_cm",
        "cv",
        "fit_time_s",
        "n_train",
    ):
        assert key in model
    assert model["type"] == kind
    assert model["n_train"] == sum(1 for v in biased.values() if v["split"] == "train")
    for axis in "xyz":
        assert set(model["train_residual_cm"][axis]) >= {"mean_cm", "std_cm", "rms_cm"}
    assert model["cv"]["k"] == 4 and "axes" in model["cv"]
    assert model["fit_time_s"] >= 0


def test_only_train_split_is_used(biased):
    # Corrupt every test item's truth: a model fitted only on train is unaffected.
    corrupted = {
        k: dict(v, truth_cm=[0.0, 0.0, 1000.0]) if v["split"] == "test" else v
        for k, v in biased.items()
    }
    a = fit("polynomial", biased)
    b = fit("polynomial", corrupted)
    assert a["coefficients"] == b["coefficients"]


def test_polynomial_target_z_matches_target_error(biased):
    a = errors(apply_all(fit("polynomial", biased, target="error", degree=2), biased))
    b = errors(apply_all(fit("polynomial", biased, target="z", degree=2), biased))
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_disparity_curve_recovers_known_coefficients():
    # Noise-free data from z = a/(d+b) + c must give back a, b, c.
    d = np.linspace(60, 250, 25)
    a, b, c = 8100.0, -1.5, 0.4
    z = a / (d + b) + c
    locs = {
        f"p{i}": {
            "pair": f"p{i}",
            "found": True,
            "x_cm": 0.0,
            "y_cm": 0.0,
            "z_cm": float(z[i] * 1.01),
            "disparity_px": float(d[i]),
            "u_left_px": 320.0,
            "v_left_px": 240.0,
            "truth_cm": [0.0, 0.0, float(z[i])],
            "split": "train",
            "frame": "left_camera",
        }
        for i in range(len(d))
    }
    coef = fit_disparity_curve(samples_from_locations(locs), rectified=False)
    assert coef["a_cm_px"] == pytest.approx(a, rel=1e-6)
    assert coef["b_px"] == pytest.approx(b, abs=1e-5)
    assert coef["c_cm"] == pytest.approx(c, abs=1e-6)


def test_disparity_curve_in_the_rectified_frame_is_exact_under_a_tilt():
    # The physical z is the rectified z times a factor of the ray direction (rectification turns the
    # camera by R1). Fitted in the rectified frame, the curve reproduces the truth exactly.
    rng = np.random.default_rng(5)
    d = rng.uniform(60, 250, 40)
    u = rng.uniform(20, 620, 40)
    g = 1 + 0.02 * (u - 320) / 560  # ~0.6 degree tilt about the vertical axis
    a, b, c = 8100.0, -1.5, 0.4
    z_true, z_meas = (a / (d + b) + c) * g, 8000.0 / d * g
    locs = {
        f"p{i}": {
            "pair": f"p{i}",
            "found": True,
            "x_cm": 0.0,
            "y_cm": 0.0,
            "z_cm": float(z_meas[i]),
            "disparity_px": float(d[i]),
            "u_left_px": float(u[i]),
            "v_left_px": 240.0,
            "truth_cm": [0.0, 0.0, float(z_true[i])],
            "split": "train",
            "frame": "left_camera",
        }
        for i in range(len(d))
    }
    samples = samples_from_locations(locs)
    from nodes.compensators.disparity_curve import predict_disparity_curve

    rect = predict_disparity_curve(fit_disparity_curve(samples, rectified=True), samples)
    cam = predict_disparity_curve(fit_disparity_curve(samples, rectified=False), samples)
    assert np.max(np.abs(rect[:, 2] - z_true)) < 1e-6
    assert np.max(np.abs(cam[:, 2] - z_true)) > 0.05  # the plain curve cannot follow the tilt


def test_apply_flags_extrapolation_and_keeps_value(biased):
    model = fit("polynomial", biased)
    zmax = model["valid_range"]["z_cm"]["max"]
    inside = dict(next(iter(biased.values())))
    far = dict(inside, z_cm=zmax * 1.3, x_cm=1.0, y_cm=1.0)
    got_in = apply_model(model, inside)
    got_far = apply_model(model, far)
    assert got_in["extrapolated"] is False
    assert got_far["extrapolated"] is True
    assert math.isfinite(got_far["z_cm"]) and got_far["z_cm"] != far["z_cm"]
    assert got_far["compensation"]["raw_cm"] == [1.0, 1.0, far["z_cm"]]


def test_apply_passes_not_found_through_unchanged(biased):
    model = fit("lookup", biased)
    lost = {
        "pair": "x",
        "found": False,
        "reason": "no ball",
        "x_cm": None,
        "y_cm": None,
        "z_cm": None,
        "frame": "left_camera",
        "split": "test",
    }
    assert apply_model(model, lost) == lost


def test_apply_undefined_curve_is_not_found_never_nan(biased):
    model = fit("disparity_curve", biased)
    loc = dict(next(iter(biased.values())))
    loc["disparity_px"] = -model["coefficients"]["b_px"] - 5.0  # beyond the curve's pole
    out = apply_model(model, loc)
    assert out["found"] is False and "undefined" in out["reason"]
    assert out["z_cm"] is None


def test_apply_missing_input_is_a_clear_error(biased):
    model = fit("xyz", biased)
    loc = dict(next(iter(biased.values())), disparity_px=None)
    with pytest.raises(NodeError, match="lacks finite disparity_px"):
        apply_model(model, loc)
    with pytest.raises(NodeError, match="unknown compensation model type 'spline'"):
        apply_model(dict(model, type="spline"), loc)


# ---- degenerate training data -------------------------------------------------------------


@pytest.mark.parametrize("kind", ["polynomial", "disparity_curve", "lookup", "xyz"])
def test_too_few_points(biased, kind):
    few = dict([(k, v) for k, v in biased.items() if v["split"] == "train"][:3])
    with pytest.raises(NodeError) as exc:
        fit(kind, few)
    assert f"compensator.{kind}" in exc.value.message
    assert (
        "usable training placements" in exc.value.message and "needs at least" in exc.value.message
    )


def test_placements_not_found_for_one_shared_reason_name_it(biased):
    # (swapped left/right ball images: every pair "not found" on different rows, and the fit said
    # only "0 usable training placements ... (13 not found)", nothing that pointed at the swap)
    # each pair says it with its own offset: one cause, counted as one (it was as many causes as
    # pairs)
    rows = (
        "left/right regions are on different rows (dv = {:.1f} px): not the same object -- "
        "or, when every pair"
    )
    lost = {
        k: dict(
            v,
            found=False,
            reason=rows.format(31.0 + i / 10) if i % 4 else "left image: no region found",
        )
        for i, (k, v) in enumerate(biased.items())
        if v["split"] == "train"
    }
    with pytest.raises(NodeError) as exc:
        fit("polynomial", lost)
    dvs = [
        float(v["reason"].split("dv = ")[1].split()[0])
        for v in lost.values()
        if "dv = " in v["reason"]
    ]
    assert len(dvs) > len(lost) / 2
    shared = rows.replace("{:.1f}", f"{min(dvs):.1f}–{max(dvs):.1f}")
    assert f"not found, most often ({len(dvs)} of {len(lost)}): {shared}" in exc.value.message


@pytest.mark.parametrize("kind", ["polynomial", "disparity_curve", "lookup", "xyz"])
def test_all_at_one_distance(kind):
    one = make_locations(n=80, seed=1, z_range_cm=(50.0, 50.0), noise_px=0.05)
    with pytest.raises(NodeError) as exc:
        fit(kind, one)
    assert f"compensator.{kind}" in exc.value.message and "all lie at one" in exc.value.message


@pytest.mark.parametrize("kind", ["polynomial", "disparity_curve", "lookup", "xyz"])
def test_nans_are_dropped_or_refused(biased, kind):
    # Half the training items carry NaN: they are dropped, and the fit stays finite.
    train_ids = [k for k, v in biased.items() if v["split"] == "train"]
    spoiled = {
        k: (dict(v, z_cm=float("nan"), disparity_px=float("nan")) if k in train_ids[::2] else v)
        for k, v in biased.items()
    }
    model = fit(kind, spoiled)
    assert model["n_train"] == len(train_ids) - len(train_ids[::2])
    assert "NaN" not in json.dumps(model)
    # All NaN: a clear error naming the reason.
    all_nan = {k: dict(v, z_cm=float("nan"), disparity_px=float("nan")) for k, v in biased.items()}
    with pytest.raises(NodeError, match="non-finite values"):
        fit(kind, all_nan)


def test_no_train_split_is_a_clear_error(biased):
    unsplit = {k: {kk: vv for kk, vv in v.items() if kk != "split"} for k, v in biased.items()}
    with pytest.raises(NodeError, match="not in the train split"):
        fit("polynomial", unsplit)


def test_none_is_identity(biased):
    model = fit("none", biased)
    out = apply_all(model, biased)
    for k in biased:
        assert out[k]["z_cm"] == biased[k]["z_cm"]
        assert out[k]["extrapolated"] is False


@pytest.mark.parametrize("kind", ["polynomial", "disparity_curve", "lookup"])
def test_xy_auto_follows_the_kind_of_error(biased, kind):
    # A baseline error moves points along their rays: auto rescales x, y too.
    assert fit(kind, biased)["coefficients"]["along_ray"] is True
    # A depth-only error (x, y exact, z 2 % long, as a focal-length error gives): auto keeps x, y.
    z_only = {
        k: dict(v, x_cm=v["truth_cm"][0], y_cm=v["truth_cm"][1], z_cm=v["truth_cm"][2] * 1.02)
        for k, v in biased.items()
    }
    model = fit(kind, z_only)
    assert model["coefficients"]["along_ray"] is False
    out = errors(apply_all(model, z_only))
    assert np.all(np.abs(out[:, :2]) < 1e-9)
    assert fit(kind, z_only, xy="along_ray")["coefficients"]["along_ray"] is True


def test_xyz_model_off_the_training_surface_is_extrapolated():
    # Balls on a table train the xyz model; inside its (u, v, d) box but 6 cm above the table it is
    # unconstrained, so apply must flag the location (and the pick refuses it), while a test ball on
    # the table is not flagged.
    table = make_locations(
        n=120,
        seed=5,
        baseline_scale=1.02,
        disparity_offset_px=0.5,
        noise_px=0.1,
        table_plane_cm=(12.0, -0.1),
    )
    model = fit("xyz", table)
    support = model["support"]
    assert (
        support["max_correction_cm"] > 0.1
        and min(np.subtract(support["max_cm"], support["min_cm"])) < 0.5
    )
    on_table = [loc for loc in table.values() if loc["split"] == "test"]
    flagged = [apply_model(model, loc)["extrapolated"] for loc in on_table]
    assert sum(flagged) <= 0.05 * len(on_table)
    # The same image position (u) and disparity, the ball 6 cm above the table: v moves by f * 6 /
    # z.
    base = max(
        (loc for loc in on_table if not apply_model(model, loc)["extrapolated"]),
        # near the camera: lifted, it stays in the image rows seen
        key=lambda loc: loc["v_left_px"],
    )
    f_px, cy = 800.0, 240.0
    lifted = dict(base, y_cm=base["y_cm"] - 6.0)
    lifted["v_left_px"] = cy + f_px * lifted["y_cm"] / lifted["z_cm"]
    vr = model["valid_range"]["v_left_px"]
    # inside the box: only the surface check can tell
    assert vr["min"] <= lifted["v_left_px"] <= vr["max"]
    got = apply_model(model, lifted)
    assert got["extrapolated"] is True
    assert any("surface" in why for why in got["compensation"]["outside_range"])


def test_support_flags_a_correction_larger_than_any_in_training(biased):
    model = fit("polynomial", biased)
    loc = dict(next(v for v in biased.values() if v["split"] == "test"))
    assert apply_model(model, loc)["extrapolated"] is False
    # Pretend the model was trained with tiny corrections: the same correction is now unsupported.
    tight = dict(
        model, support=dict(model["support"], max_correction_cm=0.01, residual_rms_cm=0.001)
    )
    got = apply_model(tight, loc)
    assert (
        got["extrapolated"] is True
        and "larger than any in training" in got["compensation"]["outside_range"][0]
    )


def test_a_correction_that_cross_validates_worse_than_none_is_refused():
    # (degree 8 on 13 placements: fitted residual 0.02 cm, held-out error 1.15 cm -- accepted
    # silently)
    few = make_locations(n=26, seed=5, noise_px=0.3, baseline_scale=1.0)
    with pytest.raises(NodeError, match="makes the results worse than none"):
        fit("polynomial", few, degree=8, outlier_mad=None)
    ok = fit(
        "polynomial",
        make_locations(n=160, seed=3, baseline_scale=1.02, disparity_offset_px=0.5),
        degree=2,
    )
    assert "skipped" not in ok["cv"]


def test_a_skipped_cross_validation_is_said(tmp_path):
    from stereograph.core.api import RunContext

    ctx = RunContext("fit", None, tmp_path, tmp_path)
    tiny = make_locations(n=8, seed=1, baseline_scale=1.02)
    fn = FIT_NODES["polynomial"]
    fn(fn.spec.params(figure=False, degree=1), train=tiny, ctx=ctx)
    assert any("cross-validation skipped" in m for m in ctx.messages)


def test_a_lookup_table_with_empty_bins_says_so_and_holds_only_where_its_bins_had_data(tmp_path):
    # (2 of 12 bins used 6 of 18 placements, and valid_range still claimed the whole training range)
    from stereograph.core.api import RunContext

    ctx = RunContext("fit", None, tmp_path, tmp_path)
    locs = make_locations(n=36, seed=2, baseline_scale=1.02)
    fn = FIT_NODES["lookup"]
    model = fn(fn.spec.params(figure=False, n_bins=12, outlier_mad=None), train=locs, ctx=ctx)[
        "model"
    ]
    z_train = [v["z_cm"] for v in locs.values() if v["split"] == "train"]
    kept = len(model["coefficients"]["knots_z_cm"])
    assert kept < 12 and any(f"only {kept} of 12 distance bins" in m for m in ctx.messages)
    rng = model["valid_range"]["z_cm"]
    assert rng["max"] - rng["min"] < max(z_train) - min(z_train)


@pytest.mark.parametrize("kind", ["polynomial", "disparity_curve", "lookup", "xyz"])
@pytest.mark.parametrize("mistake", ["mm", "frame"])
def test_a_truth_in_another_unit_or_frame_is_refused_not_fitted(biased, kind, mistake):
    # A truth.csv in mm, or table-frame numbers under x_cm,y_cm,z_cm: compensator.xyz fitted either
    # smoothly (cross-validation did not object) and moved every later ball by tens of cm.
    def wrong(t):
        return [10 * c for c in t] if mistake == "mm" else [t[0], t[2] - 40.0, 2.0]

    spoiled = {k: dict(v, truth_cm=wrong(v["truth_cm"])) for k, v in biased.items()}
    with pytest.raises(
        NodeError, match=r"truth is far from where the balls were located.*not mm"
    ) as exc:
        fit(kind, spoiled)
    assert f"compensator.{kind}" in exc.value.message


def test_when_most_training_balls_are_not_found_the_fix_is_about_finding_them():
    """(the Fix said 'more training placements, or fewer coefficients' while the reason it quoted --
    the ball's colour not found -- was the real cause)"""
    from nodes.contracts.compensator._common import training_samples
    from stereograph.core.api import NodeError

    train = {
        f"p{i}": {
            "split": "train",
            "found": False,
            "reason": "no plausible region (colour not seen)",
        }
        for i in range(20)
    }
    train["p99"] = {
        "split": "train",
        "found": True,
        "x_cm": 1.0,
        "y_cm": 2.0,
        "z_cm": 40.0,
        "truth_cm": [1.0, 2.0, 40.1],
    }
    with pytest.raises(NodeError) as e:
        training_samples(train, "node 'fit' (compensator.polynomial)", ("z_cm",), 6)
    assert "most training placements were not located (20 of 21)" in e.value.hint
    assert "colour not seen" in e.value.hint and "fewer coefficients" not in e.value.hint
