"""Training placements chosen by a truth file (source.files), pair ids from file names."""

import cv2
import numpy as np
import pytest

from nodes.sources._files import list_pairs, pair_key
from nodes.sources.files import FilesParams, files
from stereograph.core.api import NodeError, RunContext


def _images(folder, names):
    """Small grey PNGs of these file names in ``folder`` (what list_pairs matches by name)."""
    img = np.full((24, 32, 3), 90, np.uint8)
    for name in names:
        cv2.imwrite(str(folder / name), img)


def _folder(tmp_path, ids=("01", "02", "03")):
    _images(tmp_path, [f"{side}{i}.png" for i in ids for side in ("left", "right")])
    return tmp_path


def _run(tmp_path, truth_text, name="truth.csv", **kw):
    (tmp_path / name).write_text(truth_text)
    ctx = RunContext("rig", None, tmp_path / "out", tmp_path)
    pairs = files(FilesParams(folder=".", truth=name, **kw), ctx=ctx)["pairs"]
    return pairs, ctx.messages


def test_listed_pairs_train_others_are_targets_with_warnings(tmp_path):
    _folder(tmp_path)
    pairs, msgs = _run(
        tmp_path, "id,x_cm,y_cm,z_cm\n01,1,2,40\n02,0,0,45\n09,0,0,50\n", train_fraction=0.0
    )
    assert {k: v["split"] for k, v in pairs.items()} == {"01": "train", "02": "train", "03": "test"}
    assert (
        pairs["01"]["truth"]["center_left_cm"] == [1.0, 2.0, 40.0] and pairs["03"]["truth"] is None
    )
    assert any("09" in m and "no images" in m for m in msgs)
    assert any("03" in m and "no row" in m for m in msgs)


def test_a_truth_file_that_matches_no_pair_is_refused(tmp_path):
    # (accepted: an accuracy report with every figure blank, the mismatch only in run.json)
    _folder(tmp_path)
    with pytest.raises(
        NodeError, match=r"none of the 3 pairs has a row in truth.csv: its ids \(s01, s02\)"
    ):
        _run(tmp_path, "id,x_cm,y_cm,z_cm\ns01,1,2,40\ns02,0,0,45\n", train_fraction=0.0)
    # a spreadsheet turns 01 into 1
    with pytest.raises(
        NodeError, match=r"match once leading zeros are ignored: a spreadsheet dropped them"
    ):
        _run(tmp_path, "id,x_cm,y_cm,z_cm\n1,1,2,40\n2,0,0,45\n", train_fraction=0.0)


def test_split_column_rules(tmp_path):
    _folder(tmp_path)
    csv = "id,table_x_cm,table_y_cm,table_z_cm,split\n01,1,2,2,test\n02,0,5,2,train\n03,3,3,2,\n"
    pairs, _ = _run(tmp_path, csv)
    assert {k: v["split"] for k, v in pairs.items()} == {"01": "test", "02": "train", "03": "train"}
    assert pairs["01"]["truth"]["center_table_cm"] == [1.0, 2.0, 2.0]
    assert pairs["01"]["truth"]["center_left_cm"] is None
    pairs, _ = _run(
        tmp_path, '{"01": {"center_left_cm": [0, 0, 40], "split": "test"}}', name="t.json"
    )
    assert {k: v["split"] for k, v in pairs.items()} == {"01": "test", "02": "test", "03": "test"}


