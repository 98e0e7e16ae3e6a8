"""Sources that produce their collections item by item (``items=``): caching, drops, failures,
pools."""

from __future__ import annotations

import textwrap
import time
from pathlib import Path

import pytest

from stereograph.core.executors import ProcessExecutor
from stereograph.core.runner import run_pipeline

PLUGINS = [
    Path(__file__).parent / "plugins" / "toy.py",
    Path(__file__).parent / "plugins" / "toy_items.py",
]


def write_pipeline(tmp_path: Path, params: str = "{n: 5}") -> Path:
    f = tmp_path / "p.yaml"
    f.write_text(
        textwrap.dedent(f"""\
        name: items
        plugins: [{", ".join(str(p) for p in PLUGINS)}]
        nodes:
          src:
            type: toy.produce
            params: {params}
          power:
            type: toy.power
            inputs: {{m: src.items}}
          total:
            type: toy.sum
            inputs: {{values: power.norm}}
          report:
            type: toy.table
            inputs: {{m: power.m}}
        """)
    )
    return f


def run(path: Path, tmp_path: Path, *overrides: str, **kw):
    kw.setdefault("cache_dir", tmp_path / "cache")
    return run_pipeline(path, list(overrides), out_dir=tmp_path / "out", **kw)


def test_items_are_produced_and_cached_one_by_one(tmp_path):
    p = write_pipeline(tmp_path)
    r1 = run(p, tmp_path)
    assert r1.ok and r1.reports["src"].items == 5 and r1.reports["src"].items_ran == 5
    assert r1.outputs("report", "report")["items"] == [f"m{i:03d}" for i in range(5)]
    r2 = run(p, tmp_path)
    assert set(r2.status.values()) == {"cached"}
    assert r2.outputs("total", "total") == r1.outputs("total", "total")
    # one more item: every item is produced again (the params changed), but the unchanged ones
    # keep their content key, so downstream only the new item runs
    r3 = run(p, tmp_path, "src.n=6")
    assert r3.reports["src"].items_ran == 6 and r3.reports["power"].items_ran == 1


def test_direct_call_returns_everything():
    from tests.plugins.toy_items import ProduceParams, produce

    out = produce(ProduceParams(n=3))
    assert sorted(out["items"]) == ["m000", "m001", "m002"] and out["count"] == 3


def test_dropped_and_failed_items(tmp_path):
    p = write_pipeline(tmp_path, "{n: 5, drop: [m001], fail: [m003]}")
    r = run(p, tmp_path)
    assert r.status["src"] == "partial" and r.reports["src"].items_failed == 1
    assert "m003 is broken" in r.reports["src"].error
    assert any("m001 dropped" in m for m in r.reports["src"].messages)
    assert r.outputs("report", "report")["items"] == ["m000", "m002", "m004"]
    assert r.status["power"] == "ran"


def test_every_item_dropped_fails_the_node_clearly(tmp_path):
    p = write_pipeline(tmp_path, "{n: 2, drop: [m000, m001]}")
    r = run(p, tmp_path)
    assert r.status["src"] == "failed" and r.status["power"] == "skipped"
    assert "none of its 2 items could be produced" in r.reports["src"].error
    assert "m000 dropped" in r.reports["src"].error


def test_process_pool_gives_the_serial_result(tmp_path):
    p = write_pipeline(tmp_path, "{n: 12, size: 16}")
    serial = run(p, tmp_path, use_cache=False).outputs("total", "total")
    ex = ProcessExecutor(2)
    try:
        pooled = run(p, tmp_path, use_cache=False, executor=ex)
        assert (
            pooled.ok
            and pooled.reports["src"].items_ran == 12
            and pooled.reports["power"].items_ran == 12
        )
        assert pooled.outputs("total", "total") == serial  # bit for bit
        # items made ahead: files gone
        assert not (tmp_path / "out" / ".stereograph-ahead").exists()
        cached = run(p, tmp_path, executor=ex)  # workers store the entries; a rerun adopts them all
        assert cached.outputs("total", "total") == serial
        assert set(run(p, tmp_path, executor=ex).status.values()) == {"cached"}
    finally:
        ex.close()


