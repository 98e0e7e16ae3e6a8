"""`validate` reports every problem of a pipeline at once, each located (issue 14 item 3)."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereograph.app.cli import main
from stereograph.core.config import load_pipeline
from stereograph.core.errors import ConfigError, ConfigErrors
from stereograph.core.graph import build_graph, check_pipeline

ROOT = Path(__file__).resolve().parents[1]
LOCATE = ROOT / "pipelines" / "locate.yaml"


def _with_mistakes(tmp_path: Path, replacements: list[tuple[str, str]]) -> Path:
    text = LOCATE.read_text()
    for old, new in replacements:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / "locate.yaml"
    path.write_text(text)
    return path


def _line_of(path: Path, fragment: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if fragment in line)


THREE = [
    ("type: calibrator.chessboard", "type: calibrator.chesboard"),  # unknown node type
    # no such output
    ("pair: remap.rectified, rectification", "pair: remap.rectifed, rectification"),
    ("params: {frame: left_camera}", "params: {frme: left_camera}"),
]  # unknown parameter


def test_three_mistakes_give_three_located_errors_in_one_validate(tmp_path, capsys):
    path = _with_mistakes(tmp_path, THREE)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 3, err
    expected = [
        (_line_of(path, "calibrator.chesboard"), "calib", "did you mean 'calibrator.chessboard'"),
        (_line_of(path, "remap.rectifed"), "segment", "did you mean 'remap.rectified'"),
        (_line_of(path, "frme:"), "locate", "did you mean 'frame'"),
    ]
    for line, (lineno, node, fix) in zip(lines, expected):  # in file order
        assert f"{path}:{lineno}:" in line, line
        assert f"node '{node}'" in line, line
        assert "Fix:" in line and fix in line, line
    assert "3 problems" in err
    assert "Traceback" not in err


def test_check_pipeline_and_build_graph_return_every_problem(tmp_path):
    path = _with_mistakes(tmp_path, THREE)
    graph, problems = check_pipeline(path)
    assert graph is None and [p.node for p in problems] == ["calib", "segment", "locate"]
    with pytest.raises(ConfigErrors) as info:
        build_graph(load_pipeline(path))
    assert len(info.value.errors) == 3
    assert info.value.node == "calib"  # read as one ConfigError, it is the first problem


def test_a_node_declaration_problem_does_not_hide_the_others(tmp_path):
    # 'param:' for 'params:' is found while reading the file; the wiring mistake later still shows
    path = _with_mistakes(
        tmp_path,
        [
            ("params: {split: test,", "param: {split: test,"),
            ("pair: remap.rectified, rectification", "pair: remap.rectifed, rectification"),
        ],
    )
    graph, problems = check_pipeline(path)
    assert graph is None
    assert [(p.node, p.where.line) for p in problems] == [
        ("segment", _line_of(path, "remap.rectifed")),
        ("report", _line_of(path, "param: {split")),
    ]
    assert "unknown key 'param'" in problems[1].message and "params:" in problems[1].hint


def test_one_mistake_is_still_a_plain_config_error(tmp_path):
    path = _with_mistakes(tmp_path, THREE[2:])
    with pytest.raises(ConfigError) as info:
        build_graph(load_pipeline(path))
    assert not isinstance(info.value, ConfigErrors)
    assert info.value.where.line == _line_of(path, "frme:")


def test_several_bad_params_of_one_node_are_each_reported(tmp_path):
    path = _with_mistakes(
        tmp_path, [("n_scenes: 120, n_views: 16", "n_scenes: -1, n_views: sixteen")]
    )
    _, problems = check_pipeline(path)
    assert sorted(p.message.split("'")[1] for p in problems) == ["n_scenes", "n_views"]
    assert all(p.node == "rig" and p.hint for p in problems)


def test_a_valid_pipeline_has_no_problems():
    graph, problems = check_pipeline(LOCATE)
    assert problems == [] and graph is not None and "locate" in graph.nodes


def test_three_mistakes_give_three_located_errors_in_one_pass(tmp_path, capsys):
    """(a node whose params failed hid the wires below it: validate said '2 problems; fix them all',
    and the third appeared only after the others were fixed)"""
    text = (ROOT / "tests" / "old_style" / "locate.yaml").read_text()
    bad = (
        text.replace("n_views: 16", "n_view: 16")
        .replace("views: rig.views", "views: rig.view")
        .replace("type: disparity.centroid", "type: disparity.centriod")
    )
    assert bad.count("\n") == text.count("\n") and bad != text
    p = tmp_path / "locate.yaml"
    p.write_text(bad)
    assert main(["validate", str(p)]) == 2
    err = capsys.readouterr().err
    lines = {
        n: i + 1
        for i, line in enumerate(bad.splitlines())
        for n, key in (("rig", "n_view:"), ("calib", "rig.view}"), ("disparity", "centriod"))
        if key in line
    }
    for node, line in lines.items():
        assert f"locate.yaml:{line}:" in err and f"node '{node}'" in err, (node, line, err)
    assert "3 problems" in err, err


def test_a_bad_value_in_defaults_is_reported_at_its_own_line(tmp_path, capsys):
    text = (ROOT / "tests" / "old_style" / "locate.yaml").read_text()
    bad = text.replace("    working_range_cm: [20, 80]", "    working_range_cm: [80, 20]", 1)
    assert bad != text
    (tmp_path / "locate.yaml").write_text(bad)
    line = next(i + 1 for i, s in enumerate(bad.splitlines()) if "[80, 20]" in s)
    assert main(["validate", str(tmp_path / "locate.yaml")]) == 2
    err = capsys.readouterr().err
    assert f"locate.yaml:{line}:" in err and "from defaults" in err, err


def test_a_set_path_that_does_not_exist_is_refused_by_validate_naming_its_folder(
    tmp_path, capsys, monkeypatch
):
    (tmp_path / "bench" / "calib").mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    pipeline = ROOT / "pipelines" / "calibrate.yaml"
    argv = [
        "validate",
        str(pipeline),
        "--set",
        "rig.type=source.calib_files",
        "--set",
        "rig.folder=bench/calib",
    ]
    assert main(argv) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "--set rig.folder=bench/calib" in err and f"folder, {pipeline.parent})" in err, err
    assert f"Fix: --set rig.folder={tmp_path / 'bench' / 'calib'}" in err, err
    assert main(argv[:-1] + [f"rig.folder={tmp_path / 'bench' / 'calib'}"]) == 0
