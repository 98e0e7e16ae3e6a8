"""Issue 13: a rerun with nothing changed is replayed from its memo (stereograph.app.rerun) without
building the graph; any change -- pipeline, code, a pruned entry, an edited result -- means a real
run."""

from __future__ import annotations

import json
import os
import shutil
import textwrap
import uuid
from pathlib import Path

import pytest

from stereograph.app import rerun
from stereograph.app.cli import main

TOY = Path(__file__).parent / "plugins" / "toy.py"

LIVE = """\
import os
from stereograph.core.api import In, NodeError, Out, node
from helper_UID import OFFSET

@node("tmp.actUID", inputs={"values": In("Number", gather=True)},
      outputs={"log": Out("Report", save=True)}, cacheable=False)
def act(params, values, ctx=None):
    # a node that must run every time (an actuator): each call leaves a line behind
    if os.environ.get("LIVE_FAIL"):
        ctx.out_dir.mkdir(parents=True, exist_ok=True)
        # (as actuator.dynamixel's)
        (ctx.out_dir / "failure_log.txt").write_text("servo 3: no answer")
        raise NodeError("servo 3 does not answer", hint="check its cable")
    with open(os.environ["LIVE_CALLS"], "a") as f:
        f.write("call\\n")
    return {"log": {"calls": len(open(os.environ["LIVE_CALLS"]).read().split()),
                    "total": OFFSET + sum(values[k] for k in sorted(values))}}
"""


def _project(tmp_path: Path, power: int = 2, live: bool = False) -> Path:
    nodes = f"""\
        numbers: {{type: toy.numbers, params: {{n: 4, size: 8}}}}
        power: {{type: toy.power, params: {{power: {power}}}, inputs: {{m: numbers.items}}}}
        total: {{type: toy.sum, inputs: {{values: power.norm}}}}
        picture: {{type: toy.picture, inputs: {{m: numbers.items}}}}
    """
    plugins = [str(TOY)]
    if live:  # (module and type names of their own: one test's plugin must not be another's)
        uid = uuid.uuid4().hex[:8]
        (tmp_path / f"helper_{uid}.py").write_text("OFFSET = 1.0\n")
        (tmp_path / f"live_{uid}.py").write_text(LIVE.replace("UID", uid))
        plugins.append(f"live_{uid}")
        nodes += f"    act: {{type: tmp.act{uid}, inputs: {{values: power.norm}}}}\n"
    p = tmp_path / "p.yaml"
    (tmp_path / "w").mkdir()
    p.write_text(
        f"name: t\nplugins: [{', '.join(plugins)}]\nnodes:\n"
        + textwrap.indent(textwrap.dedent(nodes), "  ")
    )
    return p


def _run(p: Path, tmp_path: Path, out: str) -> int:
    # (cache and run folders one level down: the plugins' folder is on sys.path, and a new entry in
    # it would read as "installed packages changed")
    return main(
        [
            "--allow-plugins",
            "run",
            str(p),
            "--cache-dir",
            str(tmp_path / "w" / "c"),
            "--out",
            str(tmp_path / "w" / out),
        ]
    )


def _summary(tmp_path: Path, out: str) -> dict:
    return json.loads((tmp_path / "w" / out / "run.json").read_text())


def _files(folder: Path) -> dict[str, bytes]:
    return {
        str(f.relative_to(folder)): f.read_bytes()
        for f in folder.rglob("*")
        if f.is_file() and f.name not in ("run.json", "report.html")
    }


@pytest.fixture(autouse=True)
def no_racy_wait(monkeypatch):
    """Files a test writes are changed "a moment ago" (their ctime cannot be set back), so no memo
    would be recorded for 2 s (rerun.RACY_NS); the test that checks that rule sets it back."""
    monkeypatch.setattr(rerun, "RACY_NS", 0)


@pytest.fixture
def calls(tmp_path, monkeypatch):
    path = tmp_path / "w" / "calls.txt"
    monkeypatch.setenv("LIVE_CALLS", str(path))
    return path