def test_workers_inherit_what_the_source_prepares_and_use_one_library_thread(tmp_path):
    """The first item is made in this process before the pool starts its processes, so what a source
    prepares once per process is prepared once, not again in every worker; workers run the
    libraries' own thread pools with one thread (the pool is the parallelism)."""
    import os

    log = tmp_path / "calls.txt"
    p = write_pipeline(tmp_path, f"{{n: 12, log: {log}}}")
    ex = ProcessExecutor(2)  # a new pool: its processes start at its first task
    try:
        r = run(p, tmp_path, use_cache=False, executor=ex)
    finally:
        ex.close()
    assert r.ok and r.reports["src"].items_ran == 12
    calls = [line.split() for line in log.read_text().splitlines()]
    assert len(calls) == 12
    assert [c for c in calls if c[1] == "1"] == [
        [str(os.getpid()), "1", os.environ.get("OPENCV_FOR_THREADS_NUM", "-")]
    ]
    workers = [c for c in calls if c[0] != str(os.getpid())]
    assert workers and {c[2] for c in workers} == {"1"}


def _frozen_in_worker(_):
    import gc

    return gc.get_freeze_count()


def test_workers_start_with_the_parents_objects_out_of_the_collectors_reach():
    """Before a pool forks, the objects alive are frozen (gc.freeze): a collection in a worker then
    does not write into each inherited object and copy every page holding one."""
    import gc

    ex = ProcessExecutor(2)
    try:
        counts = list(ex.map(_frozen_in_worker, [0, 1, 2]))
        assert gc.get_freeze_count() > 0
    finally:
        ex.close()
    assert min(counts) > 1000, counts  # the workers got the modules, the graph, ... frozen
    assert gc.get_freeze_count() == 0  # given back to the collector once the pool is closed


def _sigint_ignored(_):
    import signal

    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_ctrl_c_is_left_to_the_pool_owner_which_ends_its_workers_for_good():
    """A terminal's Ctrl-C reaches every process of its group: workers ignore it (one waiting for a
    task printed a KeyboardInterrupt traceback), the owner ends them (close(now=True)), and a thread
    still handing tasks over (compare's variants) gets each one lost at once, not a new pool."""
    from stereograph.core.executors import TaskLost

    ex = ProcessExecutor(2)
    try:
        assert all(ex.map(_sigint_ignored, [0, 1, 2]))
    finally:
        ex.close(now=True)
    t0 = time.perf_counter()
    later = list(ex.map(_sigint_ignored, [0, 1]))
    assert all(isinstance(r, TaskLost) for r in later) and time.perf_counter() - t0 < 5
    assert not (getattr(ex.pool, "_processes", None) or {})  # no pool was started again


def test_node_by_node_gives_the_streamed_result(tmp_path, monkeypatch):
    p = write_pipeline(tmp_path, "{n: 9, drop: [m004]}")
    streamed = run(p, tmp_path, use_cache=False)
    monkeypatch.setenv("STEREOGRAPH_STREAM", "0")
    plain = run(p, tmp_path, use_cache=False)
    assert streamed.status == plain.status and streamed.outputs("total", "total") == plain.outputs(
        "total", "total"
    )
    assert streamed.outputs("report", "report") == plain.outputs("report", "report")
    assert {n: r.items for n, r in streamed.reports.items()} == {
        n: r.items for n, r in plain.reports.items()
    }


def test_a_worker_process_that_dies_fails_its_items_not_the_run(tmp_path):
    p = write_pipeline(tmp_path, "{n: 6, kill_always: m002}")
    ex = ProcessExecutor(2)
    try:
        r = run(p, tmp_path, use_cache=False, executor=ex)
    finally:
        ex.close()
    assert r.status["src"] == "partial"
    assert "worker process died" in r.reports["src"].error
    # the tasks in flight with it are run again alone: only the one that kills its worker is lost
    assert set(r.item_errors) == {("src", "m002")}
    assert r.outputs("report", "report")["items"] == ["m000", "m001", "m003", "m004", "m005"]


def _engine_pairs(tmp_path: Path, node_yaml: str, sub: str, **kw):
    f = tmp_path / f"{sub}.yaml"
    f.write_text(f"name: {sub}\nnodes:\n  src:\n{node_yaml}")
    r = run_pipeline(
        f, [], out_dir=tmp_path / sub, cache_dir=tmp_path / "cache", keep={"src"}, **kw
    )
    return r, r.outputs("src", "pairs")