def test_bad_truth_rows_name_file_and_line(tmp_path):
    _folder(tmp_path)
    with pytest.raises(NodeError, match=r"truth.csv, line 3: split is 'val'"):
        _run(tmp_path, "id,x_cm,y_cm,z_cm,split\n01,1,2,40,train\n02,1,2,40,val\n")
    with pytest.raises(NodeError, match=r"line 2: x_cm, y_cm, z_cm must be numbers"):
        _run(tmp_path, "id,x_cm,y_cm,z_cm\n01,1,two,40\n")
    # (a repeated pair silently replaced the earlier row; a bad radius was said without its line)
    with pytest.raises(
        NodeError, match=r"truth.csv, line 4: pair 01 is listed again \(first on line 2\)"
    ):
        _run(tmp_path, "id,x_cm,y_cm,z_cm\n01,1,2,40\n02,0,0,45\n01,0,0,50\n")
    with pytest.raises(
        NodeError, match=r"truth.csv, line 2: radius_cm must be a number, got 'two'"
    ):
        _run(tmp_path, "id,x_cm,y_cm,z_cm,radius_cm\n01,1,2,40,two\n")
    with pytest.raises(NodeError, match=r"no `id` column .*separated by ';', not commas"):
        _run(tmp_path, "id;x_cm;y_cm;z_cm\n01;1;2;40\n")


def test_a_truth_file_saved_by_excel_with_a_byte_order_mark_is_read(tmp_path):
    # (Excel's "CSV UTF-8" starts with U+FEFF: refused as 'no `id` column (header: id, ...)')
    _folder(tmp_path)
    pairs, _ = _run(tmp_path, "\ufeffid,x_cm,y_cm,z_cm\n01,1,2,40\n", train_fraction=0.0)
    assert (
        pairs["01"]["truth"]["center_left_cm"] == [1.0, 2.0, 40.0]
        and pairs["01"]["split"] == "train"
    )
    pairs, _ = _run(
        tmp_path, '\ufeff{"01": {"center_left_cm": [0, 0, 40]}}', name="t.json", train_fraction=0.0
    )
    assert pairs["01"]["truth"]["center_left_cm"] == [0, 0, 40]


def test_pair_id_rule():
    assert (
        pair_key("left01") == "01"
        and pair_key("007_left") == "007"
        and pair_key("scene3-R") == "scene3"
    )


def test_no_match_for_the_globs_suggests_the_globs_the_names_need(tmp_path):
    # (s000_left.png, a naming docs/bench.md gives, met "no images match 'left*'" and no more)
    _images(tmp_path, ["s000_left.png", "s000_right.png"])
    with pytest.raises(NodeError) as e:
        list_pairs(tmp_path, "left*", "right*")
    assert "left_glob: '*left*'" in e.value.hint and "s000_left.png" in e.value.hint


def test_a_truth_header_without_centre_columns_is_said_as_a_header_problem(tmp_path):
    # (`id,x_mm,y_mm,z_mm` was "line 2: pair 01 has no centre")
    _folder(tmp_path)
    with pytest.raises(NodeError, match=r"has no centre columns \(header: id, x_mm, y_mm, z_mm\)"):
        _run(tmp_path, "id,x_mm,y_mm,z_mm\n01,10,20,400\n")


def test_the_suggested_globs_match_capitalised_names(tmp_path):
    # (Left01.png / Right01.png were told to use '*left*', which matches nothing: globs are
    # case-sensitive)
    _images(tmp_path, ["Left01.png", "Right01.png"])
    with pytest.raises(NodeError) as e:
        list_pairs(tmp_path, "left*", "right*")
    assert "left_glob: '*Left*'" in e.value.hint and "right_glob: '*Right*'" in e.value.hint
    # the advice works
    assert [k for k, _, _ in list_pairs(tmp_path, "*Left*", "*Right*")] == ["01"]


def test_names_without_a_side_token_pair_by_what_the_globs_matched(tmp_path):
    # (cam0_01.png / cam1_01.png with globs cam0* / cam1*: "these images have no partner:
    # cam0_01.png, ...")
    _images(tmp_path, [f"{cam}_{i}.png" for cam in ("cam0", "cam1") for i in ("01", "02", "10")])
    for lg, rg in (("cam0*", "cam1*"), ("cam0_*.png", "cam1_*.png")):
        got = list_pairs(tmp_path, lg, rg)
        assert [(k, a.name, b.name) for k, a, b in got] == [
            (i, f"cam0_{i}.png", f"cam1_{i}.png") for i in ("01", "02", "10")
        ]
    # a real mismatch is still refused, named
    (tmp_path / "cam1_10.png").rename(tmp_path / "cam1_11.png")
    with pytest.raises(NodeError, match=r"no partner: cam0_10.png, cam1_11.png \("):
        list_pairs(tmp_path, "cam0*", "cam1*")


