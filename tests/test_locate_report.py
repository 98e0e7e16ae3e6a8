"""report.accuracy and the locate pipeline through the engine."""

import json
from pathlib import Path

import numpy as np
import pytest

from nodes.reports.accuracy import AccuracyParams, accuracy, error_table

ROOT = Path(__file__).resolve().parents[1]


def test_error_table_matches_numpy():
    rng = np.random.default_rng(0)
    true = rng.uniform(-10, 40, (50, 3))
    err = rng.normal([0.1, -0.2, 0.3], [0.05, 0.1, 0.2], (50, 3))
    t = error_table(true + err, true)
    for i, ax in enumerate("xyz"):
        assert t[ax]["mean_cm"] == pytest.approx(err[:, i].mean())
        assert t[ax]["std_cm"] == pytest.approx(err[:, i].std(ddof=1))
        assert t[ax]["max_abs_cm"] == pytest.approx(np.abs(err[:, i]).max())
        assert t[ax]["rms_cm"] == pytest.approx(np.sqrt((err[:, i] ** 2).mean()))


def _loc(pid, split, found, xyz, truth):
    return {
        "pair": pid,
        "found": found,
        "reason": None if found else "no region found",
        "split": split,
        "x_cm": xyz[0] if found else None,
        "y_cm": xyz[1] if found else None,
        "z_cm": xyz[2] if found else None,
        "sigma_z_cm": 0.01,
        "frame": "left_camera",
        "truth_cm": truth,
    }


def test_accuracy_node_filters_split_and_counts_not_found():
    locs = {
        "a": _loc("a", "test", True, [1.0, 2.0, 40.5], [1.0, 2.0, 40.0]),
        "b": _loc("b", "test", True, [0.0, 0.0, 30.3], [0.0, 0.0, 30.0]),
        "c": _loc("c", "test", False, None, [0.0, 0.0, 30.0]),
        "d": _loc("d", "train", True, [9.0, 9.0, 99.0], [0.0, 0.0, 30.0]),
    }
    out = accuracy(AccuracyParams(), locations=locs)
    rep = out["report"]
    assert (rep["n"], rep["n_found"], rep["n_evaluated"]) == (3, 2, 2)
    assert rep["axes"]["z"]["mean_cm"] == pytest.approx(0.4)
    assert rep["axes"]["x"]["max_abs_cm"] == pytest.approx(0.0)
    assert rep["not_found_reasons"] == {"no region found": 1}
    assert "| z | 0.400 |" in rep["markdown"]
    assert len(out["locations"]) == 4 and {r["pair"] for r in out["locations"]} == set("abcd")
    fig = out["figure"]
    assert fig.dtype == np.uint8 and fig.ndim == 3 and fig.shape[2] == 3
    all_ = accuracy(AccuracyParams(split="all", figure=False), locations=locs)["report"]
    assert all_["n"] == 4 and all_["axes"]["z"]["max_abs_cm"] == pytest.approx(69.0)


@pytest.mark.slow
def test_locate_pipeline_through_the_engine(tmp_path):
    from stereograph.core.runner import run_pipeline

    res = run_pipeline(
        ROOT / "pipelines" / "locate-truthcal.yaml",
        overrides=[
            "rig.n_scenes=8",
            "rig.n_views=0",
            "rig.train_fraction=0.0",
            "disparity.type=disparity.ellipse",
        ],
        cache_dir=tmp_path / "cache",
        out_dir=tmp_path / "out",
        use_cache=False,
    )
    assert res.ok, res.status
    rep = res.outputs("report", "report")
    assert rep["n"] == 8 and rep["n_found"] >= 7
    for ax in "xyz":
        assert abs(rep["axes"][ax]["mean_cm"]) < 0.1 and rep["axes"][ax]["max_abs_cm"] < 0.3
    out = tmp_path / "out"
    assert (out / "report" / "locations.json").exists() and (out / "report" / "figure.png").exists()
    # Out(lossy=True): a picture, as JPEG
    assert len(list((out / "segment" / "overlay").glob("*.jpg"))) == 8


@pytest.mark.slow
def test_hard_scenes_through_the_engine_never_crash(tmp_path):
    from stereograph.core.runner import run_pipeline

    kinds = "[clutter, second_ball, border, occluded, hidden, empty]"
    res = run_pipeline(
        ROOT / "pipelines" / "locate-truthcal.yaml",
        overrides=[
            "rig.n_scenes=0",
            f"rig.hard_cases={kinds}",
            "rig.n_hard_each=1",
            "report.split=all",
        ],
        cache_dir=tmp_path / "cache",
        out_dir=tmp_path / "out",
        use_cache=False,
    )
    assert res.ok, res.status
    locs = {r["pair"]: r for r in res.outputs("report", "locations")}
    assert len(locs) == 6
    for pid in ("empty000", "hidden000"):
        assert locs[pid]["found"] is False and locs[pid]["reason"]
    for r in locs.values():  # whatever is reported as found must be right
        if r["found"]:
            assert (
                np.linalg.norm(np.subtract([r["x_cm"], r["y_cm"], r["z_cm"]], r["truth_cm"])) < 0.5
            )


