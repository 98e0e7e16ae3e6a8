"""Scheduler and cache behaviour: what runs, what is reused, what survives failures."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from stereograph.app.cli import main
from stereograph.app.explain import explain
from stereograph.core.cache import ArtifactStore
from stereograph.core.config import load_pipeline
from stereograph.core.errors import ConfigError
from stereograph.core.graph import build_graph
from stereograph.core.runner import run_pipeline

TOY = Path(__file__).parent / "plugins" / "toy.py"


def write_pipeline(tmp_path: Path, power: int = 2, n: int = 6, extra: str = "") -> Path:
    f = tmp_path / "p.yaml"
    f.write_text(
        textwrap.dedent(f"""\
        name: t
        plugins: [{TOY}]
        nodes:
          numbers:
            type: toy.numbers
            params: {{n: {n}, size: 8}}
          power:
            type: toy.power
            params: {{power: {power}}}
            inputs: {{m: numbers.items}}
          total:
            type: toy.sum
            inputs: {{values: power.norm}}
          report:
            type: toy.table
            inputs: {{m: power.m}}
        """)
        + extra
    )
    return f


def run(path, tmp_path, *overrides, **kw):
    return run_pipeline(
        path, list(overrides), cache_dir=tmp_path / "cache", out_dir=tmp_path / "out", **kw
    )


def test_second_run_is_all_cached_and_same_result(tmp_path):
    p = write_pipeline(tmp_path)
    r1 = run(p, tmp_path)
    assert r1.ok and r1.ran == {"numbers", "power", "total", "report"}
    r2 = run(p, tmp_path)
    assert set(r2.status.values()) == {"cached"}
    assert r2.outputs("total", "total") == r1.outputs("total", "total")
    assert json.loads((tmp_path / "out" / "total" / "total.json").read_text()) == r1.outputs(
        "total", "total"
    )


def test_param_change_reruns_exactly_that_node_and_downstream(tmp_path):
    p = write_pipeline(tmp_path)
    run(p, tmp_path)
    r = run(p, tmp_path, "power.power=3")
    assert r.ran == {"power", "total", "report"}
    assert r.status["numbers"] == "cached"
    r = run(p, tmp_path, "total.scale=2")
    assert r.ran == {"total"}


def test_map_items_cached_one_by_one(tmp_path):
    p = write_pipeline(tmp_path, n=4)
    run(p, tmp_path)
    r = run(p, tmp_path, "numbers.n=6")  # two new items; the first four are the same matrices
    assert r.reports["power"].items == 6 and r.reports["power"].items_ran == 2


@pytest.mark.slow
def test_source_code_change_invalidates_including_helpers(tmp_path):
    plug = tmp_path / "plug"
    plug.mkdir()
    (plug / "helper_mod.py").write_text("OFFSET = 1.0\n")
    (plug / "mynode.py").write_text(
        textwrap.dedent("""\
        import sys, os
        sys.path.insert(0, os.path.dirname(__file__))
        from stereograph.core.api import node, Out
        import helper_mod

        @node("tmp.const", outputs={"value": Out("Number")})
        def const(params):
            return {"value": 41.0 + helper_mod.OFFSET}
        """)
    )
    f = tmp_path / "p.yaml"
    f.write_text("name: c\nplugins: [plug/mynode.py]\nnodes:\n  c: {type: tmp.const}\n")
    code = textwrap.dedent(f"""\
        import sys, json
        from stereograph.core.runner import run_pipeline
        r = run_pipeline({str(f)!r}, cache_dir={str(tmp_path / "cache")!r},
                         out_dir={str(tmp_path / "o")!r})
        print(json.dumps([r.status['c'], r.outputs('c', 'value')]))
        """)

    def once():
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        )
        return json.loads(out.stdout.strip().splitlines()[-1])

    assert once() == ["ran", 42.0]
    assert once() == ["cached", 42.0]
    (plug / "mynode.py").write_text((plug / "mynode.py").read_text().replace("41.0", "40.0"))
    assert once() == ["ran", 41.0]
    (plug / "helper_mod.py").write_text("OFFSET = 5.0\n")  # only the imported helper changes
    assert once() == ["ran", 45.0]
    verdicts = explain(build_graph(load_pipeline(f)), tmp_path / "cache")
    assert verdicts[0].fresh


def test_explain_names_the_reason(tmp_path):
    p = write_pipeline(tmp_path)
    run(p, tmp_path)
    v = {
        x.node: x
        for x in explain(build_graph(load_pipeline(p, ["power.power=5"])), tmp_path / "cache")
    }
    assert v["numbers"].fresh
    assert not v["power"].fresh and "param power changed: 2 -> 5" in v["power"].reasons[0]
    assert not v["total"].fresh and "upstream 'power'" in v["total"].reasons[0]
    v = {x.node: x for x in explain(build_graph(load_pipeline(p)), tmp_path / "cache")}
    assert all(x.fresh for x in v.values())


def test_item_failure_skips_only_that_item(tmp_path):
    p = write_pipeline(tmp_path, n=5)
    r = run(p, tmp_path, "power.fail_on=m002")
    assert r.status["power"] == "partial" and not r.ok
    assert r.reports["power"].items_failed == 1
    report = r.outputs("report", "report")
    assert report["n"] == 4 and "m002" not in report["items"]
    # upstream stays cached; the fix (a param change) reruns the node and its downstream
    r = run(p, tmp_path)
    assert r.status["numbers"] == "cached" and r.ran == {"power", "total", "report"}
    assert r.outputs("report", "report")["n"] == 5


def test_failed_single_node_stops_downstream_and_cli_says_how_to_resume(tmp_path, capsys):
    plug = tmp_path / "boom.py"
    plug.write_text(
        textwrap.dedent("""\
        from stereograph.core.api import node, In, Out, NodeError
        @node("tmp.boom", inputs={"m": In("Matrix", gather=True)}, outputs={"x": Out("Number")})
        def boom(params, m):
            raise NodeError("no object found in image left07.png", hint="check the lighting")
        """)
    )
    p = write_pipeline(
        tmp_path,
        extra="  boom:\n    type: tmp.boom\n    inputs: {m: power.m}\n"
        "  after:\n    type: toy.sum\n    params: {scale: 3}\n"
        "    inputs: {values: power.norm}\n",
    )
    text = p.read_text().replace(f"plugins: [{TOY}]", f"plugins: [{TOY}, {plug}]")
    p.write_text(text)
    code = main(["run", str(p), "--cache-dir", str(tmp_path / "c"), "--out", str(tmp_path / "o")])
    err = " ".join(capsys.readouterr().err.split())
    assert code == 1
    assert "node 'boom' (tmp.boom) failed: no object found in image left07.png" in err
    boom_line = text.splitlines().index("  boom:") + 1
    assert f"p.yaml:{boom_line}:3: node 'boom'" in err  # where the failed node is declared
    assert "Fix: check the lighting" in err and "Traceback" not in err
    assert "run the same command again" in err and "--from boom" in err
    summary = json.loads((tmp_path / "o" / "run.json").read_text())
    st = {n["node"]: n["status"] for n in summary["nodes"]}
    assert st["boom"] == "failed" and st["power"] == "ran" and st["after"] == "ran"


def test_only_and_from(tmp_path):
    p = write_pipeline(tmp_path)
    r = run(p, tmp_path, only="power")
    assert r.ran == {"numbers", "power"} and r.status["total"] == "not selected"
    # not its upstream
    assert sorted(x.name for x in (tmp_path / "out").iterdir()) == [
        "power",
        "report.html",
        "run.json",
    ]
    r = run(p, tmp_path, from_node="power")
    assert r.ran == {"power", "total", "report"} and r.status["numbers"] == "cached"


def test_no_cache_runs_everything_and_stores_nothing(tmp_path):
    p = write_pipeline(tmp_path)
    r = run(p, tmp_path, use_cache=False)
    assert r.ran == {"numbers", "power", "total", "report"}
    assert not (tmp_path / "cache").exists()


def _kill_during_save(cache: str) -> None:
    """Child process: dies (os._exit) after the temp files exist, before the rename."""
    import numpy as np

    from stereograph.core import cache as c

    real_rename = os.rename

    def dying_rename(src, dst):
        if "objects" in str(dst):
            os._exit(9)
        return real_rename(src, dst)

    c.os.rename = dying_rename
    c.ArtifactStore(cache).save("k" * 32, {"a": np.arange(1000)})


def test_kill_mid_write_leaves_no_valid_entry(tmp_path):
    ctx = mp.get_context("spawn")
    proc = ctx.Process(target=_kill_during_save, args=(str(tmp_path / "cache"),))
    proc.start()
    proc.join(30)
    assert proc.exitcode == 9
    store = ArtifactStore(tmp_path / "cache")
    assert list((tmp_path / "cache" / "tmp").iterdir()), (
        "the temp entry should exist (killed mid-write)"
    )
    assert not store.has("k" * 32)


def test_corrupt_entry_is_detected_and_recomputed(tmp_path):
    p = write_pipeline(tmp_path)
    r1 = run(p, tmp_path)
    # flip bytes in every stored array file of the 'power' items
    n = 0
    for man in (tmp_path / "cache" / "objects").glob("*/*/manifest.json"):
        meta = json.loads(man.read_text())["meta"]
        if meta.get("node") == "power":
            npz = man.parent / "arrays.npz"
            b = bytearray(npz.read_bytes())
            b[-100] ^= 0xFF
            npz.write_bytes(bytes(b))
            n += 1
    assert n == 6
    r2 = run(p, tmp_path, "total.scale=1.0001")  # total must load the (corrupt) power outputs
    assert r2.ok
    assert any("corrupt" in m for m in r2.reports["power"].messages)
    assert r2.outputs("total", "total") == pytest.approx(1.0001 * r1.outputs("total", "total"))
    r3 = run(p, tmp_path, "total.scale=1.0002")
    # the entries were rewritten
    assert r3.status["power"] == "cached" and not r3.reports["power"].messages


def _concurrent_run(args):
    path, cache, out, log = args
    os.environ["TOY_LOG"] = log
    from stereograph.core.runner import run_pipeline as rp

    r = rp(path, cache_dir=cache, out_dir=out)
    return r.ok


@pytest.mark.slow
def test_two_runs_at_once_share_the_cache(tmp_path):
    plug = tmp_path / "slow.py"
    plug.write_text(
        textwrap.dedent("""\
        import os, time
        from stereograph.core.api import node, In, Out
        @node("tmp.slow", inputs={"m": In("Matrix")}, outputs={"x": Out("Number")})
        def slow(params, m, ctx=None):
            with open(os.environ["TOY_LOG"], "a") as f:
                f.write(ctx.item + "\\n")
            time.sleep(0.2)
            return {"x": float(m.sum())}
        """)
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: s\nplugins: [{TOY}, {plug}]\nnodes:\n  numbers: {{type: toy.numbers, "
        "params: {n: 6}}\n"
        f"  slow: {{type: tmp.slow, inputs: {{m: numbers.items}}}}\n"
        f"  total: {{type: toy.sum, inputs: {{values: slow.x}}}}\n"
    )
    log = tmp_path / "log.txt"
    ctx = mp.get_context("spawn")
    with ctx.Pool(2) as pool:
        oks = pool.map(
            _concurrent_run,
            [(str(f), str(tmp_path / "c"), str(tmp_path / f"o{i}"), str(log)) for i in range(2)],
        )
    assert oks == [True, True]
    computed = log.read_text().split()
    assert sorted(computed) == sorted(set(computed)) and len(computed) == 6, computed


def test_uncacheable_node_runs_every_time(tmp_path):
    plug = tmp_path / "live.py"
    plug.write_text(
        textwrap.dedent("""\
        import itertools
        from stereograph.core.api import node, Out
        COUNTER = itertools.count()
        @node("tmp.live", outputs={"x": Out("Number")}, cacheable=False)
        def live(params):
            return {"x": float(next(COUNTER))}
        """)
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: l\nplugins: [{TOY}, {plug}]\nnodes:\n  live: {{type: tmp.live}}\n"
        f"  total: {{type: toy.sum, inputs: {{values: live.x}}}}\n"
    )
    with pytest.raises(ConfigError, match="gathers a collection"):
        # gathering a single artifact is a config error
        build_graph(load_pipeline(f))
    f.write_text(f"name: l\nplugins: [{plug}]\nnodes:\n  live: {{type: tmp.live}}\n")
    r1 = run(f, tmp_path)
    r2 = run(f, tmp_path)
    assert r1.status["live"] == "ran" and r2.status["live"] == "ran"
    assert r2.outputs("live", "x") == r1.outputs("live", "x") + 1


def test_include_and_defaults(tmp_path):
    (tmp_path / "common.yaml").write_text(
        f"plugins: [{TOY}]\nnodes:\n  numbers: {{type: toy.numbers, params: {{n: 3, size: 4}}}}\n"
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        "name: inc\ninclude: [common.yaml]\ndefaults:\n  toy.power: {power: 3}\nnodes:\n"
        "  power: {type: toy.power, inputs: {m: numbers.items}}\n"
        "  numbers: {type: toy.numbers, params: {size: 5}}\n"
    )
    g = build_graph(load_pipeline(f))
    assert g.nodes["power"].params.power == 3
    # merged over the include
    assert g.nodes["numbers"].params.n == 3 and g.nodes["numbers"].params.size == 5
    # a change to an included node may leave its type out: it keeps the included one's
    f.write_text(
        "name: inc\ninclude: [common.yaml]\nnodes:\n  numbers: {params: {size: 6}}\n"
        "  power: {type: toy.power, inputs: {m: numbers.items}}\n"
    )
    g = build_graph(load_pipeline(f))
    assert g.nodes["numbers"].type == "toy.numbers"
    assert g.nodes["numbers"].params.n == 3 and g.nodes["numbers"].params.size == 6
    # a node of its own still needs one
    f.write_text("name: inc\ninclude: [common.yaml]\nnodes:\n  other: {params: {size: 6}}\n")
    with pytest.raises(ConfigError, match="node has no 'type'"):
        load_pipeline(f)


def test_process_pool_gives_the_same_result(tmp_path):
    from stereograph.core.executors import ProcessExecutor

    p = write_pipeline(tmp_path, n=8)
    serial = run_pipeline(p, use_cache=False, out_dir=tmp_path / "o1").outputs("total", "total")
    ex = ProcessExecutor(2)
    try:
        r = run_pipeline(p, use_cache=False, out_dir=tmp_path / "o2", executor=ex)
    finally:
        ex.close()
    assert r.ok and r.outputs("total", "total") == pytest.approx(serial)


@pytest.mark.slow
def test_dask_executor_gives_the_same_result(tmp_path):
    pytest.importorskip("distributed")
    from stereograph.core.executors import DaskExecutor

    p = write_pipeline(tmp_path, n=6)
    serial = run_pipeline(p, use_cache=False, out_dir=tmp_path / "o1").outputs("total", "total")
    ex = DaskExecutor(workers=2)
    try:
        r = run_pipeline(p, use_cache=False, out_dir=tmp_path / "o2", executor=ex)
    finally:
        ex.close()
    assert r.ok and r.outputs("total", "total") == pytest.approx(serial)


def test_files_a_node_reads_are_part_of_its_key(tmp_path):
    plug = tmp_path / "reader.py"
    plug.write_text(
        textwrap.dedent("""\
        from pathlib import Path
        from stereograph.core.api import node, Out, Params, Field

        class P(Params):
            path: str = Field(..., description="A text file (path).")

        def _reads(params, pipeline_dir):
            return [pipeline_dir / params.path]

        @node("tmp.reader", outputs={"text": Out("Text")}, params=P, reads=_reads)
        def reader(params, ctx=None):
            return {"text": ctx.path(params.path).read_text()}
        """)
    )
    data = tmp_path / "data.txt"
    data.write_text("one")
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: r\nplugins: [{plug}]\nnodes:\n  read: {{type: tmp.reader, params: {{path: "
        "data.txt}}\n"
    )
    assert run(f, tmp_path).outputs("read", "text") == "one"
    assert run(f, tmp_path).status["read"] == "cached"
    os.utime(data, ns=(1, 1))  # new mtime, same content: the digest confirms nothing changed
    assert run(f, tmp_path).status["read"] == "cached"
    data.write_text("two")
    r = run(f, tmp_path)
    assert r.status["read"] == "ran" and r.outputs("read", "text") == "two"
    v = explain(build_graph(load_pipeline(f)), tmp_path / "cache")
    assert v[0].fresh
    data.write_text("three")
    v = explain(build_graph(load_pipeline(f)), tmp_path / "cache")
    assert (
        not v[0].fresh
        and "input files changed: " in v[0].reasons[0]
        and "data.txt" in v[0].reasons[0]
    )


def test_saved_images_are_written_on_cached_runs_too(tmp_path):
    p = write_pipeline(
        tmp_path,
        n=3,
        extra="  picture:\n    type: toy.picture\n    inputs: {m: numbers.items}\n"
        "  mean:\n    type: toy.sum\n    inputs: {values: picture.mean}\n",
    )
    r1 = run_pipeline(p, cache_dir=tmp_path / "cache", out_dir=tmp_path / "o1")
    r2 = run_pipeline(p, cache_dir=tmp_path / "cache", out_dir=tmp_path / "o2")
    assert r1.ok and r2.status["picture"] == "cached"
    files1 = sorted((tmp_path / "o1" / "picture" / "picture").glob("*.png"))
    files2 = sorted((tmp_path / "o2" / "picture" / "picture").glob("*.png"))
    assert [f.name for f in files1] == ["m000.png", "m001.png", "m002.png"]
    assert [f.read_bytes() for f in files1] == [f.read_bytes() for f in files2]
    import cv2

    img = cv2.imread(str(files2[0]), cv2.IMREAD_UNCHANGED)
    assert img.dtype.name == "uint8" and img.shape == (32, 32)
    assert ArtifactStore(tmp_path / "cache").clear() > 0
    assert not (tmp_path / "cache" / "rendered").exists()


def test_explain_agrees_with_what_the_next_run_does(tmp_path):
    p = write_pipeline(tmp_path)
    run(p, tmp_path, "power.power=3")
    run(p, tmp_path)  # back to power=2: the last run of every node differs from power=3 now
    for overrides in (["power.power=3"], ["power.power=4"], ["numbers.n=7"], []):
        predicted = {
            v.node: v.fresh
            for v in explain(build_graph(load_pipeline(p, overrides)), tmp_path / "cache")
        }
        actual = run(p, tmp_path, *overrides).status
        assert predicted == {n: s == "cached" for n, s in actual.items()}, (
            overrides,
            predicted,
            actual,
        )


def test_reused_out_folder_holds_only_the_new_run(tmp_path, capsys):
    p = write_pipeline(tmp_path)
    out = tmp_path / "same"
    assert main(["run", str(p), "--out", str(out), "--cache-dir", str(tmp_path / "c")]) == 0
    assert (out / "report" / "report.json").exists()
    assert (
        main(
            [
                "run",
                str(p),
                "--out",
                str(out),
                "--cache-dir",
                str(tmp_path / "c"),
                "--only",
                "power",
            ]
        )
        == 0
    )
    assert not (out / "report").exists() and (out / "run.json").exists()  # the old report is gone
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    capsys.readouterr()
    assert main(["run", str(p), "--out", str(other)]) == 2
    assert "not empty" in capsys.readouterr().err and (other / "notes.txt").read_text() == "keep me"


LOGGER = """\
from stereograph.core.api import Field, Out, Params, node

