"""The documented Python API (issue 14 item 4): docs/python.md's example runs as written."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

import stereograph
from stereograph.core.errors import ConfigError, ConfigErrors

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "python.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


@pytest.fixture
def project(tmp_path, monkeypatch):
    """A folder laid out like the repository (pipelines/), so the cache and runs stay in tmp."""
    (tmp_path / "pipelines").mkdir()
    # the project root: its cache and runs/ (docs/cache.md)
    (tmp_path / "pyproject.toml").write_text("")
    shutil.copy(ROOT / "pipelines" / "locate-truthcal.yaml", tmp_path / "pipelines")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.slow
def test_the_documented_example_runs(project, capsys):
    blocks = _python_blocks(DOC.read_text())
    assert len(blocks) == 1
    exec(compile(blocks[0], str(DOC), "exec"), {"__name__": "docs_python_example"})
    out = capsys.readouterr().out
    assert "<stereograph.Result" in out and ": ok;" in out
    assert "x, y, z (cm):" in out or "not found:" in out
    assert "10 segmentations" in out
    assert out.count("z RMS (cm):") == 2  # one row per variant
    # the runs went to the project's runs/
    assert list((project / "runs" / "locate-truthcal").iterdir())


@pytest.mark.slow
def test_result_access_and_its_errors(project):
    res = stereograph.run("pipelines/locate-truthcal.yaml", {"rig.n_scenes": 4}, progress=False)
    assert res.ok and set(res.status) >= {"rig", "locate", "report"}
    assert set(res.outputs("locate", "location")) == {"s000", "s001", "s002", "s003"}
    assert "report" in res["report"]
    masks = res["segment"]["segmentation"]  # not terminal, not saved: loaded from the cache
    assert set(masks) == {"s000", "s001", "s002", "s003"}
    with pytest.raises(KeyError, match="no node 'segmnt'"):
        res.outputs("segmnt", "segmentation")
    with pytest.raises(KeyError, match="has no output 'mask'"):
        res.outputs("segment", "mask")
    again = stereograph.run("pipelines/locate-truthcal.yaml", ["rig.n_scenes=4"], progress=False)
    assert again.ran == set() and "segment" in again.nodes  # all cached
    assert again.raise_for_errors() is again
    nocache = stereograph.run(
        "pipelines/locate-truthcal.yaml",
        {"rig.n_scenes": 4},
        use_cache=False,
        keep=["disparity"],
        progress=False,
    )
    assert set(nocache.outputs("disparity", "disparity")) == set(masks)  # kept in memory
    with pytest.raises(KeyError, match="keep="):
        nocache["segment"]  # no cache to load it from, and not kept


def test_a_bad_pipeline_raises_every_problem(project):
    bad = {"segment.canny_lo": 40, "rig.n_scenes": -1}
    assert len(stereograph.check("pipelines/locate-truthcal.yaml", bad)) == 2
    with pytest.raises(ConfigErrors) as info:
        stereograph.run("pipelines/locate-truthcal.yaml", bad, progress=False)
    assert {e.node for e in info.value.errors} == {"segment", "rig"}
    with pytest.raises(ConfigError, match="keep= names nodes"):
        stereograph.run("pipelines/locate-truthcal.yaml", keep=["nosuch"], progress=False)


def test_compare_is_a_plain_function_of_the_package():
    import types

    from stereograph.app.pyapi import compare

    assert isinstance(stereograph.compare, types.FunctionType) and stereograph.compare is compare


def test_bad_arguments_of_the_python_api_are_clear_errors(project):
    """(they were: workers=0 silently serial, workers='abc' a TypeError from inside the runner,
    set=5 "'int' object is not iterable", a set= value that is not plain a bare TypeError, and a
    one-string vary= split letter by letter)"""
    path = "pipelines/locate-truthcal.yaml"
    for bad in (0, -1, "abc", 1.5, True):
        with pytest.raises(ConfigError, match="workers= must be a whole number"):
            stereograph.run(path, {"rig.n_scenes": 2}, workers=bad, progress=False)
    with pytest.raises(ConfigError, match="set= must be a mapping or a list"):
        stereograph.run(path, 5, progress=False)
    with pytest.raises(ConfigError, match="set= value of 'rig.n_scenes' is not a plain value"):
        stereograph.check(path, {"rig.n_scenes": object()})
    with pytest.raises(ConfigError, match="not a plain value"):
        stereograph.check(path, {"rig.min_distance_cm": float("nan")})
    with pytest.raises(ConfigError, match="vary= values of 'rig.seed' must be a list"):
        stereograph.compare(path, {"rig.seed": "1"}, progress=False)
    from stereograph.app.pyapi import _set_texts

    assert _set_texts("rig.seed=0,1", "vary") == ["rig.seed=0,1"]  # one --vary, not one per letter
