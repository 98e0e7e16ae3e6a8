"""Fuzzing the pipeline language (issue 12).

``test_validate_never_crashes`` mutates the shipped pipelines — keys, types, values, wiring, YAML
syntax, ``--set`` overrides — and checks that ``stereograph validate`` either accepts the result
or gives a config error (exit 2) that names a file or a ``--set``, within a few seconds, never an
internal error or a traceback. ``test_small_runs_never_crash`` runs mutated small pipelines
(hello.yaml, and locate.yaml cut down to 2 scenes) and checks that whatever happens is reported as
a config error or a node's failure with its message, never a raw exception.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml
from fuzzing import examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereograph.app.cli import main
from stereograph.core import registry

ROOT = Path(__file__).resolve().parent.parent
PIPELINES = sorted((ROOT / "pipelines").glob("*.yaml"))
TOY = ROOT / "tests" / "plugins" / "toy.py"
# "never longer than a few seconds" of CPU (a shipped pipeline validates in ~20 ms)
SECONDS_PER_EXAMPLE = 3.0


def _shipped() -> dict[str, str]:
    """Each shipped pipeline's text, its toy plugin path made absolute (the copies live
    elsewhere)."""
    return {p.name: p.read_text().replace("../tests/plugins/toy.py", str(TOY)) for p in PIPELINES}


SHIPPED = _shipped()
NAMES = sorted(SHIPPED)

# ---------------------------------------------------------------------------------- strategies

odd_text = st.one_of(
    st.sampled_from(
        [
            "",
            ".",
            "..",
            "../x",
            "/tmp/x",
            "a.b",
            "a[/]b",
            "[bold]x[/]",
            "x" * 300,
            "rig.views",
            "source.synthetic",
            "segmenter.edge_morph",
            "toy.numbers",
            "*a",
            "&a",
            "{",
            "- x",
            "é",
            "\u202e",
            "NaN",
            "1e309",
            "-.inf",
            "~",
            "null",
            "yes",
            "0x1F",
            "2026-11-23",
        ]
    ),
    st.text(max_size=12),
)
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.integers(-3, 300),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e308, -1.0, 0.5]),
    odd_text,
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(odd_text, inner, max_size=3)
    ),
    max_leaves=8,
)


def _paths(data, prefix=()):
    """Every key path in the document (mappings and lists)."""
    out = [prefix]
    if isinstance(data, dict):
        for k, v in data.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out += _paths(v, prefix + (i,))
    return out


def _get(data, path):
    for p in path:
        data = data[p]
    return data


@st.composite
def mutated_document(draw):
    """A shipped pipeline with a few structural mutations, as YAML text."""
    name = draw(st.sampled_from(NAMES))
    data = yaml.safe_load(SHIPPED[name])
    for _ in range(draw(st.integers(1, 4))):
        paths = _paths(data)
        path = draw(st.sampled_from(paths))
        kind = draw(st.sampled_from(["value", "delete", "rename", "add", "type", "wire", "node"]))
        parent = _get(data, path[:-1]) if path else None
        key = path[-1] if path else None
        if kind == "value" and path:
            parent[key] = draw(values)
        elif kind == "delete" and path:
            del parent[key]
        elif kind == "rename" and path and isinstance(parent, dict):
            parent[draw(odd_text)] = parent.pop(key)
        elif kind == "add":
            target = _get(data, path)
            if isinstance(target, dict):
                target[draw(odd_text)] = draw(values)
            elif isinstance(target, list):
                target.append(draw(values))
        elif kind == "type" and isinstance(data.get("nodes"), dict) and data["nodes"]:
            node = draw(st.sampled_from(sorted(data["nodes"], key=str)))
            if isinstance(data["nodes"][node], dict):
                data["nodes"][node]["type"] = draw(
                    st.one_of(st.sampled_from(registry.names()), odd_text)
                )
        elif kind == "wire" and isinstance(data.get("nodes"), dict) and data["nodes"]:
            node = draw(st.sampled_from(sorted(data["nodes"], key=str)))
            other = draw(st.sampled_from(sorted(data["nodes"], key=str)))
            decl = data["nodes"][node]
            if isinstance(decl, dict):
                ins = (
                    decl.setdefault("inputs", {})
                    if isinstance(decl.get("inputs", {}), dict)
                    else {}
                )
                port = draw(st.one_of(st.sampled_from(sorted(map(str, ins)) or ["x"]), odd_text))
                ins[port] = draw(
                    st.one_of(
                        st.builds(
                            lambda o, out: f"{o}.{out}",
                            st.just(other),
                            st.sampled_from(
                                [
                                    "pairs",
                                    "views",
                                    "calibration",
                                    "items",
                                    "m",
                                    "norm",
                                    "rectified",
                                    "location",
                                    "x",
                                ]
                            ),
                        ),
                        values,
                    )
                )
        elif kind == "node" and isinstance(data.get("nodes"), dict):
            data["nodes"][draw(odd_text)] = draw(
                st.one_of(
                    values,
                    st.builds(
                        lambda t, p: {"type": t, "params": p},
                        st.sampled_from(registry.names()),
                        st.dictionaries(odd_text, values, max_size=2),
                    ),
                )
            )
    return name, yaml.safe_dump(data, allow_unicode=True, sort_keys=False)


@st.composite
def mutated_text(draw):
    """A shipped pipeline's text with characters inserted, deleted or replaced (YAML syntax)."""
    name = draw(st.sampled_from(NAMES))
    text = SHIPPED[name]
    for _ in range(draw(st.integers(1, 5))):
        pos = draw(st.integers(0, len(text)))
        kind = draw(st.sampled_from(["insert", "delete", "replace"]))
        piece = draw(
            st.one_of(
                st.sampled_from(
                    [
                        ":",
                        "-",
                        "[",
                        "]",
                        "{",
                        "}",
                        ",",
                        "&a",
                        "*a",
                        "!!python/object",
                        "? ",
                        "\t",
                        "\n",
                        "  ",
                        "'",
                        '"',
                        "#",
                        "|",
                        ">",
                        "%YAML 1.1\n",
                        "\x00",
                        "\x07",
                        "\ufeff",
                        "<<: *object",
                        "---\n",
                        "...",
                    ]
                ),
                st.text(max_size=4),
            )
        )
        if kind == "insert":
            text = text[:pos] + piece + text[pos:]
        elif kind == "delete":
            text = text[:pos] + text[pos + len(piece) :]
        else:
            text = text[:pos] + piece + text[pos + len(piece) :]
    return name, text