def _same(a, b) -> None:
    import numpy as np

    if isinstance(a, dict):
        assert set(a) == set(b)
        for k in a:
            _same(a[k], b[k])
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _same(x, y)
    else:
        assert a == b


def test_synthetic_pairs_item_by_item_are_the_one_call_pairs(tmp_path):
    from nodes.sources.synthetic import SyntheticParams, synthetic

    params = dict(
        image_width_px=96,
        image_height_px=72,
        focal_length_px=84,
        n_scenes=5,
        n_views=0,
        hard_cases=["border"],
        n_hard_each=1,
        min_distance_cm=30,
        max_distance_cm=60,
        seed=4,
    )
    direct = synthetic(SyntheticParams(**params))["pairs"]
    yaml = "    type: source.synthetic\n    params: " + str(params).replace("'", "") + "\n"
    r, pairs = _engine_pairs(tmp_path, yaml, "synth")
    assert r.ok and r.reports["src"].items == 6 and list(pairs) == list(direct)
    _same({k: dict(v) for k, v in pairs.items()}, direct)  # pixels, truth and split, bit for bit
    ex = ProcessExecutor(2)
    try:  # rendered in the workers, from a cold cache
        r2, pooled = _engine_pairs(tmp_path, yaml, "synth2", executor=ex, use_cache=False)
    finally:
        ex.close()
    _same(pooled, direct)


def test_files_read_item_by_item_skip_a_bad_pair(tmp_path):
    import cv2
    import numpy as np

    d = tmp_path / "imgs"
    d.mkdir()
    for n in ("a", "b", "c"):
        for side in ("left", "right"):
            cv2.imwrite(str(d / f"{side}_{n}.png"), np.full((24, 32, 3), ord(n), np.uint8))
    (d / "left_b.png").write_bytes(b"not a png")
    r, pairs = _engine_pairs(
        tmp_path,
        f"    type: source.files\n    params: {{folder: {d}, train_fraction: 1}}\n",
        "files",
    )
    assert r.ok and r.status["src"] == "ran" and list(pairs) == ["a", "c"]
    assert any("pair b skipped" in m for m in r.reports["src"].messages)
    assert int(pairs["c"]["left"][0, 0, 0]) == ord("c") and pairs["a"]["split"] == "train"


def test_a_per_item_node_reading_a_sum_of_its_region_starts_a_region_of_its_own(
    tmp_path, monkeypatch
):
    """src -> power -> picture (saved) and power -> total (all items) -> scale (per item, reads the
    total): scale cannot run with its items' first region, so it runs in a second one, fed the
    first region's values; streamed, pooled and node-by-node runs agree."""
    import numpy as np

    f = tmp_path / "two.yaml"
    f.write_text(
        textwrap.dedent(f"""\
        name: two
        plugins: [{", ".join(str(p) for p in PLUGINS)}]
        nodes:
          src: {{type: toy.produce, params: {{n: 7, size: 6}}}}
          power: {{type: toy.power, inputs: {{m: src.items}}}}
          picture: {{type: toy.picture, inputs: {{m: power.m}}}}
          total: {{type: toy.sum, inputs: {{values: power.norm}}}}
          scale: {{type: toy.scale, inputs: {{m: power.m, k: total.total}}}}
          report: {{type: toy.table, inputs: {{m: scale.m}}}}
        """)
    )
    from stereograph.core import streaming
    from stereograph.core.config import load_pipeline
    from stereograph.core.executors import SerialExecutor
    from stereograph.core.graph import build_graph
    from stereograph.core.run_state import RunState

    g = build_graph(load_pipeline(f))
    state = RunState(g, None, tmp_path, SerialExecutor(), set(), None)
    regions = streaming.plan_regions(g, list(g.order), state.producer)
    assert [(r.source, r.nodes) for r in regions] == [
        ("src", ["power", "picture"]),
        (None, ["scale"]),
    ]

    def outcome(sub, **kw):
        r = run_pipeline(f, [], out_dir=tmp_path / sub, keep={"scale"}, **kw)
        assert r.ok, {n: x.error for n, x in r.reports.items() if x.error}
        pictures = sorted(p.name for p in (tmp_path / sub / "picture" / "picture").iterdir())
        return r, r.outputs("scale", "m"), pictures

    streamed, scaled, pics = outcome("s", use_cache=False)
    assert pics == [f"m{i:03d}.png" for i in range(7)]  # written by the region, item by item
    img = streamed.outputs("picture", "picture")["m003"]  # read back from the run folder
    assert img.dtype == np.uint8 and img.shape == (24, 24)  # (toy.picture draws 4 px per element)
    ex = ProcessExecutor(2)
    try:
        pooled = outcome("p", cache_dir=tmp_path / "cache", executor=ex)
    finally:
        ex.close()
    monkeypatch.setenv("STEREOGRAPH_STREAM", "0")
    plain = outcome("n", use_cache=False)
    for other in (pooled, plain):
        assert other[2] == pics and sorted(other[1]) == sorted(scaled)
        assert all(np.array_equal(other[1][i], scaled[i]) for i in scaled)
        assert np.array_equal(other[0].outputs("picture", "picture")["m003"], img)
        assert {n: x.items for n, x in other[0].reports.items()} == {
            n: x.items for n, x in streamed.reports.items()
        }