def test_a_rerun_with_nothing_changed_is_replayed_without_the_graph(tmp_path, capsys, monkeypatch):
    p = _project(tmp_path)
    assert _run(p, tmp_path, "o1") == 0
    first = capsys.readouterr().out
    monkeypatch.setattr(
        "stereograph.core.graph.build_graph", lambda *a, **k: pytest.fail("not a replay")
    )
    assert _run(p, tmp_path, "o2") == 0
    again = capsys.readouterr().out
    s1, s2 = _summary(tmp_path, "o1"), _summary(tmp_path, "o2")
    assert {n["node"]: n["status"] for n in s2["nodes"]} == dict.fromkeys(
        ["numbers", "power", "total", "picture"], "cached"
    )
    assert [n["files"] for n in s2["nodes"]] == [n["files"] for n in s1["nodes"]]
    assert s2["run_id"] != s1["run_id"] and s2["ok"]
    assert _files(tmp_path / "w" / "o2") == _files(tmp_path / "w" / "o1")
    assert (tmp_path / "w" / "o2" / "report.html").is_file()
    # the same printed results (the total), and the images are the cache's own files, not copies
    assert "total.total" in first and "total.total" in again
    assert (
        first.split("total.total")[1].split("run ")[0]
        == again.split("total.total")[1].split("run ")[0]
    )
    png = next((tmp_path / "w" / "o2" / "picture" / "picture").iterdir())
    assert png.stat().st_nlink >= 3  # cache entry, o1, o2 (and the memo): one copy on disk


def test_a_pipeline_edit_that_keeps_size_and_mtime_is_noticed(tmp_path, capsys, monkeypatch):
    p = _project(tmp_path, power=2)
    assert _run(p, tmp_path, "o1") == 0
    st = p.stat()
    p.write_text(p.read_text().replace("power: 2", "power: 3"))  # same size
    # and the old mtime back (touch -r)
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert p.stat().st_size == st.st_size and p.stat().st_mtime_ns == st.st_mtime_ns
    memo = rerun.memo_dir(tmp_path / "w" / "c", p, []) / "memo.json"
    before = json.loads(memo.read_text())["recorded_ns"]
    monkeypatch.setattr(rerun, "RACY_NS", 2_000_000_000)
    assert _run(p, tmp_path, "o2") == 0
    status = {n["node"]: n["status"] for n in _summary(tmp_path, "o2")["nodes"]}
    assert status["power"] == "ran" and status["numbers"] == "cached"
    # the file changed (its ctime) a moment ago: no memo is recorded from this run, the next decides
    assert json.loads(memo.read_text())["recorded_ns"] == before


def test_a_code_edit_in_an_imported_helper_is_noticed(tmp_path, calls, monkeypatch):
    p = _project(tmp_path, live=True)
    assert _run(p, tmp_path, "o1") == 0
    helper = next(tmp_path.glob("helper_*.py"))
    st = helper.stat()
    helper.write_text("OFFSET = 7.0\n")  # same size, old mtime: only the ctime tells
    os.utime(helper, ns=(st.st_atime_ns, st.st_mtime_ns))
    memo = json.loads((rerun.memo_dir(tmp_path / "w" / "c", p, []) / "memo.json").read_text())
    assert (
        str(helper.resolve()) in memo["inputs"]
        and str(next(tmp_path.glob("live_*.py")).resolve()) in memo["inputs"]
    )
    assert str(Path(rerun.__file__).resolve()) in memo["inputs"]  # the engine's own code too
    from stereograph.core import graph

    built = []
    real = graph.build_graph
    monkeypatch.setattr(graph, "build_graph", lambda doc: built.append(doc) or real(doc))
    assert _run(p, tmp_path, "o2") == 0
    # a real run (in this process the old helper stays imported; a new command imports it)
    assert len(built) == 1
    assert _run(p, tmp_path, "o3") == 0
    assert len(built) == 1  # and that run left a memo the next one replays