overrides = st.lists(
    st.builds(
        lambda n, f, v: f"{n}.{f}={v}",
        st.sampled_from(["rig", "calib", "segment", "numbers", "power", "locate", "x"]),
        st.sampled_from(
            [
                "n_scenes",
                "seed",
                "params",
                "type",
                "inputs.m",
                "working_range_cm",
                "object.radius_cm",
                "a.b.c",
                "focal_length_px",
            ]
        ),
        st.one_of(
            st.sampled_from(
                [
                    "",
                    "[",
                    "1e309",
                    ".nan",
                    "[80, 20]",
                    "{a: 1}",
                    "*x",
                    "&a [1, *a]",
                    "[[[[[]]]]]",
                    "x" * 50,
                ]
            ),
            st.text(max_size=8),
        ),
    ),
    max_size=2,
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder holding every shipped pipeline (includes resolve) for the mutated copies."""
    d = tmp_path_factory.mktemp("fuzz")
    for name, text in SHIPPED.items():
        (d / name).write_text(text)
    return d


def _check_validate(folder: Path, text: str, sets: list[str], capsys) -> None:
    f = folder / "mutated.yaml"
    f.write_bytes(text.encode("utf-8", "surrogatepass"))
    argv = ["validate", str(f)] + [a for s in sets for a in ("--set", s)]
    # CPU time: a hang or a blow-up burns it; a busy host's other work does not
    t0 = time.process_time()
    code = main(argv)
    seconds = time.process_time() - t0
    out = capsys.readouterr()
    msg = out.out + out.err
    assert "internal error" not in msg and "Traceback" not in msg, msg
    assert code in (0, 2), msg
    if code == 2:
        assert msg.startswith("error: ") and (".yaml" in msg or "--set" in msg), msg
    assert seconds < SECONDS_PER_EXAMPLE, f"validate took {seconds:.1f} s"


@settings(
    max_examples=examples(250),
    deadline=None,
    database=None,
    derandomize=False,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.function_scoped_fixture,
        HealthCheck.data_too_large,
        HealthCheck.filter_too_much,
    ],
)
@pytest.mark.slow
@given(doc=st.one_of(mutated_document(), mutated_text()), sets=overrides)
def test_validate_never_crashes(folder, capsys, doc, sets):
    _, text = doc
    _check_validate(folder, text, sets, capsys)


# ---------------------------------------------------------------------------------- small runs

HELLO_SETS = st.lists(
    st.builds(
        lambda k, v: f"{k}={v}",
        st.sampled_from(
            [
                "numbers.n",
                "numbers.size",
                "numbers.seed",
                "power.power",
                "power.fail_on",
                "total.scale",
                "power.inputs.m",
                "report.inputs.m",
                "numbers.type",
            ]
        ),
        st.one_of(
            st.sampled_from(
                [
                    "0",
                    "1",
                    "2",
                    "-1",
                    "64",
                    "65",
                    "1e309",
                    ".nan",
                    "2.5",
                    "''",
                    "'0'",
                    "null",
                    "numbers.items",
                    "power.norm",
                    "total.total",
                    "toy.power",
                    "toy.sum",
                ]
            ),
            st.text(max_size=4),
        ),
    ),
    min_size=1,
    max_size=3,
)

LOCATE_SETS = st.lists(
    st.builds(
        lambda k, v: f"{k}={v}",
        st.sampled_from(
            [
                "segment.working_range_cm",
                "segment.min_roundness",
                "segment.object.radius_cm",
                "segment.edge_search_px",
                "segment.type",
                "disparity.type",
                "disparity.range_slack",
                "locate.working_range_cm",
                "locate.frame",
                "report.split",
            ]
        ),
        st.one_of(
            st.sampled_from(
                [
                    "[20, 80]",
                    "[30, 31]",
                    "[1e-3, 1e6]",
                    "0",
                    "1",
                    "0.5",
                    "100",
                    "1e-9",
                    "segmenter.color",
                    "segmenter.otsu",
                    "disparity.ellipse",
                    "table",
                    "train",
                    "all",
                    "[0.1, 0.2]",
                ]
            ),
            st.floats(allow_nan=False, allow_infinity=False, min_value=-10, max_value=1000).map(
                repr
            ),
        ),
    ),
    min_size=1,
    max_size=2,
)

SMALL_LOCATE = ["rig.n_scenes=2", "rig.n_views=6"]


def _check_run(folder: Path, name: str, sets: list[str], tmp_path: Path, capsys) -> None:
    out = tmp_path / "runs" / str(time.perf_counter_ns())
    argv = ["run", str(folder / name), "--out", str(out), "--cache-dir", str(folder / ".cache")]
    code = main(argv + [a for s in sets for a in ("--set", s)])
    got = capsys.readouterr()
    msg = got.out + got.err
    assert "internal error" not in msg and "Traceback" not in msg, msg
    assert "looks like a bug" not in msg, msg  # a node raised something other than NodeError
    assert code in (0, 1, 2), msg
    if code == 1:
        assert "failed:" in msg, msg


@settings(
    max_examples=examples(40),
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@pytest.mark.slow
@given(sets=HELLO_SETS)
def test_small_runs_never_crash_hello(folder, tmp_path, capsys, sets):
    _check_run(folder, "hello.yaml", sets, tmp_path, capsys)


@settings(
    max_examples=examples(12),
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@pytest.mark.slow
@given(sets=LOCATE_SETS)
def test_small_runs_never_crash_locate(folder, tmp_path, capsys, sets):
    _check_run(folder, "locate.yaml", SMALL_LOCATE + sets, tmp_path, capsys)


def test_fuzz_inputs_are_the_shipped_pipelines(folder, capsys):
    """The fuzzers start from every shipped pipeline, and each validates as shipped (from the
    copy)."""
    assert len(SHIPPED) >= 5 and {"hello.yaml", "locate.yaml", "pick.yaml"} <= set(SHIPPED)
    for name in SHIPPED:
        code = main(["validate", str(folder / name)])
        out = capsys.readouterr()
        assert code == 0, name + ": " + out.out + out.err
