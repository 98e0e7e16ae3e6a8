"""`stereograph run --repeat`: only the live part reruns, failed cycles are logged, interrupts end
it cleanly."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from stereograph.app.cli import main
from stereograph.app.loop import Loop
from stereograph.core.config import load_pipeline
from stereograph.core.graph import build_graph
from stereograph.core.runner import run_graph

TOY = Path(__file__).parent / "plugins" / "live_toy.py"


def pipeline(tmp_path: Path, tick: str = "{}", check: str = "{}") -> Path:
    f = tmp_path / "live.yaml"
    f.write_text(
        textwrap.dedent(f"""\
        name: live
        plugins: [{TOY}]
        nodes:
          const: {{type: toy.constant}}
          tick:
            type: toy.ticker
            params: {tick}
          check:
            type: toy.check
            params: {check}
            inputs: {{tick: tick.tick, offset: const.value}}
        """)
    )
    return f


def cycles(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "cycles.jsonl").read_text().splitlines()]


def test_only_the_live_part_reruns_and_each_cycle_is_logged(tmp_path):
    marker = tmp_path / "closed.txt"
    graph = build_graph(load_pipeline(pipeline(tmp_path, tick=f"{{marker: {marker}}}")))
    loop = Loop(4)
    r = run_graph(graph, cycles=loop, out_dir=tmp_path / "out", cache_dir=tmp_path / "cache")
    assert loop.live == ["tick", "check"] and loop.completed and loop.n_ok == 4
    log = cycles(tmp_path / "out")
    assert [c["values"]["check.result"] for c in log] == [8, 9, 10, 11]  # the ticker stayed open
    assert "const" in log[0]["nodes"] or "const" not in log[1]["nodes"]
    assert all(set(c["nodes"]) == {"tick", "check"} for c in log)
    assert r.status["const"] == "ran" and r.outputs("check", "result") == 11
    assert marker.read_text() == "closed after 4"  # closed once, at the end of the run
    run_json = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run_json["loop"]["cycles"] == 4 and run_json["loop"]["completed"]
    # A second run: the upstream comes from the cache, the live part's results were never stored.
    r2 = run_graph(graph, cycles=Loop(2), out_dir=tmp_path / "out2", cache_dir=tmp_path / "cache")
    assert r2.status["const"] == "cached" and r2.outputs("check", "result") == 9


def test_a_failed_cycle_is_logged_and_the_loop_goes_on(tmp_path):
    f = pipeline(tmp_path, check="{fail_on_multiple_of: 2}")
    code = main(["run", str(f), "--repeat", "5", "--out", str(tmp_path / "out")])
    assert code == 0
    log = cycles(tmp_path / "out")
    assert [c["status"] for c in log] == ["ok", "failed", "ok", "failed", "ok"]
    assert log[1]["failed_node"] == "check" and log[1]["error"] == "tick 2 refused"
    # the fix is kept with the reason (it was lost in a loop)
    assert log[1]["hint"] == "none needed"
    assert "check.result" not in log[1]["values"]  # nothing from the failed node


def test_the_loop_stops_when_its_source_ends(tmp_path, capsys):
    f = pipeline(tmp_path, tick="{stop_after: 3}")
    code = main(["run", str(f), "--repeat", "0", "--out", str(tmp_path / "out")])
    assert code == 1
    log = cycles(tmp_path / "out")
    assert [c["status"] for c in log] == ["ok", "ok", "ok", "failed"]
    out = capsys.readouterr()
    assert (
        "stopped: 'tick' gave no new input" in out.out
        and "the ticker ended after 3 ticks" in out.err
    )


def test_repeat_needs_a_live_node(tmp_path, capsys):
    f = tmp_path / "static.yaml"
    f.write_text(f"name: s\nplugins: [{TOY}]\nnodes:\n  const: {{type: toy.constant}}\n")
    assert main(["run", str(f), "--repeat", "2", "--out", str(tmp_path / "o")]) == 2
    assert "every node of static.yaml can be cached" in capsys.readouterr().err


@pytest.mark.slow
def test_sigterm_ends_the_loop_like_ctrl_c(tmp_path):
    marker = tmp_path / "closed.txt"
    f = pipeline(tmp_path, tick=f"{{sleep_s: 0.2, marker: {marker}}}")
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "stereograph", "run", str(f), "--repeat", "0", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
    )
    deadline = time.time() + 60
    while time.time() < deadline and not (
        (out / "cycles.jsonl").exists() and len(cycles(out)) >= 2
    ):
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    stdout, _ = proc.communicate(timeout=60)
    assert proc.returncode == 130
    # The signal lands in a node (usually: the ticker sleeps) or between two cycles; either way
    # the loop ends cleanly and run.json counts exactly the cycles logged.
    assert (
        "stopped by an interrupt during cycle" in stdout
        or "stopped by an interrupt between cycles" in stdout
    )
    run_json = json.loads((out / "run.json").read_text())
    assert run_json["loop"]["interrupted"] and run_json["loop"]["cycles"] >= 2
    assert run_json["loop"]["cycles"] == len(cycles(out))
    assert marker.read_text().startswith("closed after")  # the source was closed on the way out


def test_an_interrupt_between_cycles_ends_the_loop_after_the_last_logged_one(tmp_path):
    def stop_after_two(cycle):  # the CLI's line printer, interrupted as cycle 2 is printed
        if cycle.index == 2:
            raise KeyboardInterrupt

    graph = build_graph(load_pipeline(pipeline(tmp_path)))
    loop = Loop(0, on_cycle=stop_after_two)
    run_graph(graph, cycles=loop, out_dir=tmp_path / "out", cache_dir=tmp_path / "cache")
    assert loop.interrupted and loop.stopped == "stopped by an interrupt between cycles 2 and 3"
    assert [c["status"] for c in cycles(tmp_path / "out")] == ["ok", "ok"]
    assert json.loads((tmp_path / "out" / "run.json").read_text())["loop"]["cycles"] == 2


def test_stop_on_failure_stops_at_the_first_failed_cycle(tmp_path, capsys):
    f = pipeline(tmp_path, check="{fail_on_multiple_of: 2}")
    assert (
        main(["run", str(f), "--repeat", "5", "--stop-on-failure", "--out", str(tmp_path / "out")])
        == 1
    )
    assert [c["status"] for c in cycles(tmp_path / "out")] == ["ok", "failed"]
    assert "stopped at the first failed cycle (2)" in capsys.readouterr().out


def test_a_lasting_failure_ends_the_loop_instead_of_failing_every_cycle(tmp_path, capsys):
    # (a serial port that cannot be opened failed 1286 cycles in 15 s with --repeat 0)
    f = pipeline(tmp_path, check="{lasting_from: 3}")
    code = main(["run", str(f), "--repeat", "0", "--out", str(tmp_path / "out")])
    assert code == 1
    log = cycles(tmp_path / "out")
    assert [c["status"] for c in log] == ["ok", "ok", "failed"] and log[2]["failed_node"] == "check"
    out = capsys.readouterr()
    assert "no later cycle can change" in out.out and "the device behind tick 3 is gone" in out.err
    assert "cycle 3: failed" in out.out and "Fix: plug it in" in out.out
    # an ordinary failure still lets the loop go on
    f = pipeline(tmp_path, check="{fail_on_multiple_of: 3}")
    assert main(["run", str(f), "--repeat", "4", "--out", str(tmp_path / "out2")]) == 0
    assert [c["status"] for c in cycles(tmp_path / "out2")] == ["ok", "ok", "failed", "ok"]


def test_a_failure_outside_the_live_part_makes_cycle_1_failed_not_ok(tmp_path, capsys):
    # (a refused calibration file left every live node skipped, and the cycle was logged "ok")
    f = pipeline(tmp_path)
    f.write_text(
        f.read_text().replace(
            "const: {type: toy.constant}", "const: {type: toy.constant, params: {fail: true}}"
        )
    )
    code = main(["run", str(f), "--repeat", "3", "--out", str(tmp_path / "out")])
    assert code == 1
    log = cycles(tmp_path / "out")
    assert len(log) == 1 and log[0]["status"] == "failed" and log[0]["failed_node"] == "const"
    assert "0 ok, 1 failed" in capsys.readouterr().out


def test_a_warning_given_in_a_cycle_is_logged_and_printed_with_that_cycle(tmp_path, capsys):
    # (a live node's warning -- 'the left recording ended ... while the other goes on' -- was
    # dropped with the cycle's report when the next cycle began: in neither cycles.jsonl nor the
    # terminal)
    f = pipeline(tmp_path, tick="{warn_on: 2}")
    assert main(["run", str(f), "--repeat", "4", "--out", str(tmp_path / "out")]) == 0
    log = cycles(tmp_path / "out")
    assert [c["nodes"]["tick"]["messages"] for c in log] == [
        [],
        ["tick 2 came from a rewound source"],
        [],
        [],
    ]
    out = capsys.readouterr().out
    assert "cycle 2: ok" in out and "note: tick: tick 2 came from a rewound source" in out
    # with its cycle, not at the end
    assert out.index("note: tick: tick 2") < out.index("cycle 3: ok")


def test_an_interrupted_cycle_says_what_the_interrupted_node_did(tmp_path, capsys):
    # (an actuator holds the arm on Ctrl-C and notes it on the interrupt; the cycle's record said
    # only 'interrupted' with error null, so cycles.jsonl could not tell whether the arm was held or
    # left moving)
    f = pipeline(tmp_path, tick="{interrupt_on: 2}")
    assert main(["run", str(f), "--repeat", "0", "--out", str(tmp_path / "out")]) == 130
    log = cycles(tmp_path / "out")
    assert [c["status"] for c in log] == ["ok", "interrupted"]
    assert (
        log[1]["failed_node"] == "tick"
        and log[1]["error"] == "ticker: Ctrl-C during tick 2: held still"
    )
    assert "cycle 2: interrupted in" in (out := capsys.readouterr().out)
    assert "(during tick): ticker: Ctrl-C during tick 2: held still" in out
    run_json = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run_json["loop"]["stopped"] == "stopped by an interrupt during cycle 2 (node 'tick')"


def test_a_live_node_is_never_run_again_to_get_a_value_back(tmp_path):
    """(soak_stop.py: an interrupt half-way through a cycle's reset left refs to values no longer
    held, and writing the run folder recomputed the live nodes: the camera grabbed and the arm
    moved after Ctrl-C.) A value held in memory only and let go of is not computed again, and a
    live (uncacheable) node is never run again to get a value back."""
    from stereograph.core.api import NodeError

    graph = build_graph(load_pipeline(pipeline(tmp_path)))
    r = run_graph(graph, use_cache=False, out_dir=tmp_path / "out")
    assert r.ok and r.outputs("check", "result") == 8  # tick 1 + 7: the ticker ran once
    for ref in [("const", "value", None), ("tick", "tick", None)]:  # (let go of, no cache)
        with pytest.raises(NodeError, match="no longer held"):
            r.state.get(ref)
    with pytest.raises(NodeError, match="live node 'tick'"):
        r.state.recompute("tick", None)
    # the ticker was not called again: a call would have opened its device anew (ctx.resource)
    assert r.state.take_resource("tick:ticker") is None


def test_an_interrupt_before_a_nodes_code_began_is_not_put_on_the_node(tmp_path):
    """(soak_stop.py: a signal that landed as the engine went from 'pick' to 'act' was said to be
    'during act', and act had left no log of it: it had not begun.) The loop says where it
    landed: before the node's own code, which did nothing in that cycle."""
    calls = []

    def lost_signal_at_check_of_cycle_2():  # (calls: cycle 1: start, const, tick, check; 2: ...)
        calls.append(1)
        return "cam" if len(calls) == 7 else None

    graph = build_graph(load_pipeline(pipeline(tmp_path)))
    loop = Loop(0, stop_requested=lost_signal_at_check_of_cycle_2)
    run_graph(graph, cycles=loop, out_dir=tmp_path / "out", cache_dir=tmp_path / "cache")
    assert loop.stopped == "stopped by an interrupt during cycle 2, before node 'check' began"
    last = cycles(tmp_path / "out")[-1]
    assert last["status"] == "interrupted" and last["failed_node"] == "check"