def test_nodes_that_must_run_run_again_and_plugins_must_be_allowed(
    tmp_path, calls, monkeypatch, capsys
):
    p = _project(tmp_path, live=True)
    assert _run(p, tmp_path, "o1") == 0
    monkeypatch.setattr(
        "stereograph.core.graph.build_graph", lambda *a, **k: pytest.fail("not a replay")
    )
    assert _run(p, tmp_path, "o2") == 0
    status = {n["node"]: n["status"] for n in _summary(tmp_path, "o2")["nodes"]}
    assert status["act"] == "ran" and status["power"] == "cached"
    log = json.loads((tmp_path / "w" / "o2" / "act" / "log.json").read_text())
    total = json.loads((tmp_path / "w" / "o2" / "total" / "total.json").read_text())
    assert log == {"calls": 2, "total": pytest.approx(1.0 + total)}
    assert "act.log" in capsys.readouterr().out  # its value shown as a real run shows it
    # without --allow-plugins the replay does not run the plugin's code: the real run refuses it
    monkeypatch.undo()
    code = main(
        [
            "run",
            str(p),
            "--cache-dir",
            str(tmp_path / "w" / "c"),
            "--out",
            str(tmp_path / "w" / "o3"),
        ]
    )
    assert code == 2 and "--allow-plugins" in " ".join(capsys.readouterr().err.split())
    assert calls.read_text().split() == ["call", "call"]


