"""Every bad config: exit code 2 and one message with file:line and the node's name."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from stereograph.app.cli import main

TOY = Path(__file__).parent / "plugins" / "toy.py"

GOOD = f"""\
name: t
plugins: [{TOY}]
nodes:
  numbers:
    type: toy.numbers
    params: {{n: 3, size: 4}}
  power:
    type: toy.power
    params: {{power: 2}}
    inputs: {{m: numbers.items}}
  total:
    type: toy.sum
    inputs: {{values: power.norm}}
"""


def run_cli(tmp_path: Path, text: str, *extra: str, capsys) -> tuple[int, str]:
    f = tmp_path / "p.yaml"
    f.write_text(textwrap.dedent(text))
    code = main(["validate", str(f), *extra])
    out = capsys.readouterr()
    return code, " ".join((out.out + out.err).split())


def test_good_pipeline_validates(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD, capsys=capsys)
    assert code == 0, msg
    assert "OK" in msg


def test_broken_yaml_names_line(tmp_path, capsys):
    code, msg = run_cli(
        tmp_path, GOOD.replace("params: {power: 2}", "params: {power: 2"), capsys=capsys
    )
    assert code == 2
    assert "p.yaml:" in msg and "not valid YAML" in msg


def test_unknown_node_type_did_you_mean(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD.replace("type: toy.power", "type: toy.powr"), capsys=capsys)
    assert code == 2
    assert "p.yaml:8" in msg and "node 'power'" in msg
    assert "unknown node type 'toy.powr'" in msg and "did you mean 'toy.power'" in msg


def test_a_misspelt_pipeline_path_names_the_closest_file(tmp_path, capsys):
    (tmp_path / "locate.yaml").write_text(GOOD)
    (tmp_path / "pick.yaml").write_text(GOOD)
    assert main(["validate", str(tmp_path / "locat.yaml")]) == 2
    msg = " ".join(capsys.readouterr().err.split())
    assert "pipeline file not found" in msg and "did you mean 'locate.yaml'?" in msg
    assert main(["validate", str(tmp_path / "zzz.yaml")]) == 2  # nothing close: the folder's files
    msg = " ".join(capsys.readouterr().err.split())
    assert "pipeline files in" in msg and "'locate.yaml', 'pick.yaml'" in msg
    assert main(["validate", str(tmp_path / "none" / "a.yaml")]) == 2
    assert "Fix: check the path." in " ".join(capsys.readouterr().err.split())


def test_unknown_param(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD.replace("{power: 2}", "{pwer: 2}"), capsys=capsys)
    assert code == 2
    assert (
        "p.yaml:9" in msg
        and "node 'power'" in msg
        and "'pwer'" in msg
        and "did you mean 'power'" in msg
    )


def test_mistyped_param(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD.replace("{power: 2}", "{power: two}"), capsys=capsys)
    assert code == 2
    assert (
        "p.yaml:9" in msg
        and "node 'power'" in msg
        and "parameter 'power'" in msg
        and "'two'" in msg
    )


def test_param_out_of_range(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD.replace("{power: 2}", "{power: 0}"), capsys=capsys)
    assert code == 2
    assert "node 'power'" in msg and "greater than or equal to 1" in msg


def test_dangling_input_node(tmp_path, capsys):
    code, msg = run_cli(
        tmp_path, GOOD.replace("m: numbers.items", "m: numbrs.items"), capsys=capsys
    )
    assert code == 2
    assert (
        "p.yaml:10" in msg
        and "node 'power'" in msg
        and "'numbrs'" in msg
        and "did you mean 'numbers'" in msg
    )


def test_dangling_input_output(tmp_path, capsys):
    code, msg = run_cli(
        tmp_path, GOOD.replace("m: numbers.items", "m: numbers.item"), capsys=capsys
    )
    assert code == 2
    assert "p.yaml:10" in msg and "has no output 'item'" in msg and "numbers.items" in msg


def test_mistyped_input(tmp_path, capsys):
    code, msg = run_cli(
        tmp_path, GOOD.replace("values: power.norm", "values: power.m"), capsys=capsys
    )
    assert code == 2
    assert (
        "p.yaml:13" in msg
        and "node 'total'" in msg
        and "wants Number but 'power.m' gives Matrix" in msg
    )


def test_input_accepting_alternatives_names_them_all(tmp_path, capsys):
    text = GOOD + "  what:\n    type: toy.describe\n    inputs: {x: total.total}\n"
    assert run_cli(tmp_path, text, capsys=capsys)[0] == 0  # Number is one of the alternatives
    bad = GOOD.replace(
        "  total:\n", "  what:\n    type: toy.describe\n    inputs: {x: numbers.items}\n  total:\n"
    )
    assert run_cli(tmp_path, bad, capsys=capsys)[0] == 0  # so is Matrix (per item)
    code, msg = run_cli(tmp_path, text.replace("x: total.total", "x: what.kind"), capsys=capsys)
    assert code == 2  # a Report is neither (and wiring a node to itself is refused first or after)
    code, msg = run_cli(
        tmp_path,
        GOOD + "  tbl:\n    type: toy.table\n    inputs: {m: numbers.items}\n"
        "  what:\n    type: toy.describe\n    inputs: {x: tbl.report}\n",
        capsys=capsys,
    )
    assert code == 2
    assert "node 'what'" in msg and "wants Matrix or Number but 'tbl.report' gives Report" in msg


def test_missing_required_input(tmp_path, capsys):
    code, msg = run_cli(
        tmp_path, GOOD.replace("    inputs: {values: power.norm}\n", ""), capsys=capsys
    )
    assert code == 2
    assert "node 'total'" in msg and "required input 'values'" in msg


def test_cycle_is_named(tmp_path, capsys):
    text = f"""\
    name: t
    plugins: [{TOY}]
    nodes:
      a:
        type: toy.power
        inputs: {{m: b.m}}
      b:
        type: toy.power
        inputs: {{m: a.m}}
    """
    code, msg = run_cli(tmp_path, text, capsys=capsys)
    assert code == 2
    assert "cycle" in msg and ("a -> b -> a" in msg or "b -> a -> b" in msg)


def test_set_override_validated_by_the_same_model(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD, "--set", "power.power=-3", capsys=capsys)
    assert code == 2
    assert "--set power.power=-3" in msg and "node 'power'" in msg


def test_set_unknown_node(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD, "--set", "pwr.power=3", capsys=capsys)
    assert code == 2
    assert "no node named 'pwr'" in msg and "did you mean 'power'" in msg


def test_unknown_key_in_node(tmp_path, capsys):
    code, msg = run_cli(
        tmp_path, GOOD.replace("    params: {power: 2}", "    parms: {power: 2}"), capsys=capsys
    )
    assert code == 2
    assert "p.yaml:9" in msg and "unknown key 'parms'" in msg


def test_missing_pipeline_file(tmp_path, capsys):
    code = main(["run", str(tmp_path / "nope.yaml")])
    out = capsys.readouterr()
    assert code == 2
    assert "not found" in out.err


@pytest.mark.parametrize("cmd", ["graph", "explain"])
def test_other_commands_share_validation(tmp_path, capsys, cmd):
    f = tmp_path / "p.yaml"
    f.write_text(GOOD.replace("type: toy.power", "type: toy.powr"))
    assert main([cmd, str(f)]) == 2
    assert "did you mean" in capsys.readouterr().err


def test_nested_params_merge_into_their_default(tmp_path, capsys):
    plug = tmp_path / "nested.py"
    plug.write_text(
        textwrap.dedent("""\
        from stereograph.core.api import node, Out, Params, Field

        class Joint(Params):
            min_deg: float = Field(..., description="Lower limit (deg).")
            max_deg: float = Field(..., description="Upper limit (deg).")

        class ArmP(Params):
            yaw: Joint = Field(default_factory=lambda: Joint(min_deg=-150, max_deg=150),
                               description="Yaw.")

        @node("tmp.arm", outputs={"arm": Out("Arm")}, params=ArmP)
        def arm(params):
            return {"arm": params.model_dump()}
        """)
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: n\nplugins: [{plug}]\nnodes:\n  arm:\n    type: tmp.arm\n"
        "    params: {yaw: {max_deg: 90}}\n"
    )
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    g = build_graph(load_pipeline(f, ["arm.yaw.min_deg=-100"]))
    assert g.nodes["arm"].params.yaw.min_deg == -100 and g.nodes["arm"].params.yaw.max_deg == 90
    assert main(["validate", str(f), "--set", "arm.yaw.min_deg=low"]) == 2
    assert "yaw.min_deg" in capsys.readouterr().err


def test_unused_outputs_are_warned_unless_optional(tmp_path, capsys):
    code, msg = run_cli(tmp_path, GOOD, capsys=capsys)
    assert code == 0
    assert "node 'power': output 'm' is never used" in msg  # power.norm is wired, power.m is not
    assert "'items' is never used" not in msg


LOCATE = Path(__file__).resolve().parent.parent / "pipelines" / "locate.yaml"
# the old style: the object given per segmenter type in `defaults:` (still supported)
LOCATE_OLD = Path(__file__).resolve().parent / "old_style" / "locate.yaml"


def test_a_nested_param_given_on_the_node_keeps_the_other_fields_of_the_pipelines_defaults(
    tmp_path,
):
    # locate.yaml's `defaults:` give the segmenters object: {radius_cm: 2, color_bgr: orange};
    # setting only the radius (a 5 cm ball) dropped the colour, and the segmenter then refused every
    # pair of a plain 5 cm ball as "ambiguous ... give object.color_bgr" (20/20 not found, now 20/20
    # found)
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    obj = (
        build_graph(load_pipeline(LOCATE_OLD, ["segment.object.radius_cm=5"]))
        .nodes["segment"]
        .params.object
    )
    assert obj.radius_cm == 5 and tuple(obj.color_bgr) == (20, 120, 245)
    # the same through an include: nested params and nested defaults merge field by field
    (tmp_path / "common.yaml").write_text(
        "defaults:\n  segmenter.color: {object: {radius_cm: 2.0, color_bgr: [1, 2, 3]}}\n"
        "nodes:\n  seg:\n    type: segmenter.color\n    params: {object: "
        "{color_tolerance: 0.2}, overlay: false}\n"
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        "name: n\ninclude: [common.yaml]\ndefaults:\n  segmenter.color: {object: "
        "{min_saturation: 9}}\n"
        "nodes:\n  seg:\n    type: segmenter.color\n    params: {object: {radius_cm: 3.0}}\n"
    )
    doc = load_pipeline(f)
    want = {"object": {"radius_cm": 2.0, "color_bgr": [1, 2, 3], "min_saturation": 9}}
    assert doc.defaults["segmenter.color"] == want
    assert doc.nodes["seg"]["params"] == {
        "object": {"color_tolerance": 0.2, "radius_cm": 3.0},
        "overlay": False,
    }
    # null still unsets one field
    obj = (
        build_graph(load_pipeline(LOCATE_OLD, ["segment.object.color_bgr=null"]))
        .nodes["segment"]
        .params.object
    )
    assert obj.color_bgr is None and obj.radius_cm == 2.0


def _validate(*argv: str, capsys, pipeline: Path = LOCATE) -> tuple[int, str]:
    code = main(["validate", str(pipeline), *argv])
    out = capsys.readouterr()
    return code, " ".join((out.out + out.err).split())


def test_a_set_list_value_is_blamed_on_the_set_not_on_the_file_line_it_replaced(capsys):
    # dense-aloe.yaml gives dense.working_range_cm as a list in the node's params; an error in the
    # value given by --set must not point at that line (the lines of its items were the file's)
    dense = LOCATE.parent / "dense-aloe.yaml"
    code, msg = _validate(
        "--set", "dense.working_range_cm=[.nan,200]", capsys=capsys, pipeline=dense
    )
    assert (
        code == 2
        and msg.startswith("error: --set dense.working_range_cm=[.nan,200]:")
        and ".yaml:" not in msg
    )
    code, msg = _validate("--set", "dense.working_range_cm=[120]", capsys=capsys, pipeline=dense)
    assert (
        code == 2
        and msg.startswith("error: --set dense.working_range_cm=[120]:")
        and ".yaml:" not in msg
    )


def test_a_nested_parameter_error_shows_the_nested_fields_own_description(capsys):
    code, msg = _validate("--set", "segment.shadow.max_brightness_ratio=3", capsys=capsys)
    assert (
        code == 2
        and "Fix: 'shadow.max_brightness_ratio' is float: A shadow pixel is at most" in msg
    )
    code, msg = _validate("--set", "segment.object.color_bgr=[300,0,0]", capsys=capsys)
    assert code == 2 and "'object.color_bgr.0'" in msg and "less than or equal to 255" in msg
    assert "Fix: 'object.color_bgr' is" in msg and "B, G, R in 0-255" in msg


@pytest.mark.parametrize("value", ["[-20,120,245]", "[20,120,256]"])
def test_a_colour_outside_0_255_is_refused_before_anything_runs(value, capsys):
    # (it was accepted, and every pair then failed "colour differs from the object's")
    code, msg = _validate("--set", f"segment.object.color_bgr={value}", capsys=capsys)
    assert code == 2 and "node 'segment'" in msg
    code, msg = _validate("--set", "segment.object.hue_range_deg=[400,20]", capsys=capsys)
    assert code == 2 and "less than or equal to 360" in msg


def test_a_node_check_on_its_wiring_runs_at_validation(capsys):
    # segmenter.color needs a colour from its params or its `appearance` input: said by `validate`
    # (exit 2, the node and the --set named), not found when every item fails
    # (locate.yaml's defaults give every segmenter type the colour: unset it)
    code, msg = _validate(
        "--set",
        "segment.type=segmenter.color",
        "--set",
        "segment.object.color_bgr=null",
        capsys=capsys,
        pipeline=LOCATE_OLD,
    )
    assert code == 2 and "node 'segment'" in msg and "needs the object's colour" in msg
    assert "segment.object.color_bgr=null" in msg and "appearance" in msg
    code, msg = _validate(
        "--set",
        "segment.type=segmenter.color",
        "--set",
        "segment.object.color_bgr=null",
        "--set",
        "segment.object.hue_range_deg=[10,40]",
        capsys=capsys,
        pipeline=LOCATE_OLD,
    )
    assert code == 0, msg
    code, msg = _validate(
        "--set",
        "segment.type=segmenter.edge_morph",
        "--set",
        "segment.object.color_bgr=null",
        capsys=capsys,
        pipeline=LOCATE_OLD,
    )
    # (edge_morph works without a colour: look-alikes are refused as ambiguous)
    assert code == 0, msg


def test_validate_warns_of_a_file_a_node_will_read_that_is_not_there(capsys, tmp_path):
    # in the file: a warning (another pipeline may write it before this one runs) ...
    live = LOCATE.parent / "pick-live.yaml"
    (tmp_path / "live").symlink_to(LOCATE.parent / "live")
    mine = tmp_path / "pick-live.yaml"
    mine.write_text(
        live.read_text().replace("live/calibration.yml", "live/no-such-calibration.yml")
    )
    code, msg = _validate(capsys=capsys, pipeline=mine)
    assert (
        code == 0
        and "warning:" in msg
        and "node 'calibration'" in msg
        and "no-such-calibration.yml" in msg
    )
    code, msg = _validate(capsys=capsys, pipeline=live)
    assert code == 0 and "warning:" not in msg
    # ... on the command line: an error, saying which folder a relative path is taken from
    code, msg = _validate(
        "--set", "calibration.path=no-such-calibration.yml", capsys=capsys, pipeline=live
    )
    assert code == 2 and "node 'calibration'" in msg and f"folder, {live.parent})" in msg, msg


def test_a_misspelt_nested_key_is_matched_against_its_own_model(capsys):
    # (the suggestion came from the top-level parameters: `shadow.enabeld` got no useful hint)
    code, msg = _validate("--set", "segment.shadow.enabeld=true", capsys=capsys)
    assert code == 2 and "did you mean 'enabled'?" in msg
    code, msg = _validate(
        "--set", "rig.scenes=[{ball: {center_cm: [0, 40], colour: red}}]", capsys=capsys
    )
    assert code == 2 and "'scenes.0.ball.colour'" in msg and "did you mean 'color'?" in msg


@pytest.mark.parametrize(
    "override",
    [
        "rig.type=nosuch",
        "locate.inputs.pair=nosuch.x",
        "locate.inputs.pair=rig.nope",
        "rig.n_scenes.deep=1",
        "segment.object.color_bgr.0=5",
    ],
)
def test_a_bad_set_is_located_at_the_set_not_at_the_file_line_it_replaced(override, capsys):
    # (these pointed at locate.yaml's line, which holds the pipeline's own -- correct -- value)
    code, err = _validate("--set", override, capsys=capsys)
    assert code == 2 and err.startswith(f"error: --set {override}:"), err


def test_a_type_swap_on_the_command_line_keeps_params_set_before_it():
    """`--set segment.object.radius_cm=5 --set segment.type=segmenter.color` dropped the radius (the
    swap reset the node's params, in command-line order); type swaps now go first, wherever they
    stand."""
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    locate = LOCATE_OLD
    for order in (
        ["segment.object.radius_cm=5", "segment.type=segmenter.color"],
        ["segment.type=segmenter.color", "segment.object.radius_cm=5"],
    ):
        seg = build_graph(load_pipeline(locate, order)).nodes["segment"]
        assert seg.type == "segmenter.color" and seg.params.object.radius_cm == 5.0, order
        # (and the colour from defaults: for the new type)
        assert seg.params.object.color_bgr is not None


def test_user_text_with_colons_is_printed_as_written(tmp_path, capsys):
    """(rich turned ':ab:' in a message into an emoji: `--set segment.type=segmenter:ab:x` was shown
    as 'segmenter🆎x', a name the user never typed)"""
    code, msg = run_cli(tmp_path, GOOD, "--set", "power.type=toy:ab:power", capsys=capsys)
    assert code == 2
    assert "toy:ab:power" in msg and "\N{NEGATIVE SQUARED AB}" not in msg, msg


def test_a_plugin_node_without_params_that_reads_one_is_told_to_declare_them(tmp_path, capsys):
    # was "AttributeError: '_NoParams' object has no attribute 'gain'", taken for a bug in the
    # engine
    plug = tmp_path / "noparams.py"
    plug.write_text(
        textwrap.dedent("""\
        from stereograph.core.api import Out, node

        @node("mine.gain", outputs={"value": Out("Number")})
        def gain(params):
            # (still AttributeErrors)
            assert not hasattr(params, "gain") and getattr(params, "gain", 2.0) == 2.0
            return {"value": 3.0 * params.gain}
        """)
    )
    f = tmp_path / "p.yaml"
    f.write_text(f"name: p\nplugins: [{plug}]\nnodes:\n  g: {{type: mine.gain}}\n")
    code = main(["run", str(f), "--allow-plugins", "--no-cache", "--out", str(tmp_path / "out")])
    out = capsys.readouterr()
    msg = " ".join((out.out + out.err).split())
    assert code == 1, msg
    assert "the node reads params.gain, but its @node(...) declares no params model" in msg, msg
    assert "params=MyParams" in msg and "Traceback" not in msg and "_NoParams" not in msg


def test_a_control_character_in_a_text_param_is_refused_by_validate(capsys):
    """(a report title with an escape sequence reached the terminal raw, through matplotlib's
    warning that the figure's font has no glyph for it)"""
    code, msg = _validate("--set", 'report.title="T\\e[31mRED"', capsys=capsys)
    assert code == 2 and "node 'report'" in msg and "title holds a control character" in msg, msg
    assert "\x1b" not in msg
    code, msg = _validate("--set", 'report.title="two\\nlines"', capsys=capsys)
    assert code == 0, msg