def test_a_cycles_images_are_not_logged_as_values_whatever_their_size(tmp_path):
    # (a segmenter's overlay turned off is a 1x1 placeholder: cycles.jsonl logged it as [[[0, 0,
    # 0]]])
    plug = tmp_path / "pictures.py"
    plug.write_text(
        textwrap.dedent("""\
        import numpy as np
        from stereograph.core.api import In, Out, node

        @node("pic.draw", inputs={"tick": In("Number")},
              outputs={"overlay": Out("Image"), "mask": Out("Image"), "count": Out("Number")})
        def draw(params, tick):
            return {"overlay": np.zeros((1, 1, 3), np.uint8), "mask": np.zeros((4, 5), np.uint8),
                    "count": tick}
        """)
    )
    f = tmp_path / "p.yaml"
    f.write_text(
        textwrap.dedent(f"""\
        name: pics
        plugins: [{TOY}, {plug}]
        nodes:
          tick: {{type: toy.ticker}}
          draw: {{type: pic.draw, inputs: {{tick: tick.tick}}}}
        """)
    )
    loop = Loop(2)
    run_graph(
        build_graph(load_pipeline(f)),
        cycles=loop,
        out_dir=tmp_path / "out",
        cache_dir=tmp_path / "c",
    )
    for c in cycles(tmp_path / "out"):
        assert "draw.overlay" not in c["values"] and "draw.mask" not in c["values"], c["values"]
        assert isinstance(c["values"]["draw.count"], (int, float))