def test_the_markdown_table_is_an_output_and_names_extrapolated_results():
    # (accuracy.md was written beside the outputs only when the node computed: a cached report's run
    # folder had none; extrapolated results were averaged into it without a word)
    locs = {
        "a": _loc("a", "test", True, [1.0, 2.0, 40.5], [1.0, 2.0, 40.0]),
        "b": {**_loc("b", "test", True, [0.0, 0.0, 70.3], [0.0, 0.0, 70.0]), "extrapolated": True},
    }
    out = accuracy(AccuracyParams(), locations=locs)
    md = out["accuracy"]["file_text"]
    assert out["accuracy"]["file_suffix"] == ".md" and md.startswith("### ") and "| axis |" in md
    assert "1 of the 2 evaluated results were corrected outside the range" in md
    assert out["report"]["markdown"] == md


@pytest.mark.slow
def test_a_cached_report_still_writes_accuracy_md(tmp_path):
    from stereograph.core.runner import run_pipeline

    locate = Path(__file__).resolve().parent.parent / "pipelines" / "locate.yaml"
    for out in ("o1", "o2"):  # the second run: every node from the cache
        r = run_pipeline(
            locate, ["rig.n_scenes=4"], cache_dir=tmp_path / "c", out_dir=tmp_path / out
        )
        assert r.ok
    assert r.status["report"] == "cached" and (tmp_path / "o2" / "report" / "accuracy.md").is_file()


def test_not_found_reasons_are_grouped_by_kind_with_their_numbers_as_ranges():
    """(twenty pairs refused for one shared cause -- swapped images: 'different rows (dv = 6.9 px)',
    '(dv = 11.2 px)', ... -- were twenty distinct reasons of one pair each, and the Markdown said
    none)"""
    from collections import Counter

    from nodes.contracts.reasons import group_reasons

    rows = [
        f"left/right regions are on different rows (dv = {dv} px): swapped?"
        for dv in (6.9, 11.2, 3.6, 6.9)
    ]
    assert group_reasons(Counter([*rows, "no region found", "ratio 1.2.", "ratio 1.5."])) == [
        ("left/right regions are on different rows (dv = 3.6–11.2 px): swapped?", 4),
        ("ratio 1.2–1.5.", 2),
        ("no region found", 1),
    ]
    assert group_reasons(
        Counter(["scene s001 of DICT_4X4_50 (9x6)", "scene s002 of DICT_4X4_50 (9x6)"])
    ) == [
        # ids are not numbers
        ("scene s001 of DICT_4X4_50 (9x6)", 1),
        ("scene s002 of DICT_4X4_50 (9x6)", 1),
    ]
    locs = {
        f"p{i}": {**_loc(f"p{i}", "test", False, None, [0.0, 0.0, 30.0]), "reason": r}
        for i, r in enumerate([*rows, "no region found"])
    }
    rep = accuracy(AccuracyParams(figure=False), locations=locs)["report"]
    assert len(rep["not_found_reasons"]) == 4  # the exact strings, as before
    assert rep["not_found_kinds"][0] == {"reason": rows[0].replace("6.9", "3.6–11.2"), "count": 4}
    assert (
        "Not found (5 pairs)" in rep["markdown"] and "- 4 × left/right regions" in rep["markdown"]
    )


def test_an_overlay_switched_off_writes_no_file_and_no_link(tmp_path):
    """Off means off: no 1x1 placeholder saved, linked from the page or logged."""
    from stereograph.core.runner import run_pipeline

    res = run_pipeline(
        Path(__file__).resolve().parents[1] / "pipelines" / "locate.yaml",
        [
            "rig.n_scenes=3",
            "rig.n_views=6",
            "segment.overlay=false",
            "locate.overlay=false",
            "report.figure=false",
        ],
        cache_dir=tmp_path / "c",
        out_dir=tmp_path / "run",
    )
    written = sorted(str(p.relative_to(res.out_dir)) for p in res.out_dir.rglob("*") if p.is_file())
    assert not [f for f in written if "overlay" in f or f.startswith("report/figure")], written
    assert "report/accuracy.md" in written
    assert 'data-output="overlay"' not in (res.out_dir / "report.html").read_text()
    run = json.loads((res.out_dir / "run.json").read_text())
    assert not [f for n in run["nodes"] for f in n.get("files", []) if "overlay" in f]