def test_a_pruned_entry_or_an_edited_result_means_a_real_run(tmp_path):
    p = _project(tmp_path)
    assert _run(p, tmp_path, "o1") == 0
    good = _files(tmp_path / "w" / "o1")
    png = next((tmp_path / "w" / "o1" / "picture" / "picture").iterdir())
    data = bytearray(png.read_bytes())
    data[len(data) // 2] ^= 0xFF
    with open(png, "r+b") as f:  # in place: the cache's, the memo's and o1's file are one inode
        f.write(data)
    assert _run(p, tmp_path, "o2") == 0
    assert _files(tmp_path / "w" / "o2") == good  # recomputed, never the edited picture
    picture = next(n for n in _summary(tmp_path, "o2")["nodes"] if n["node"] == "picture")
    # found by the real run's digest check, and recomputed
    assert "corrupt" in " ".join(picture["messages"])
    memo = json.loads((rerun.memo_dir(tmp_path / "w" / "c", p, []) / "memo.json").read_text())
    key = memo["entries"][0]
    shutil.rmtree(tmp_path / "w" / "c" / "objects" / key[:2] / key)
    assert _run(p, tmp_path, "o3") == 0
    assert any(n["status"] == "ran" for n in _summary(tmp_path, "o3")["nodes"])
    assert _files(tmp_path / "w" / "o3") == good


def test_a_node_that_fails_on_a_replay_fails_the_run_as_a_real_run_would(
    tmp_path, calls, monkeypatch, capsys
):
    p = _project(tmp_path, live=True)
    assert _run(p, tmp_path, "o1") == 0
    monkeypatch.setattr(
        "stereograph.core.graph.build_graph", lambda *a, **k: pytest.fail("not a replay")
    )
    monkeypatch.setenv("LIVE_FAIL", "1")
    capsys.readouterr()
    assert _run(p, tmp_path, "o2") == 1
    err = " ".join(capsys.readouterr().err.split())
    line = (
        p.read_text()
        .splitlines()
        .index(
            "  act: {type: "
            + p.read_text().split("act: {type: ")[1].split(",")[0]
            + ", inputs: {values: power.norm}}"
        )
        + 1
    )
    assert f"p.yaml:{line}" in err and "node 'act'" in err and "servo 3 does not answer" in err
    assert "Fix: check its cable" in err
    s = _summary(tmp_path, "o2")
    assert not s["ok"] and {n["node"]: n["status"] for n in s["nodes"]}["act"] == "failed"
    # the failed call left nothing; the first run's line only
    assert calls.read_text().split() == ["call"]
    # the log it wrote into its folder is the run's: a later run into that folder removes it
    assert "act/failure_log.txt" in {n["node"]: n for n in s["nodes"]}["act"]["files"]
    monkeypatch.delenv("LIVE_FAIL")
    assert _run(p, tmp_path, "o2") == 0
    assert not (tmp_path / "w" / "o2" / "act" / "failure_log.txt").exists()


READER = """\
from stereograph.core.api import Field, Out, Params, node

class P(Params):
    path: str = Field(..., description="A text file (path).")

@node("tmp.readerUID", outputs={"text": Out("Text", save=True)}, params=P,
      reads=lambda params, pipeline_dir: [pipeline_dir / params.path])
def reader(params, ctx=None):
    return {"text": ctx.path(params.path).read_text()}
"""


def test_an_edit_to_a_file_a_node_reads_is_noticed(tmp_path, monkeypatch):
    uid = uuid.uuid4().hex[:8]
    plug = tmp_path / f"reader_{uid}.py"
    plug.write_text(READER.replace("UID", uid))
    data = tmp_path / "data.txt"
    data.write_text("one")
    p = tmp_path / "p.yaml"
    p.write_text(
        f"name: r\nplugins: [{plug}]\nnodes:\n  read: {{type: tmp.reader{uid}, params: "
        "{path: data.txt}}\n"
    )
    (tmp_path / "w").mkdir()
    assert _run(p, tmp_path, "o1") == 0
    st = data.stat()
    data.write_text("two")  # same size, old mtime back
    os.utime(data, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert _run(p, tmp_path, "o2") == 0
    assert (tmp_path / "w" / "o2" / "read" / "text.json").read_text().strip() == '"two"'
    monkeypatch.setattr(
        "stereograph.core.graph.build_graph", lambda *a, **k: pytest.fail("not a replay")
    )
    assert _run(p, tmp_path, "o3") == 0  # nothing changed since: replayed, with the new text
    assert (tmp_path / "w" / "o3" / "read" / "text.json").read_text().strip() == '"two"'


PLAIN = """\
from stereograph.core.api import In, Out, node

@node("tmp.countUID", outputs={"n": Out("Number")})
def count(params):
    return {"n": 3}

@node("tmp.actUID", inputs={"n": In("Number")}, outputs={"log": Out("Report", save=True)},
      cacheable=False)
def act(params, n):
    return {"log": {"moves": n}}
"""


@pytest.mark.slow
def test_a_replay_imports_no_numpy_for_a_node_that_must_run_on_plain_data(tmp_path):
    """The replay of an actuator-like node (plain-data inputs and outputs) runs it and writes its
    run folder without NumPy, and its page without NetworkX (0.2 s of imports): a replayed rerun
    costs the node's own modules, not the engine's codecs or its graph library."""
    import subprocess
    import sys

    uid = uuid.uuid4().hex[:8]
    (tmp_path / f"plain_{uid}.py").write_text(PLAIN.replace("UID", uid))
    p = tmp_path / "p.yaml"
    p.write_text(
        f"name: t\nplugins: [plain_{uid}]\nnodes:\n  count: {{type: tmp.count{uid}}}\n"
        f"  act: {{type: tmp.act{uid}, inputs: {{n: count.n}}}}\n"
    )
    (tmp_path / "w").mkdir()
    code = (
        "import sys; from stereograph.app import rerun; rerun.RACY_NS = 0; from "
        "stereograph.app.cli import main; "
        f"rc = main(['--allow-plugins', 'run', {str(p)!r}, '--cache-dir', "
        f"{str(tmp_path / 'w' / 'c')!r}, "
        "'--out', sys.argv[1]]); "
        "print('NUMPY', 'numpy' in sys.modules, 'networkx' in sys.modules); sys.exit(rc)"
    )
    env = dict(os.environ, STEREOGRAPH_NO_REPLAY="")
    outs = []
    for out in ("o1", "o2"):
        r = subprocess.run(
            [sys.executable, "-c", code, str(tmp_path / "w" / out)],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 0, r.stdout + r.stderr
        outs.append(r.stdout)
    assert "NUMPY True True" in outs[0]  # the real run: the cache's codecs, the graph
    assert "NUMPY False False" in outs[1], outs[1]
    assert (tmp_path / "w" / "o2" / "report.html").is_file()
    s2 = _summary(tmp_path, "o2")
    assert {n["node"]: n["status"] for n in s2["nodes"]} == {"count": "cached", "act": "ran"}
    assert json.loads((tmp_path / "w" / "o2" / "act" / "log.json").read_text()) == {"moves": 3}