def test_after_cycle_1_a_cycle_is_one_line_unless_verbose(tmp_path, capsys):
    """(--repeat 5 printed 16 started/finished lines per cycle, also on a terminal)"""
    f = pipeline(tmp_path)
    assert main(["run", str(f), "--repeat", "4", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    after = out[out.index("cycle 1: ok") : out.index("cycle 4: ok")].splitlines()[1:]
    assert [line.split(":")[0] for line in after] == ["cycle 2", "cycle 3"], out
    # cycle 1 runs the graph: its nodes are said
    assert "tick: started" in out[: out.index("cycle 1: ok")]
    assert main(["run", str(f), "--repeat", "3", "--verbose", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "tick: started" in out[out.index("cycle 1: ok") : out.index("cycle 3: ok")]


def test_a_node_ends_the_loop_when_its_work_is_done_and_the_pipeline_bounds_it(tmp_path, capsys):
    """`ctx.stop_loop`: the cycle finishes, the loop stops, says who and why, and the run is a
    success; the pipeline's `repeat:` is what a plain `run` loops by."""
    f = pipeline(tmp_path, tick="{done_after: 3}")
    f.write_text(f.read_text().replace("nodes:", "repeat: 10\nnodes:"))
    assert (
        main(
            ["run", str(f), "--out", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "cache")]
        )
        == 0
    )
    log = cycles(tmp_path / "out")
    assert [c["status"] for c in log] == ["ok", "ok", "ok"] and log[-1]["values"][
        "check.result"
    ] == 10
    run_json = json.loads((tmp_path / "out" / "run.json").read_text())
    assert (
        run_json["loop"]["completed"]
        and run_json["loop"]["stopped"] == "stopped by node 'tick': counted to 3"
    )
    assert "stopped by node 'tick': counted to 3" in capsys.readouterr().out
    # without the node's word, `repeat:` bounds the loop; --repeat overrides it
    f.write_text(f.read_text().replace("{done_after: 3}", "{}").replace("repeat: 10", "repeat: 2"))
    assert (
        main(
            ["run", str(f), "--out", str(tmp_path / "out2"), "--cache-dir", str(tmp_path / "cache")]
        )
        == 0
    )
    assert len(cycles(tmp_path / "out2")) == 2
    assert (
        main(
            [
                "run",
                str(f),
                "--out",
                str(tmp_path / "out3"),
                "--cache-dir",
                str(tmp_path / "cache"),
                "--repeat",
                "4",
            ]
        )
        == 0
    )
    assert len(cycles(tmp_path / "out3")) == 4


def test_a_bad_repeat_in_the_pipeline_is_named_with_its_line(tmp_path):
    from stereograph.core.errors import ConfigError

    f = pipeline(tmp_path)
    f.write_text(f.read_text().replace("nodes:", "repeat: -2\nnodes:"))
    with pytest.raises(ConfigError) as e:
        load_pipeline(f)
    assert "'repeat' must be a whole number >= 0, got -2" in str(e.value) and "live.yaml:3:" in str(
        e.value
    )