def test_unknown_truth_columns_are_refused_naming_them_and_the_known_ones(tmp_path):
    # (`radius` for radius_cm, a typo'd tabel_z_cm beside x_cm,y_cm,z_cm: both were read as absent,
    # silently)
    _folder(tmp_path)
    with pytest.raises(
        NodeError,
        match=r"truth.csv has column\(s\) it does not know: 'radius' \(did you mean "
        r"'radius_cm'\?\); they would be ignored\. Known columns: id, x_cm",
    ):
        _run(tmp_path, "id,x_cm,y_cm,z_cm,radius\n01,1,2,40,2\n")
    with pytest.raises(NodeError, match=r"'tabel_z_cm' \(did you mean 'table_z_cm'\?\)"):
        _run(tmp_path, "id,x_cm,y_cm,z_cm,tabel_z_cm\n01,1,2,40,2\n")
    with pytest.raises(NodeError, match=r"column\(s\) x_cm twice"):
        _run(tmp_path, "id,x_cm,y_cm,z_cm,x_cm\n01,1,2,40,3\n")
    with pytest.raises(NodeError, match=r"line 2: value\(s\) '7' stand under no column name"):
        _run(tmp_path, "id,x_cm,y_cm,z_cm\n01,1,2,40,7\n")
    # an empty trailing column (a spreadsheet's) is harmless and still read
    pairs, _ = _run(tmp_path, "id,x_cm,y_cm,z_cm,\n01,1,2,40,\n", train_fraction=0.0)
    assert pairs["01"]["truth"]["center_left_cm"] == [1.0, 2.0, 40.0]


def test_duplicate_json_ids_are_refused_naming_the_id(tmp_path):
    # (json.loads kept the last of two "01" records, silently)
    _folder(tmp_path)
    with pytest.raises(NodeError, match=r"t.json: id '01' is given twice"):
        _run(
            tmp_path,
            '{"01": {"center_left_cm": [0, 0, 40]}, "01": {"center_left_cm": [0, 0, 50]}}',
            name="t.json",
        )
    with pytest.raises(NodeError, match=r"t.json: id '02' is given twice"):
        _run(
            tmp_path,
            '[{"id": "02", "center_left_cm": [0, 0, 40]}, {"id": "02", "center_left_cm": '
            "[1, 0, 40]}]",
            name="t.json",
        )
    with pytest.raises(NodeError, match=r"t.json: field 'center_left_cm' is given twice"):
        _run(
            tmp_path,
            '{"01": {"center_left_cm": [0, 0, 40], "center_left_cm": [0, 0, 50]}}',
            name="t.json",
        )


def test_a_json_record_key_the_reader_does_not_know_is_refused(tmp_path):
    # ('center_cm' was ignored: the pair then had no truth, and the fit or the report said little
    # why)
    _folder(tmp_path)
    with pytest.raises(
        NodeError,
        match=r"t.json, id 01, has key\(s\) it does not know: 'center_cm' \(did you mean "
        r"'center_left_cm'\?\)",
    ) as e:
        _run(tmp_path, '{"01": {"center_cm": [0, 0, 40]}}', name="t.json")
    assert "Known keys: id, center_left_cm, center_table_cm, radius_cm, split" in e.value.message
    with pytest.raises(NodeError, match=r"'radius' \(did you mean 'radius_cm'\?\)"):
        _run(tmp_path, '[{"id": "02", "center_left_cm": [0, 0, 40], "radius": 2}]', name="t.json")
    _run(
        tmp_path,
        '[{"id": "02", "center_left_cm": [0, 0, 40], "radius_cm": 2, "split": "train"}]',
        name="t.json",
    )