class LogParams(Params):
    files: list[str] = Field(
        [], description="Files the node writes into its own folder (relative paths).")

@node("mine.logger", outputs={"value": Out("Number")}, params=LogParams, cacheable=False)
def logger(params, ctx=None):
    for rel in params.files:
        path = ctx.out_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("this run")
    return {"value": 1.0}
"""


def logger_run(tmp_path: Path, files: str) -> list[str]:
    """The command line of a pipeline whose node `act` writes ``files`` (YAML list) into its own
    folder."""
    (tmp_path / "logger.py").write_text(LOGGER)
    p = tmp_path / "p.yaml"
    p.write_text(
        f"name: p\nplugins: [{tmp_path / 'logger.py'}]\nnodes:\n"
        f"  act: {{type: mine.logger, params: {{files: {files}}}}}\n"
    )
    return ["run", str(p), "--allow-plugins", "--no-cache", "--out", str(tmp_path / "same")]


def test_a_file_a_node_wrote_into_its_folder_itself_goes_with_its_run(tmp_path):
    # a failure log written through ctx.out_dir was not in run.json, so a later run into the same
    # folder left it beside its own results, naming a failure that run did not have
    run, out = logger_run(tmp_path, "[failed_log.json, sub/detail.txt]"), tmp_path / "same"
    assert main(run) == 0
    files = json.loads((out / "run.json").read_text())["nodes"][0]["files"]
    assert {"act/failed_log.json", "act/sub/detail.txt"} <= set(files)
    assert main(run + ["--set", "act.files=[]"]) == 0
    assert not (out / "act" / "failed_log.json").exists() and not (out / "act" / "sub").exists()


def test_a_users_file_in_a_nodes_folder_is_not_taken_for_the_nodes(tmp_path):
    # the files a node writes itself are found in its folder after the run; a user's notes put there
    # between runs were found too, recorded as the node's, and deleted by the run after
    run, out = logger_run(tmp_path, "[]"), tmp_path / "same"
    assert main(run) == 0
    (out / "act" / "notes.txt").write_text("mine")
    (out / "act" / "log.txt").write_text("mine, and the node will write over it")
    assert main(run + ["--set", "act.files=[log.txt]"]) == 0
    files = json.loads((out / "run.json").read_text())["nodes"][0]["files"]
    # (the one it wrote over is the run's)
    assert "act/notes.txt" not in files and "act/log.txt" in files
    assert main(run) == 0 and main(run) == 0
    assert (out / "act" / "notes.txt").read_text() == "mine" and not (
        out / "act" / "log.txt"
    ).exists()


def test_unexpected_node_error_points_at_debug_and_keeps_the_traceback(tmp_path, capsys):
    plug = tmp_path / "bug.py"
    plug.write_text(
        "from stereograph.core.api import node, Out\n"
        "@node('tmp.bug', outputs={'x': Out('Number')})\n"
        "def bug(params):\n    return {'x': 1 / 0}\n"
    )
    f = tmp_path / "p.yaml"
    f.write_text(f"name: b\nplugins: [{plug}]\nnodes:\n  bug: {{type: tmp.bug}}\n")
    assert main(["run", str(f), "--out", str(tmp_path / "o")]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "ZeroDivisionError" in err and "--debug" in err and "Traceback" not in err
    summary = json.loads((tmp_path / "o" / "run.json").read_text())
    assert "Traceback" in summary["nodes"][0]["traceback"]
    assert main(["--debug", "run", str(f), "--out", str(tmp_path / "o")]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_node_warnings_survive_a_cached_run(tmp_path):
    plug = tmp_path / "warn.py"
    plug.write_text(
        "from stereograph.core.api import node, In, Out\n"
        "@node('tmp.warn', inputs={'m': In('Matrix')}, outputs={'x': Out('Number')})\n"
        "def warn(params, m, ctx=None):\n    ctx.warn(f'{ctx.item}: looks odd')\n"
        "    return {'x': float(m.sum())}\n"
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: w\nplugins: [{TOY}, {plug}]\nnodes:\n  numbers: {{type: toy.numbers, "
        "params: {n: 3}}\n"
        f"  warn: {{type: tmp.warn, inputs: {{m: numbers.items}}}}\n"
    )
    r1, r2 = run(f, tmp_path), run(f, tmp_path)
    assert r2.status["warn"] == "cached"
    assert (
        r1.reports["warn"].messages
        == r2.reports["warn"].messages
        == [f"m00{i}: looks odd" for i in range(3)]
    )


def test_cache_prune_keeps_the_recently_used(tmp_path, capsys):
    p = write_pipeline(tmp_path, n=4)
    run(p, tmp_path, "power.power=3")
    time.sleep(0.05)
    run(p, tmp_path)  # power=2 entries (and the shared numbers entries) used last
    store = ArtifactStore(tmp_path / "cache")
    before = store.info()["bytes"]
    removed, freed = store.prune(before // 2)
    assert removed > 0 and before - freed <= before // 2
    assert set(run(p, tmp_path).status.values()) == {"cached"}  # the latest settings survived
    assert run(p, tmp_path, "power.power=3").status["power"] == "ran"  # the older ones did not
    entries = ArtifactStore(tmp_path / "cache").info()["entries"]
    for bad in ("-1", "nan", "inf", "five"):  # (-1 emptied the cache; nan was an "internal error")
        assert (
            main(["cache", "prune", "--cache-dir", str(tmp_path / "cache"), "--max-gb", bad]) == 2
        )
    assert ArtifactStore(tmp_path / "cache").info()["entries"] == entries
    # the pipeline after the option, as `--help` shows it (was: "unrecognized arguments")
    assert (
        main(["cache", "prune", "--max-gb", "100", str(p), "--cache-dir", str(tmp_path / "cache")])
        == 0
    )
    assert main(["cache", "prune", "--cache-dir", str(tmp_path / "cache"), "--max-gb", "0"]) == 0
    assert ArtifactStore(tmp_path / "cache").info()["entries"] == 0


def test_node_learns_which_alternative_is_wired(tmp_path):
    from stereograph.core.executors import ProcessExecutor

    extra = (
        "  per_item:\n    type: toy.describe\n    inputs: {x: numbers.items}\n"
        "  whole:\n    type: toy.describe\n    inputs: {x: total.total}\n"
    )
    p = write_pipeline(tmp_path, n=3, extra=extra)
    r = run(p, tmp_path)
    assert r.ok
    assert {v["wired"] for v in r.outputs("per_item", "kind").values()} == {"Matrix"}
    assert all(v["is_array"] for v in r.outputs("per_item", "kind").values())
    assert r.outputs("whole", "kind") == {"wired": "Number", "is_array": False}
    ex = ProcessExecutor(2)  # the wiring travels with the task to another process
    try:
        r2 = run_pipeline(p, use_cache=False, out_dir=tmp_path / "o2", executor=ex)
    finally:
        ex.close()
    assert {v["wired"] for v in r2.outputs("per_item", "kind").values()} == {"Matrix"}


def test_a_per_item_node_that_made_no_item_writes_no_output_file(tmp_path):
    # a terminal per-item node whose every item failed (or that was skipped) once wrote an empty
    # `[]` JSON per output: a file that looks like a result
    f = tmp_path / "p.yaml"
    f.write_text(
        textwrap.dedent(f"""\
        name: t
        plugins: [{TOY}]
        nodes:
          numbers: {{type: toy.numbers, params: {{n: 2, size: 4}}}}
          power: {{type: toy.power, inputs: {{m: numbers.items}}}}
        """)
    )
    r = run(f, tmp_path, "power.fail_on=m000", "numbers.n=1")
    assert not r.ok and r.status["power"] == "failed"
    assert not (tmp_path / "out" / "power").exists()
    r = run(f, tmp_path, "power.fail_on=m000")  # the items that finished are still written
    norm = json.loads((tmp_path / "out" / "power" / "norm.json").read_text())
    assert sorted(p.name for p in (tmp_path / "out" / "power").iterdir()) == ["m.json", "norm.json"]
    assert "m001" in json.dumps(norm) and "m000" not in json.dumps(norm)


def test_an_interrupted_run_leaves_a_folder_the_same_command_resumes_into(tmp_path, capsys):
    # (Ctrl-C said "run again to resume", and the same command with --out then refused the folder:
    # "not the folder of an earlier stereograph run")
    p = write_pipeline(tmp_path, n=6)
    out = tmp_path / "out"
    args = ["run", str(p), "--out", str(out), "--cache-dir", str(tmp_path / "cache")]
    assert main([*args, "--set", "power.interrupt_on=m003"]) == 130
    summary = json.loads((out / "run.json").read_text())
    assert summary["ok"] is False and "interrupted" in " ".join(summary["notes"])
    assert {n["node"]: n["status"] for n in summary["nodes"]}["total"] == "interrupted"
    assert main(["report", str(out)]) == 0  # a page of what was done
    capsys.readouterr()
    assert main(args) == 0
    again = json.loads((out / "run.json").read_text())
    assert (
        again["ok"] is True and {n["node"]: n["status"] for n in again["nodes"]}["total"] == "ran"
    )


def test_a_symbolic_link_put_into_an_earlier_runs_folder_is_not_written_through(tmp_path):
    p = write_pipeline(tmp_path, n=3)
    assert run(p, tmp_path).ok
    victim = tmp_path / "victim"
    victim.mkdir()
    node_dir = tmp_path / "out" / "total"
    shutil.rmtree(node_dir)
    node_dir.symlink_to(victim, target_is_directory=True)
    assert run(p, tmp_path).ok
    assert list(victim.iterdir()) == [] and node_dir.is_dir() and not node_dir.is_symlink()


def _plugin(folder: Path, name: str, body: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    f = folder / name
    f.write_text(textwrap.dedent(body))
    return f


def test_a_plugin_edited_in_a_long_lived_process_runs_its_new_code(tmp_path):
    # (the second run in one Python process ran the old code and cached it under the new code's key)
    body = """\
        from stereograph.core.api import node, Out
        @node("tmp.answer", outputs={{"value": Out("Number", save=True)}})
        def answer(params):
            return {{"value": {v}}}
        """
    plug = _plugin(tmp_path, "answer.py", body.format(v=1))
    f = tmp_path / "p.yaml"
    f.write_text(f"name: a\nplugins: [{plug}]\nnodes:\n  a: {{type: tmp.answer}}\n")
    assert run(f, tmp_path).outputs("a", "value") == 1
    plug.write_text(textwrap.dedent(body.format(v=2)))
    assert run(f, tmp_path).outputs("a", "value") == 2
    assert run(f, tmp_path).status["a"] == "cached" and run(f, tmp_path).outputs("a", "value") == 2


def test_a_plugin_edited_with_its_old_size_and_time_is_imported_again(tmp_path):
    # (every task asks whether its plugin file changed, by its stat rather than its bytes; the stat
    # holds the change time, which no tool sets back)
    body = """\
        from stereograph.core.api import node, Out
        @node("tmp.answer_old", outputs={{"value": Out("Number", save=True)}})
        def answer(params):
            return {{"value": {v}}}
        """
    plug = _plugin(tmp_path, "answer_old.py", body.format(v=1))
    long_ago = time.time_ns() - 60 * 10**9
    os.utime(plug, ns=(long_ago, long_ago))
    f = tmp_path / "p.yaml"
    f.write_text(f"name: a\nplugins: [{plug}]\nnodes:\n  a: {{type: tmp.answer_old}}\n")
    assert run(f, tmp_path).outputs("a", "value") == 1
    plug.write_text(textwrap.dedent(body.format(v=2)))  # the same size
    os.utime(plug, ns=(long_ago, long_ago))  # and the same modification time
    assert run(f, tmp_path).outputs("a", "value") == 2


def test_what_a_code_file_imports_is_kept_with_its_digest_and_renewed_when_it_changes(
    tmp_path, monkeypatch
):
    # (a run parsed every source file its node types import, ~0.3 s per start for pick.yaml)
    from stereograph.core import file_index
    from stereograph.core.cache import ArtifactStore

    long_ago = time.time_ns() - 60 * 10**9
    _plugin(tmp_path, "helper_kept.py", "VALUE = 5\n")
    body = """\
        from stereograph.core.api import node, Out
        {imports}
        @node("tmp.kept", outputs={{"value": Out("Number", save=True)}})
        def kept(params):
            return {{"value": 5}}
        """
    plug = _plugin(tmp_path, "kept.py", body.format(imports=""))
    os.utime(plug, ns=(long_ago, long_ago))
    f = tmp_path / "p.yaml"
    f.write_text(f"name: k\nplugins: [{plug}]\nnodes:\n  k: {{type: tmp.kept}}\n")
    assert run(f, tmp_path).ok
    # a new process's index gives the statements without parsing the file
    monkeypatch.setattr(file_index, "import_statements", lambda path: pytest.fail(f"parsed {path}"))
    index = ArtifactStore(tmp_path / "cache").files
    assert ("stereograph.core.api", 0, ("node", "Out")) in index.statements(str(plug))
    monkeypatch.undo()
    # an edit (the stamp changes) is parsed again: the helper it now imports is in the key
    plug.write_text(textwrap.dedent(body.format(imports="from helper_kept import VALUE")))
    os.utime(plug, ns=(long_ago, long_ago))
    r = run(f, tmp_path)
    assert r.status["k"] == "ran"
    assert any(p.endswith("helper_kept.py") for p in r.state.code_digests())


def test_plugins_of_one_file_name_in_two_folders_both_load_and_import_their_neighbours(tmp_path):
    one = _plugin(
        tmp_path / "a",
        "nodes.py",
        """\
        from stereograph.core.api import node, Out
        from helper_a import VALUE
        @node("tmp.from_a", outputs={"value": Out("Number", save=True)})
        def from_a(params):
            return {"value": VALUE}
        """,
    )
    _plugin(tmp_path / "a", "helper_a.py", "VALUE = 3\n")
    two = _plugin(
        tmp_path / "b",
        "nodes.py",
        """\
        from stereograph.core.api import node, Out
        @node("tmp.from_b", outputs={"value": Out("Number", save=True)})
        def from_b(params):
            return {"value": 4}
        """,
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: ab\nplugins: [{one}, {two}]\nnodes:\n  a: {{type: tmp.from_a}}\n  b: "
        "{type: tmp.from_b}\n"
    )
    r = run(f, tmp_path)
    assert r.outputs("a", "value") == 3 and r.outputs("b", "value") == 4


def test_a_plugin_does_not_replace_an_installed_node_type(tmp_path):
    plug = _plugin(
        tmp_path,
        "clash.py",
        """\
        from stereograph.core.api import node, Out
        @node("segmenter.color", outputs={"segmentation": Out("Segmentation")})
        def color(params):
            return {"segmentation": {}}
        """,
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: c\nplugins: [{plug}]\nnodes:\n  s: {{type: source.synthetic, params: "
        "{n_views: 0}}\n"
    )
    with pytest.raises(
        ConfigError, match="defines a node type 'segmenter.color', the name of an installed node"
    ):
        build_graph(load_pipeline(f))
    from stereograph.core.registry import get

    # the built-in is still the one
    assert get("segmenter.color").fn.__module__ == "nodes.segmenters.color"


def _slow_items_pipeline(tmp_path: Path, n: int, seconds: float) -> tuple[Path, Path]:
    """A pipeline of ``n`` items, each taking ``seconds`` and leaving a file in ``marks`` when done:
    (marks folder, pipeline file)."""
    marks = tmp_path / "marks"
    marks.mkdir()
    slow = _plugin(
        tmp_path,
        "slow.py",
        f"""\
        import time, uuid
        from pathlib import Path
        from stereograph.core.api import node, Out, In
        @node("tmp.slow", inputs={{"m": In("Matrix")}}, outputs={{"v": Out("Number", save=True)}})
        def slow(params, m):
            time.sleep({seconds})
            Path({str(marks)!r}, uuid.uuid4().hex).touch()
            return {{"v": 1.0}}
        """,
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        f"name: s\nplugins: [{TOY}, {slow}]\nnodes:\n  numbers: {{type: toy.numbers, "
        f"params: {{n: {n}, "
        "size: 4}}\n  s: {type: tmp.slow, inputs: {m: numbers.items}}\n"
    )
    return marks, f


@pytest.mark.slow
def test_ctrl_c_with_workers_ends_the_workers_instead_of_waiting_for_the_queue(tmp_path):
    # (it printed "interrupted" at once, then went on computing the queued items for 20-100 s)
    import signal

    marks, f = _slow_items_pipeline(tmp_path, n=60, seconds=0.5)
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(f),
        "--allow-plugins",
        "--workers",
        "2",
        "--no-cache",
        "--out",
        str(tmp_path / "out"),
    ]
    p = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    while len(list(marks.iterdir())) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and "interrupted" in err
    done = len(list(marks.iterdir()))
    time.sleep(1.5)  # no worker left behind writing more
    # (60 items: the queue was not run out)
    assert len(list(marks.iterdir())) == done and done < 30, done


def test_json_output_stays_json_when_a_node_prints(tmp_path):
    # (a node's print() landed above the JSON on standard output: `stereograph run --json | jq`
    # broke)
    printer = _plugin(
        tmp_path,
        "printer.py",
        """\
        from stereograph.core.api import node, Out
        @node("tmp.printer", outputs={"v": Out("Number", save=True)})
        def printer(params):
            print("HELLO FROM NODE")
            return {"v": 1}
        """,
    )
    f = tmp_path / "p.yaml"
    f.write_text(f"name: pr\nplugins: [{printer}]\nnodes:\n  p: {{type: tmp.printer}}\n")
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "stereograph",
            "run",
            str(f),
            "--allow-plugins",
            "--json",
            "--no-cache",
            "--out",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert (
        out.returncode == 0
        and json.loads(out.stdout)["ok"] is True
        and "HELLO FROM NODE" in out.stderr
    )


@pytest.mark.slow
def test_sigterm_ends_a_run_like_ctrl_c_and_the_same_command_resumes(tmp_path):
    # (SIGTERM -- `kill`, a CI job's timeout -- killed a single run on the spot: its saved outputs
    # stayed without a run.json, and the same command with the same --out was refused as "not the
    # folder of an earlier stereograph run")
    import signal

    marks, f = _slow_items_pipeline(tmp_path, n=8, seconds=0.3)
    cmd = [
        sys.executable,
        "-m",
        "stereograph",
        "run",
        str(f),
        "--allow-plugins",
        "--cache-dir",
        str(tmp_path / "cache"),
        "--out",
        str(tmp_path / "out"),
    ]
    p = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    deadline = time.monotonic() + 120
    while len(list(marks.iterdir())) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(p.pid, signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and "interrupted" in err and "Traceback" not in err, err
    summary = json.loads((tmp_path / "out" / "run.json").read_text())
    assert summary["ok"] is False and "interrupted" in {n["status"] for n in summary["nodes"]}
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    summary = json.loads((tmp_path / "out" / "run.json").read_text())
    assert summary["ok"] is True and summary["nodes"][-1]["items"] == 8
    # (the items finished before the signal were not computed again)
    assert len(list(marks.iterdir())) < 8 + 8


def test_the_command_process_ends_after_its_exit_handlers_threads_and_output(tmp_path):
    """The `stereograph` command ends its process without Python's slow unloading, yet after its
    atexit handlers, with its output flushed, and never under a thread that is still running."""
    import subprocess
    import sys
    import textwrap

    marks = tmp_path / "marks"
    code = textwrap.dedent(f"""
        import atexit, sys, threading, time
        from pathlib import Path
        marks = Path({str(marks)!r})
        atexit.register(lambda: (marks / "atexit").write_text("ran"))
        if sys.argv[1] == "thread":
            def late():
                time.sleep(0.5)
                (marks / "thread").write_text("ran")
            threading.Thread(target=late).start()
        from stereograph.app.cli import main
        sys.argv = ["stereograph", "nodes"]
        sys.exit(main())
    """)
    for case in ("plain", "thread"):
        marks.mkdir(exist_ok=True)
        proc = subprocess.run(
            [sys.executable, "-c", code, case], capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
        assert "source.synthetic" in proc.stdout and proc.stdout.rstrip().endswith("┘"), (
            proc.stdout[-300:]
        )
        assert (marks / "atexit").read_text() == "ran"
        if case == "thread":
            assert (marks / "thread").read_text() == "ran"
        for f in marks.iterdir():
            f.unlink()


class _InterruptAt:
    """A progress display that presses Ctrl-C when ``node`` has finished ``n`` entries."""

    def __init__(self, node: str, n: int):
        self.node, self.n, self.done = node, n, 0

    def node_started(self, name, n_items):
        pass

    def advance(self, name):
        if name == self.node:
            self.done += 1
            if self.done == self.n:
                raise KeyboardInterrupt


@pytest.mark.slow
@pytest.mark.parametrize("node, n", [("rig → locate", 2), ("calib", 1), ("rectify", 1)])
def test_explain_after_an_interrupt_agrees_with_the_next_run(tmp_path, node, n):
    """(after Ctrl-C in the middle of the streamed items, explain said calib and rectify would run
    -- 'upstream rig will run' -- and the rerun found both cached: rig's views were, only pairs were
    not)"""
    from stereograph.core.runner import run_graph

    pipeline = Path(__file__).resolve().parents[1] / "pipelines" / "locate.yaml"
    sets = ["rig.n_scenes=4", "rig.n_views=6"]
    with pytest.raises(KeyboardInterrupt):
        run_graph(
            build_graph(load_pipeline(pipeline, sets)),
            progress=_InterruptAt(node, n),
            cache_dir=tmp_path / "c",
            out_dir=tmp_path / "first",
        )
    predicted = {
        v.node: v.fresh for v in explain(build_graph(load_pipeline(pipeline, sets)), tmp_path / "c")
    }
    actual = run_graph(
        build_graph(load_pipeline(pipeline, sets)),
        cache_dir=tmp_path / "c",
        out_dir=tmp_path / "second",
    ).status
    assert predicted == {name: s == "cached" for name, s in actual.items()}, (predicted, actual)
    if node == "rig → locate":  # the calibration views were all made: only pairs are missing
        assert predicted["calib"] and predicted["rectify"] and not predicted["locate"]
