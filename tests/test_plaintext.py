"""stereograph.app.plaintext prints a run's closing lines for logs and pipes exactly as rich would
(there without colours), or declines; the command then prints them with rich."""

from __future__ import annotations

import io
import json
import os
import random
import subprocess
import sys
import uuid

import pytest
from rich.cells import cell_len
from rich.console import Console
from rich.markup import escape
from rich.pretty import Pretty
from rich.table import Table

from stereograph.app import plaintext


def _console(width: int) -> tuple[Console, io.StringIO]:
    buf = io.StringIO()  # (as stereograph.app.console.command_console for a pipe)
    return Console(file=buf, highlight=False, soft_wrap=True, width=width), buf


def _value(rnd: random.Random, depth: int = 0):
    r = rnd.random()
    if depth < 4 and r < 0.25:
        keys = [
            "a",
            "object_left_cm",
            "it's",
            'say "hi"',
            "Δz_cm",
            "x" * rnd.randint(1, 40),
            "[b]",
            "wide 球",
        ]
        return {rnd.choice(keys) + str(i): _value(rnd, depth + 1) for i in range(rnd.randint(0, 6))}
    if depth < 4 and r < 0.45:
        return [_value(rnd, depth + 1) for _ in range(rnd.randint(0, 8))]
    return rnd.choice(
        [
            None,
            True,
            False,
            rnd.randint(-(10**6), 10**6),
            rnd.uniform(-1e3, 1e3),
            round(rnd.uniform(-100, 100), 2),
            "x" * rnd.randint(0, 260),
            "a \"q\" 'b' \\ [red]",
            "",
            "±0.5 cm → 1 σ",
            "tab\there",
            ":smile:",
        ]
    )


def test_pretty_values_are_printed_as_rich_prints_them():
    rnd = random.Random(7)
    compared = declined = 0
    for _ in range(600):
        value = json.loads(json.dumps(_value(rnd)))
        width = rnd.choice([20, 40, 80, 160])
        mine = plaintext.pretty(value, width)
        if mine is None:
            declined += 1
            continue
        con, buf = _console(width)
        con.print(Pretty(value, indent_guides=False, max_string=200))
        assert mine + "\n" == buf.getvalue(), (value, width)
        compared += 1
    assert compared > 400 and declined > 10  # (wide characters are declined, not guessed)


def test_summary_tables_and_rules_are_printed_as_rich_prints_them():
    rnd = random.Random(3)
    cells = ["", "0.00", "0 ran / 120", "RMS 0.0526 px, mean |Δy| 0.040 px", "a [b] \\c", "x" * 70]
    odd = ["wide 球", ":warning: low", "tab\tcell"]
    compared = 0
    for _ in range(300):
        columns = ["c" * rnd.randint(1, 8) for _ in range(rnd.randint(1, 6))]
        rows = [
            [rnd.choice(odd if rnd.random() < 0.03 else cells) for _ in columns]
            for _ in range(rnd.randint(0, 5))
        ]
        width = rnd.choice([40, 80, 160])
        title = rnd.choice(["run 20261123-191035-44f9", "run x", "r" * 50])
        con, buf = _console(width)
        t = Table(*columns, title=title, title_justify="left")
        for r in rows:
            t.add_row(*(escape(c) for c in r))
        con.print(t)
        mine = plaintext.table(title, columns, rows, width)
        if mine is not None:
            assert mine + "\n" == buf.getvalue(), (columns, rows, width)
            compared += 1
        if any(c in odd for r in rows for c in r):
            # what rich lays out otherwise (two-cell characters, emoji codes, tabs)
            assert mine is None
    assert compared > 60  # (the rest: wider than the console, rich wraps them)
    for title in ["act.log", "a [b] c", "x" * 150, "node.out_Δ"]:
        con, buf = _console(160)
        con.rule(escape(title), align="left")
        assert plaintext.rule(title, 160) + "\n" == buf.getvalue()
    assert plaintext.rule("x" * 159, 160) is None  # rich would cut it


def test_every_character_counted_as_one_cell_is_one_cell_for_rich():
    accepted = [chr(o) for o in range(0x110000) if plaintext._one_cell(chr(o))]
    assert len(accepted) > 1500
    assert [c for c in accepted if cell_len(c) != 1] == []


def test_the_plain_path_is_only_for_output_that_is_not_a_terminal(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    assert plaintext.plain_width(io.StringIO(), 160) == 160
    assert plaintext.plain_width(Tty(), 160) is None
    monkeypatch.setenv("FORCE_COLOR", "1")  # rich would colour a pipe: leave it to rich
    assert plaintext.plain_width(io.StringIO(), 160) is None


PIPELINE = """\
name: t
plugins: [{toy}]
nodes:
  numbers: {{type: toy.numbers, params: {{n: 3, size: 8}}}}
  power: {{type: toy.power, params: {{power: 2}}, inputs: {{m: numbers.items}}}}
  total: {{type: toy.sum, inputs: {{values: power.norm}}}}
"""


@pytest.mark.slow
def test_a_replayed_run_prints_what_rich_prints_without_importing_it(tmp_path):
    toy = os.path.join(os.path.dirname(__file__), "plugins", "toy.py")
    p = tmp_path / "p.yaml"
    p.write_text(PIPELINE.format(toy=toy))
    code = (
        "import sys; from stereograph.app import rerun; rerun.RACY_NS = 0; from "
        "stereograph.app.cli import main; "
        f"rc = main(['--allow-plugins', 'run', {str(p)!r}, '--cache-dir', {str(tmp_path / 'c')!r}, "
        "'--out', sys.argv[1]]); print('RICH', 'rich' in sys.modules); sys.exit(rc)"
    )
    outs = {}
    for name, extra in (("cold", {}), ("plain", {}), ("rich", {"TTY_COMPATIBLE": "0"})):
        env = {
            k: v
            for k, v in os.environ.items()
            if k not in ("FORCE_COLOR", "TTY_COMPATIBLE", "STEREOGRAPH_NO_REPLAY")
        }
        out = tmp_path / uuid.uuid4().hex
        r = subprocess.run(
            [sys.executable, "-c", code, str(out)],
            env={**env, **extra},
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 0, r.stdout + r.stderr
        run_id = json.loads((out / "run.json").read_text())["run_id"]
        outs[name] = r.stdout.replace(run_id, "RUN").replace(str(out), "OUT")
    assert "RICH False" in outs["plain"] and "RICH True" in outs["rich"]
    assert "total.total" in outs["plain"] and "│ total" in outs["plain"]
    assert outs["plain"].replace("RICH False", "") == outs["rich"].replace("RICH True", "")


def test_the_console_shows_floats_at_a_glance_and_the_run_folder_keeps_them():
    """A terminal value's floats are shown to 4 significant digits (whole digits kept); the value
    itself, as run.json and the output files hold it, is untouched."""
    from stereograph.app.console import echo_entry

    value = {"z_mean_cm": -0.05870309273607587, "n": 55, "f_px": 514.91234, "big": 1234567.3}
    value["per_pair"] = [0.0072564784611959384, 0.0, float("nan")]
    kind, text = echo_entry(value)
    assert kind == "json"
    assert text == (
        '{"z_mean_cm": -0.0587, "n": 55, "f_px": 514.9, "big": 1234567.0, '
        '"per_pair": [0.007256, 0.0, null]}'
    )
    assert value["z_mean_cm"] == -0.05870309273607587