def test_chunks_cover_the_items_in_order_and_shrink_at_the_end():
    from stereograph.core.streaming import chunk_bounds, chunk_size

    for n, workers in [(120, 2), (120, 1), (9, 2), (5, 3), (1, 2), (0, 2), (480, 4)]:
        bounds = chunk_bounds(n, workers)
        assert [i for a, b in bounds for i in range(a, b)] == list(range(n))
        sizes = [b - a for a, b in bounds]
        assert all(0 < s <= chunk_size(n, workers) for s in sizes)
        if workers > 1 and n >= 3 * workers * chunk_size(n, workers):
            # the workers finish together: the last tasks are a quarter chunk, the very last one
            # item
            quarter = max(1, chunk_size(n, workers) // 4)
            ones = workers if quarter > 1 else 0
            assert sizes[-2 * workers - ones :] == [quarter] * (2 * workers) + [1] * ones
            assert sizes == sorted(sizes, reverse=True)
    assert [b - a for a, b in chunk_bounds(120, 2)] == [8] * 13 + [6] + [2] * 4 + [1] * 2


_FIRST_NUMPY_IMPORT = """
import os, sys
seen = []

class Watch:
    def find_spec(self, name, path=None, target=None):
        if name == "numpy" and not seen:
            seen.append(os.environ.get("OPENBLAS_NUM_THREADS", "-"))
        return None

sys.meta_path.insert(0, Watch())
from stereograph.app.cli import main
rc = main(sys.argv[1:])
print("OPENBLAS_NUM_THREADS when NumPy loaded:", seen[0] if seen else "not loaded")
sys.exit(rc)
"""


@pytest.mark.slow
def test_a_workers_command_loads_numpy_with_one_blas_thread(tmp_path):
    """OpenBLAS reads its thread count once, when NumPy loads, and its idle threads spin: a
    ``--workers N`` command sets one thread per library pool before anything imports NumPy (its own
    process shares the cores with the workers). One worker keeps the libraries' defaults."""
    import os
    import subprocess
    import sys

    p = write_pipeline(tmp_path, "{n: 4}")
    env = {
        k: v
        for k, v in os.environ.items()
        if k
        not in (
            "OPENBLAS_NUM_THREADS",
            "OMP_NUM_THREADS",
            "OPENCV_FOR_THREADS_NUM",
            "MKL_NUM_THREADS",
        )
    }
    seen = {}
    for workers in ("1", "2"):
        out = subprocess.run(
            [
                sys.executable,
                "-c",
                _FIRST_NUMPY_IMPORT,
                "run",
                str(p),
                "--allow-plugins",
                "--no-cache",
                "--workers",
                workers,
                "--out",
                str(tmp_path / f"out{workers}"),
            ],
            capture_output=True,
            text=True,
            env=env,
            cwd=tmp_path,
            timeout=120,
        )
        assert out.returncode == 0, out.stdout + out.stderr
        seen[workers] = out.stdout.rsplit("NumPy loaded:", 1)[1].strip()
    assert seen == {"1": "-", "2": "1"}


def test_pool_requested_reads_the_raw_command_line():
    from stereograph.core.threads import pool_requested

    assert pool_requested(["run", "p.yaml", "--workers", "2"])
    assert pool_requested(["compare", "p.yaml", "--workers=3", "--json"])
    assert not pool_requested(["run", "p.yaml", "--workers", "1"])
    assert not pool_requested(["run", "p.yaml", "--workers", "2", "--dask", "local"])
    # the parser says what is wrong
    assert not pool_requested(["run", "p.yaml", "--workers", "two"])
    assert not pool_requested(["run", "p.yaml", "--workers"])
    assert not pool_requested(["run", "p.yaml"])


def test_nodes_after_a_pooled_region_prepare_while_the_process_waits(tmp_path, monkeypatch):
    """A node's ``prepare()`` (heavy imports) runs in a background thread of this process while the
    pool works through the region before it -- once per process -- and not at all in a serial run,
    where this process has no idle time to give it."""
    import threading
    import time

    from stereograph.core import registry, runner

    p = write_pipeline(tmp_path, "{n: 6}")
    # (other tests' pooled runs prepared it already)
    monkeypatch.setattr(runner, "_PREPARED", set())
    r = run(p, tmp_path, use_cache=False)  # serial (this also imports the plugin)
    prepared = registry.get("toy.table").fn.__globals__["PREPARED"]
    prepared.clear()
    callers = []  # the caller's own prepare (the CLI: what it prints with), after the nodes'

    def caller_prepare():
        callers.append(threading.current_thread().name)

    r = run(p, tmp_path, use_cache=False, prepare=[caller_prepare])
    assert r.ok and prepared == [] and callers == []
    ex = ProcessExecutor(2)
    try:
        r = run(p, tmp_path, use_cache=False, executor=ex, prepare=[caller_prepare])
    finally:
        ex.close()
    for _ in range(100):  # (a daemon thread: it may still be finishing when a tiny run ends)
        if prepared and callers:
            break
        time.sleep(0.05)
    assert r.ok and prepared == ["stereograph-prepare"] and callers == ["stereograph-prepare"]


def test_a_nodes_further_messages_are_printed_under_the_summary(tmp_path, capsys):
    # (only the first was shown, then '(+N more in run.json)': a warning such as 'rejected 1
    # view(s): 03' never reached the console)
    from stereograph.app.cli import main

    p = write_pipeline(tmp_path, "{n: 8, drop: [m001, m002, m003, m004, m005]}")
    assert (
        main(["run", str(p), "--out", str(tmp_path / "o"), "--cache-dir", str(tmp_path / "c")]) == 0
    )
    out = capsys.readouterr().out
    assert "(+4 more below)" in out and "note: src: item m002 dropped (on purpose)" in out
    assert (
        "note: src: item m004 dropped (on purpose)" in out
        and "note: src: +1 more in run.json" in out
    )


def test_a_chunk_whose_items_were_all_dropped_does_not_say_the_node_had_none(tmp_path):
    # ("2 ran / 2" beside "no items to process (upstream produced none)": a chunk's own note)
    drop = ", ".join(f"m{i:03d}" for i in range(12))
    r = run(write_pipeline(tmp_path, f"{{n: 16, drop: [{drop}]}}"), tmp_path)
    assert r.reports["power"].items == 4
    assert not any("no items to process" in m for m in r.reports["power"].messages)


def test_more_than_one_failed_item_is_counted_where_the_first_is_named(tmp_path, capsys):
    # (only the first failed item was named; the second was only in run.json, without a word)
    from stereograph.app.cli import main

    p = write_pipeline(tmp_path, "{n: 6, fail: [m001, m004]}")
    assert (
        main(["run", str(p), "--out", str(tmp_path / "o"), "--cache-dir", str(tmp_path / "c")]) == 1
    )
    out = capsys.readouterr()
    assert (
        "(+1 more failed items: run.json)" in out.out
        and "(and 1 more items: failed_items in run.json)" in out.err
    )


def test_a_per_item_node_after_a_failed_node_is_skipped_without_a_progress_line_of_its_items(
    tmp_path, capsys
):
    # (its region still ran: "add: started (4 items)" then "finished (4/4 items)", for a node
    # skipped)
    import json
    import textwrap

    from stereograph.app.cli import main

    plug = tmp_path / "blocked.py"
    plug.write_text(
        textwrap.dedent("""\
        from stereograph.core.api import In, NodeError, Out, node

        @node("blk.items", outputs={"v": Out("Number", collection=True)})
        def items(params):
            return {"v": {f"i{k}": float(k) for k in range(4)}}

        @node("blk.boom", inputs={"v": In("Number", gather=True)}, outputs={"x": Out("Number")})
        def boom(params, v):
            raise NodeError("boom")

        @node("blk.add", inputs={"v": In("Number"), "x": In("Number")},
              outputs={"y": Out("Number")})
        def add(params, v, x):
            return {"y": v + x}
        """)
    )
    p = tmp_path / "p.yaml"
    p.write_text(
        f"name: p\nplugins: [{plug}]\nnodes:\n  items: {{type: blk.items}}\n"
        "  boom: {type: blk.boom, inputs: {v: items.v}}\n"
        "  add: {type: blk.add, inputs: {v: items.v, x: boom.x}}\n"
    )
    capsys.readouterr()
    assert main(["run", str(p), "--allow-plugins", "--no-cache", "--out", str(tmp_path / "o")]) == 1
    out = capsys.readouterr().out
    assert "add: started" not in out and "add: finished" not in out, out
    nodes = json.loads((tmp_path / "o" / "run.json").read_text())["nodes"]
    st = {n["node"]: (n["status"], n["error"]) for n in nodes}
    assert st["add"] == ("skipped", "upstream node 'boom' did not finish"), st


def test_explain_after_failed_items_predicts_the_next_run(tmp_path):
    """(after a run where an item failed and one was dropped, explain said every node downstream
    would run -- 'upstream src will run' -- while the next run tried the two items again, they
    failed again, and everything downstream came from the cache)"""
    from stereograph.app.explain import explain
    from stereograph.core.config import load_pipeline
    from stereograph.core.graph import build_graph

    p = write_pipeline(tmp_path, "{n: 5, drop: [m001], fail: [m003]}")
    assert run(p, tmp_path).status["src"] == "partial"
    for _ in range(2):
        verdicts = {v.node: v for v in explain(build_graph(load_pipeline(p)), tmp_path / "cache")}
        actual = run(p, tmp_path).status
        assert {n: v.fresh for n, v in verdicts.items()} == {
            n: s == "cached" for n, s in actual.items()
        }, actual
        assert (
            "m003 failed; m001 dropped" in verdicts["src"].reasons[0]
            and "tried again" in verdicts["src"].reasons[0]
        )
        assert "unless" in verdicts["total"].reasons[0]


SCALE_NODE = '''
from stereograph.core.api import In, Out, Params, node

@node("mine.scale", inputs={"m": In("Matrix"), "report": In("Report")},
      outputs={"norm": Out("Number")})
def scale(params: Params, m, report):
    """A per-item node that also reads a gathering node's result (the item count)."""
    return {"norm": float(abs(m).sum()) * report["n"]}
'''


@pytest.mark.parametrize(
    "strategy",
    ["node by node", "streamed", "workers", pytest.param("dask", marks=pytest.mark.slow)],
)
def test_a_gathering_node_wired_to_a_streamed_source_sees_every_item(
    tmp_path, monkeypatch, strategy
):
    """(issue 27: a gathering node wired straight to a streamed source's output --
    segmenter.appearance on bench-fit's balls.pairs -- got no items: 'none of the 0 pairs is a train
    placement'. It ran between the source's whole part and the region that makes the items.)"""
    from stereograph.core.executors import DaskExecutor

    (tmp_path / "mine.py").write_text(SCALE_NODE)
    p = tmp_path / "p.yaml"
    p.write_text(
        textwrap.dedent(f"""\
        name: gather
        plugins: [{", ".join(str(x) for x in PLUGINS)}, mine.py]
        nodes:
          src: {{type: toy.produce, params: {{n: 5}}}}
          direct: {{type: toy.table, inputs: {{m: src.items}}}}
          scaled: {{type: mine.scale, inputs: {{m: src.items, report: direct.report}}}}
          total: {{type: toy.sum, inputs: {{values: scaled.norm}}}}
        """)
    )
    if strategy == "node by node":
        monkeypatch.setenv("STEREOGRAPH_STREAM", "0")
    executor = {"workers": lambda: ProcessExecutor(2), "dask": lambda: DaskExecutor(None, 2)}.get(
        strategy
    )
    import numpy as np

    res = run(p, tmp_path, executor=executor() if executor else None, use_cache=False)
    every = sum(float(abs(np.random.default_rng(i).normal(size=(8, 8))).sum()) for i in range(5))
    # (0.0: the table saw 0 items)
    assert res.ok and res.outputs("total", "total") == pytest.approx(5 * every)
