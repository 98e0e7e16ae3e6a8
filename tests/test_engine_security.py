"""Issue 12: a pipeline file from someone else cannot write outside the run, run code, or hang the
tool; every user error is a located message (exit 2); the cache never serves a corrupt result.

One test (or a few) per class of the issue, each with the issue's repro.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import textwrap
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereograph.app.cli import main
from stereograph.core.runner import run_pipeline

ROOT = Path(__file__).resolve().parent.parent
TOY = ROOT / "tests" / "plugins" / "toy.py"
LOCATE = ROOT / "pipelines" / "locate.yaml"


def cli(*argv: str, capsys) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, " ".join((out.out + out.err).split())


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def toy_pipeline(tmp_path: Path, n: int = 4) -> Path:
    return write(
        tmp_path / "p.yaml",
        f"""\
        name: t
        plugins: [{TOY}]
        nodes:
          numbers: {{type: toy.numbers, params: {{n: {n}, size: 12}}}}
          power: {{type: toy.power, inputs: {{m: numbers.items}}}}
          picture: {{type: toy.picture, inputs: {{m: power.m}}}}
          total: {{type: toy.sum, inputs: {{values: power.norm}}}}
        """,
    )


def files_under(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*") if p.is_file()}


# --------------------------------------------------------------------------- writes outside the run


@pytest.mark.parametrize("name", ["/tmp/x/pwned", "../up", "a\\b", "a b", ".hidden", "a[/]b"])
def test_unsafe_node_name_is_refused(tmp_path, capsys, name):
    f = write(tmp_path / "p.yaml", f"nodes:\n  '{name}': {{type: source.synthetic}}\n")
    code, msg = cli("validate", f, capsys=capsys)
    assert code == 2, msg
    assert "p.yaml:2" in msg and "invalid node name" in msg and "internal error" not in msg


def test_unsafe_pipeline_name_is_refused(tmp_path, capsys):
    f = write(
        tmp_path / "p.yaml",
        f"name: {tmp_path / 'elsewhere'}\nnodes:\n  x: {{type: source.synthetic}}\n",
    )
    code, msg = cli("validate", f, capsys=capsys)
    assert code == 2 and "p.yaml:1" in msg and "invalid pipeline name" in msg
    # without a name, an unusual file name still gives a safe run folder
    g = tmp_path / "my pipeline (v2).yaml"
    g.write_text(
        f"plugins: [{TOY}]\nnodes:\n  numbers: {{type: toy.numbers, params: {{n: 1, size: 2}}}}\n"
    )
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        r = run_pipeline(g, cache_dir=tmp_path / "c")
    finally:
        os.chdir(cwd)
    assert r.ok and r.out_dir.parent.parent == tmp_path / "runs"
    assert "/" not in r.out_dir.parent.name and " " not in r.out_dir.parent.name


ITEMS_PLUGIN = """\
import numpy as np
from stereograph.core.api import Out, node

@node("tmp.items", outputs={"pictures": Out("Image", collection=True, save=True),
                            "records": Out("Report", collection=True, save=True)})
def items(params):
    ids = ["../../escaped", "/abs/olute", "..", "scene.001", "ok_1", "a" * 300]
    pic = np.full((16, 16), 200, np.uint8)
    return {"pictures": {i: pic for i in ids}, "records": {i: {"v": 1} for i in ids}}
"""


def test_item_ids_from_data_stay_inside_out(tmp_path):
    """A scene id such as ``../../x`` (data, not config) is encoded into one file name."""
    (tmp_path / "plug").mkdir()
    (tmp_path / "plug" / "items.py").write_text(ITEMS_PLUGIN)
    work = tmp_path / "work"
    work.mkdir()
    f = write(
        work / "p.yaml",
        f"plugins: [{tmp_path / 'plug' / 'items.py'}]\nnodes:\n  src: {{type: tmp.items}}\n",
    )
    before = files_under(tmp_path)
    out = work / "deep" / "er" / "out"
    for _ in range(2):  # the second run copies the kept renders: the same names
        r = run_pipeline(f, cache_dir=work / "c", out_dir=out)
        assert r.ok
    new = files_under(tmp_path) - before
    outside = [p for p in new if out not in p.parents and (work / "c") not in p.parents]
    assert outside == []
    names = sorted(p.name for p in (out / "src" / "pictures").iterdir())
    assert len(names) == 6 and "ok_1.png" in names and "scene.001.png" in names
    assert all("/" not in n and not n.startswith(".") and len(n) < 130 for n in names)
    records = json.loads((out / "src" / "records.json").read_text())
    # the ids themselves, as data
    assert [r["item"] for r in records][:2] == ["../../escaped", "/abs/olute"]


# --------------------------------------------------------------------------- code execution


def _plugin_that_leaves_a_trace(tmp_path: Path) -> tuple[Path, Path]:
    trace = tmp_path / "plugin-ran"
    plug = tmp_path / "evil.py"
    plug.write_text(f"open({str(trace)!r}, 'w').write('ran')\n")
    f = write(tmp_path / "p.yaml", "plugins: [evil.py]\nnodes:\n  x: {type: source.synthetic}\n")
    return f, trace


@pytest.mark.parametrize("command", ["validate", "graph", "explain", "run"])
def test_plugins_are_not_imported_without_allow_plugins(tmp_path, capsys, monkeypatch, command):
    monkeypatch.delenv("STEREOGRAPH_ALLOW_PLUGINS", raising=False)
    f, trace = _plugin_that_leaves_a_trace(tmp_path)
    extra = ["--out", tmp_path / "o", "--cache-dir", tmp_path / "c"] if command == "run" else []
    code, msg = cli(command, f, *extra, capsys=capsys)
    assert code == 2 and not trace.exists()
    assert "p.yaml:1" in msg and "--allow-plugins" in msg
    assert not (tmp_path / "o").exists()


def test_allow_plugins_imports_them(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("STEREOGRAPH_ALLOW_PLUGINS", raising=False)
    f, trace = _plugin_that_leaves_a_trace(tmp_path)
    code, msg = cli("validate", f, "--allow-plugins", capsys=capsys)
    assert code == 0 and trace.exists(), msg


@pytest.mark.parametrize(
    "body,shown",
    [
        ("import sys\nsys.exit(0)\n", "sys.exit(0)"),
        ("raise SystemExit\n", "sys.exit(None)"),
        ("raise KeyError('x')\n", "KeyError"),
    ],
)
def test_plugin_exiting_on_import_is_a_config_error(tmp_path, capsys, body, shown):
    (tmp_path / "bye.py").write_text(body)
    f = write(tmp_path / "p.yaml", "plugins: [bye.py]\nnodes:\n  x: {type: source.synthetic}\n")
    for command in ("validate", "run"):
        code, msg = cli(command, f, "--allow-plugins", capsys=capsys)
        assert code == 2, msg
        assert "p.yaml:1" in msg and "plugin 'bye.py' failed to import" in msg and shown in msg


# --------------------------------------------------------------------------- data loss


def test_out_folder_of_another_tool_is_never_emptied(tmp_path, capsys):
    out = tmp_path / "mine"
    (out / "empty_sub").mkdir(parents=True)
    (out / "run.json").write_text(json.dumps({"nodes": [{"files": ["notes.txt"]}]}))
    (out / "notes.txt").write_text("precious")
    code, msg = cli(
        "run", toy_pipeline(tmp_path), "--out", out, "--cache-dir", tmp_path / "c", capsys=capsys
    )
    assert code == 2 and "not the folder of an earlier stereograph run" in msg
    assert (out / "notes.txt").read_text() == "precious" and (out / "run.json").exists()
    assert (out / "empty_sub").is_dir()


def test_earlier_run_folder_is_cleared_of_its_own_files_only(tmp_path, capsys):
    out = tmp_path / "o"
    p = toy_pipeline(tmp_path)
    assert cli("run", p, "--out", out, "--cache-dir", tmp_path / "c", capsys=capsys)[0] == 0
    (out / "user.txt").write_text("mine")
    (out / "user_empty").mkdir()
    assert (
        cli(
            "run",
            p,
            "--out",
            out,
            "--cache-dir",
            tmp_path / "c",
            "--only",
            "numbers",
            capsys=capsys,
        )[0]
        == 0
    )
    assert (out / "user.txt").read_text() == "mine" and (out / "user_empty").is_dir()
    assert not (out / "picture").exists()  # the earlier run's own files went
    assert not list(out.rglob("*.tmp"))


def test_out_or_cache_dir_that_is_a_file(tmp_path, capsys):
    p = toy_pipeline(tmp_path)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    code, msg = cli("run", p, "--out", a_file, "--cache-dir", tmp_path / "c", capsys=capsys)
    assert code == 2 and "is an existing file" in msg and "--out" in msg
    code, msg = cli("run", p, "--out", tmp_path / "o", "--cache-dir", a_file, capsys=capsys)
    assert code == 2 and "is an existing file" in msg and "--cache-dir" in msg
    assert a_file.read_text() == "x"


# --------------------------------------------------------------------------- hangs and resource
# exhaustion


def _alias_bomb(levels: int = 9) -> str:
    lines = ["a0: &a0 [" + ", ".join(["x"] * 9) + "]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines)


def test_yaml_alias_bomb_in_file_and_set(tmp_path, capsys):
    t0 = time.perf_counter()
    f = write(
        tmp_path / "p.yaml",
        "nodes:\n  x: {type: source.synthetic}\nvariants:\n  "
        + _alias_bomb().replace("\n", "\n  ")
        + "\n",
    )
    code, msg = cli("validate", f, capsys=capsys)
    assert code == 2 and "p.yaml:" in msg and "more than" in msg and "aliases are expanded" in msg
    bomb = "{" + _alias_bomb().replace("\n", ", ") + "}"
    code, msg = cli("validate", LOCATE, "--set", f"rig.seed={bomb}", capsys=capsys)
    assert code == 2 and "--set rig.seed" in msg and "aliases are expanded" in msg
    assert time.perf_counter() - t0 < 30  # (was: no answer after 54 s and 5.6 GB)


def test_deep_nesting_and_big_files(tmp_path, capsys):
    for depth in (3000, 20000):
        f = write(
            tmp_path / "p.yaml",
            "nodes:\n  x: {type: source.synthetic, params: {seed: "
            + "[" * depth
            + "]" * depth
            + "}}\n",
        )
        code, msg = cli("validate", f, capsys=capsys)
        assert code == 2 and "p.yaml:2" in msg and "nested more than" in msg
        code, msg = cli(
            "validate", LOCATE, "--set", "rig.seed=" + "[" * depth + "]" * depth, capsys=capsys
        )
        assert code == 2 and "nested more than" in msg
    big = tmp_path / "big.yaml"
    big.write_text(
        "nodes:\n  x: {type: source.synthetic}\nvariants:\n  v: [" + "1, " * 400_000 + "1]\n"
    )
    t0 = time.perf_counter()
    code, msg = cli("validate", big, capsys=capsys)
    assert code == 2 and "larger than" in msg and time.perf_counter() - t0 < 5


def _png_claiming(path: Path, width: int, height: int) -> None:
    """A real PNG whose header claims another size (the pixels are never needed)."""
    ok, buf = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    b = bytearray(buf.tobytes())
    b[16:24] = struct.pack(">II", width, height)
    b[29:33] = struct.pack(">I", zlib.crc32(bytes(b[12:29])))
    path.write_bytes(bytes(b))


def _image_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "imgs"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        for side in ("left", "right"):
            cv2.imwrite(
                str(folder / f"{side}{i:02d}.png"),
                rng.integers(0, 255, (40, 60, 3), dtype=np.uint8),
            )
    return folder


@pytest.mark.parametrize("bad", ["zero", "truncated", "text", "huge_header"])
def test_one_unreadable_image_skips_only_its_pair(tmp_path, bad):
    folder = _image_folder(tmp_path)
    target = folder / "left01.png"
    if bad == "zero":
        target.write_bytes(b"")
    elif bad == "truncated":
        target.write_bytes(target.read_bytes()[:60])
    elif bad == "text":
        target.write_text("not an image")
    else:
        _png_claiming(target, 70000, 70000)
    f = write(
        tmp_path / "p.yaml",
        f"nodes:\n  src: {{type: source.files, params: {{folder: {folder}}}}}\n",
    )
    r = run_pipeline(f, cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    assert r.ok, r.reports["src"].error
    assert sorted(r.outputs("src", "pairs")) == ["00", "02"]
    assert any("pair 01 skipped" in m and "left01.png" in m for m in r.reports["src"].messages)


def test_pixel_limit_from_the_header_before_decoding(tmp_path):
    folder = _image_folder(tmp_path)
    f = write(
        tmp_path / "p.yaml",
        f"nodes:\n  src: {{type: source.files, params: {{folder: {folder}, "
        # 60x40 = 0.0024 Mpx: every pair too big
        "max_image_mpx: 0.002}}\n",
    )
    r = run_pipeline(f, cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    assert not r.ok and "above the limit of 0.002 Mpx" in r.reports["src"].error


def test_unreadable_calibration_view_is_rejected_with_its_reason(tmp_path):
    folder = _image_folder(tmp_path)
    (folder / "right02.png").write_bytes(b"")
    f = write(
        tmp_path / "p.yaml",
        f"nodes:\n  src: {{type: source.calib_files, params: {{folder: {folder}}}}}\n",
    )
    r = run_pipeline(f, cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    assert r.ok
    views = r.outputs("src", "views")
    assert [v["id"] for v in views["views"]] == ["00", "01"]
    assert "right02.png" in views["rejected"]["02"]


# --------------------------------------------------------------------------- user errors: exit 2,
# located


@pytest.mark.parametrize(
    "content,where,says",
    [
        (b"name: a\nnodes:\n  x: {type: source.synthetic}\n# \xff\xfe\n", "p.yaml:4", "not UTF-8"),
        (b"name: a\nnodes:\n  x: {type: source.syn\x00thetic}\n", "p.yaml:3", "U+0000"),
        (b"name: a\nnodes:\n  x: {type: source.syn\x07thetic}\n", "p.yaml:3", "U+0007"),
        (
            b"name: a\n? [a, b] : 1\nnodes:\n  x: {type: source.synthetic}\n",
            "p.yaml:2",
            "plain name",
        ),
        (b"include: 5\nnodes:\n  x: {type: source.synthetic}\n", "p.yaml:1", "'include' must be"),
        (
            b"include: [null]\nnodes:\n  x: {type: source.synthetic}\n",
            "p.yaml:1",
            "not a file name",
        ),
        (b"include: [5]\nnodes:\n  x: {type: source.synthetic}\n", "p.yaml:1", "not a file name"),
        (
            b"include: [/dev/zero]\nnodes:\n  x: {type: source.synthetic}\n",
            "p.yaml:1",
            "is not a regular file",
        ),
        (b"a: &a [1, *a]\nnodes:\n  x: {type: source.synthetic}\n", "p.yaml:1", "alias refers to"),
        (b"nodes:\n  x: {type: [source.synthetic]}\n", "p.yaml:2", "'type' must be"),
        (b"nodes:\n  x: {type: source.synthetic, params: {1: 2}}\n", "p.yaml:2", "parameter '1'"),
        (
            b"defaults:\n  segmenter.edge_morf: {canny_low: 40}\nnodes:\n  x: {type: "
            b"source.synthetic}\n",
            "p.yaml:2",
            "did you mean 'segmenter.edge_morph'",
        ),
    ],
)
def test_bad_pipeline_files_are_located_config_errors(tmp_path, capsys, content, where, says):
    f = tmp_path / "p.yaml"
    f.write_bytes(content)
    code, msg = cli("validate", f, capsys=capsys)
    assert code == 2, msg
    assert where in msg and says in msg and "internal error" not in msg and "Traceback" not in msg


def test_an_error_in_an_included_file_names_the_include_line(tmp_path, capsys):
    write(tmp_path / "common.yaml", "include: [deeper.yaml]\n")
    write(tmp_path / "deeper.yaml", "nodes:\n  x: {type: source.synthetic, paramz: {}}\n")
    f = write(tmp_path / "p.yaml", "name: p\ninclude:\n  - common.yaml\nnodes: {}\n")
    code, msg = cli("validate", f, capsys=capsys)
    assert code == 2 and "deeper.yaml:2" in msg and "'paramz'" in msg, msg
    assert "included at " in msg and "common.yaml:1" in msg and "p.yaml:3" in msg, msg
    code, msg = cli(
        "validate", write(tmp_path / "q.yaml", "include: [/etc/passwd]\n"), capsys=capsys
    )
    assert code == 2 and "/etc/passwd:1" in msg and "included at " in msg and "q.yaml:1" in msg
    # found after the files are read (the graph's checks): the same chain, innermost first
    write(tmp_path / "deeper.yaml", "nodes:\n  x: {type: source.synthetic}\n  y: {type: nosuch}\n")
    code, msg = cli("validate", f, capsys=capsys)
    chain = f"(in a file included at {tmp_path / 'common.yaml'}:1:11, in a file included at "
    assert code == 2 and "deeper.yaml:3:7: node 'y': unknown node type" in msg, msg
    assert chain + f"{tmp_path / 'p.yaml'}:3:5)" in msg, msg


@pytest.mark.parametrize("path", ["/dev/zero", "."])
def test_special_files_as_pipeline(capsys, path):
    code, msg = cli("validate", path, capsys=capsys)
    assert code == 2 and "not a regular file" in msg


def test_markup_in_user_text_is_printed_literally(tmp_path, capsys):
    f = write(tmp_path / "p.yaml", "nodes:\n  x: {type: '[bold red]a[/]b'}\n")
    code, msg = cli("validate", f, capsys=capsys)
    assert code == 2 and "unknown node type '[bold red]a[/]b'" in msg


def test_control_characters_in_user_text_cannot_drive_the_terminal(tmp_path, capsys):
    # "\e" and "\r" are valid escapes in a double-quoted YAML string: ESC [2J clears the screen,
    # ESC ]0; retitles the window, CR writes over the line
    f = write(
        tmp_path / "p.yaml", 'nodes:\n  x: {type: "source.synthetic\\e[2J\\e]0;pwned\\a\\r"}\n'
    )
    code = main(["validate", str(f)])
    out = capsys.readouterr()
    assert (
        code == 2 and "unknown node type 'source.synthetic\\x1b[2J\\x1b]0;pwned\\x07\\r'" in out.err
    )
    assert not any(c in out.out + out.err for c in "\x1b\x07\r")
    # a param holding one (here a folder) is refused before anything runs, and never printed raw
    g = write(
        tmp_path / "q.yaml",
        'nodes:\n  src: {type: source.files, params: {folder: "x\\e[2Jy\\u202e"}}\n',
    )
    code = main(["run", str(g), "--out", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "c")])
    out = capsys.readouterr()
    assert code == 2 and "folder holds a control character" in out.err, out.err
    assert not any(c in out.out + out.err for c in "\x1b\u202e")


@pytest.mark.parametrize(
    "setting,says",
    [
        ("rig.focal_length_px=1e309", "finite number"),
        ("rig.focal_length_px=.inf", "finite number"),
        ("rig.focal_length_px=.nan", "finite number"),
        ("segment.working_range_cm=[0, 0]", "must start above 0"),
        ("segment.working_range_cm=[80, 20]", "first value must be below the second"),
        ("disparity.working_range_cm=[80, 20]", "first value must be below the second"),
        ("locate.working_range_cm=[30, 30]", "first value must be below the second"),
        ("segment.edge_search_px=1e-300", "greater than or equal to 0.5"),
    ],
)
def test_values_that_would_crash_a_node_are_refused_by_validate(capsys, setting, says):
    code, msg = cli("validate", LOCATE, "--set", setting, capsys=capsys)
    assert code == 2 and f"--set {setting}" in msg and says in msg


# --------------------------------------------------------------------------- runs and the cache


def _entry_dirs(cache: Path, node: str) -> list[Path]:
    out = []
    for man in (cache / "objects").glob("*/*/manifest.json"):
        if json.loads(man.read_text())["meta"].get("node") == node:
            out.append(man.parent)
    return out


@pytest.mark.parametrize("damage", ["flip_index", "zero_item_arrays"])
def test_corrupt_collection_entry_is_recomputed(tmp_path, damage):
    p = toy_pipeline(tmp_path)
    r1 = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1")
    assert r1.ok
    entries = _entry_dirs(tmp_path / "c", "numbers")
    index = [
        d
        for d in entries
        if "item" not in json.loads((d / "manifest.json").read_text())["meta"]
        or json.loads((d / "manifest.json").read_text())["meta"]["item"] is None
    ]
    if damage == "flip_index":
        data = bytearray((index[0] / "data.json").read_bytes())
        data[len(data) // 2] ^= 0x01
        (index[0] / "data.json").write_bytes(bytes(data))
        # the copy of the index a rerun reads from the manifest, damaged too (JSON still valid)
        man = json.loads((index[0] / "manifest.json").read_text())
        man["meta"]["indexes"]["items"]["__items__"][0] += "x"
        (index[0] / "manifest.json").write_text(json.dumps(man))
    else:
        item = next(d for d in entries if (d / "arrays.npz").exists() and d not in index)
        (item / "arrays.npz").write_bytes(bytes((item / "arrays.npz").stat().st_size))
    r2 = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o2", from_node="power")
    assert r2.ok, {n: r.error for n, r in r2.reports.items() if r.error}
    assert r2.outputs("total", "total") == r1.outputs("total", "total")
    assert any("was corrupt" in m for m in r2.reports["numbers"].messages)


def test_corrupt_rendered_png_is_not_delivered(tmp_path):
    p = toy_pipeline(tmp_path)
    assert run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1").ok
    good = {f.name: f.read_bytes() for f in (tmp_path / "o1" / "picture" / "picture").iterdir()}
    # the cache keeps each image once, as the PNG the run folder gets (in its entry; older
    # entries: under rendered/): flip a byte in every copy it has
    rendered = sorted((tmp_path / "c").rglob("*.png"))
    assert rendered and not list((tmp_path / "c" / "rendered").rglob("*.png"))
    for f in rendered:
        data = bytearray(f.read_bytes())
        data[-20] ^= 0xFF
        f.write_bytes(bytes(data))
    assert run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o2").ok
    again = {f.name: f.read_bytes() for f in (tmp_path / "o2" / "picture" / "picture").iterdir()}
    assert again == good


READER_PLUGIN = """\
from pathlib import Path
from stereograph.core.api import Field, Out, Params, node

class P(Params):
    path: str = Field(..., description="File to read.")

@node("tmp.reader", outputs={"text": Out("Report")}, params=P,
      reads=lambda p, d: [d / p.path])
def reader(params, ctx=None):
    return {"text": ctx.path(params.path).read_text()}
"""


def test_input_edited_with_mtime_restored_is_noticed(tmp_path):
    (tmp_path / "reader.py").write_text(READER_PLUGIN)
    data = tmp_path / "data.txt"
    data.write_text("AAAA")
    old = time.time_ns() - 3600 * 10**9
    os.utime(data, ns=(old, old))
    f = write(
        tmp_path / "p.yaml",
        "plugins: [reader.py]\nnodes:\n  read: {type: tmp.reader, params: {path: data.txt}}\n",
    )
    assert (
        run_pipeline(f, cache_dir=tmp_path / "c", out_dir=tmp_path / "o1").outputs("read", "text")
        == "AAAA"
    )
    data.write_text("BBBB")  # same size ...
    os.utime(data, ns=(old, old))  # ... and the old mtime back, as a restore tool would
    r = run_pipeline(f, cache_dir=tmp_path / "c", out_dir=tmp_path / "o2")
    assert r.status["read"] == "ran" and r.outputs("read", "text") == "BBBB"


def _read_only_run(argv: list[str], cache: Path) -> subprocess.CompletedProcess:
    """Run the CLI with ``cache`` on a read-only file system (a read-only bind mount as root)."""
    cmd = [sys.executable, "-m", "stereograph", *argv]
    env = {**os.environ, "STEREOGRAPH_ALLOW_PLUGINS": "1"}
    if os.geteuid() != 0:
        subprocess.run(["chmod", "-R", "a-w", str(cache)], check=True)
        try:
            return subprocess.run(cmd, capture_output=True, text=True, env=env)
        finally:
            subprocess.run(["chmod", "-R", "u+w", str(cache)], check=True)
    if shutil.which("unshare") is None:
        pytest.skip("needs unshare to mount the cache read-only as root")
    script = (
        f"mount --bind {cache} {cache} && mount -o remount,ro,bind {cache} {cache} || exit 99; "
        + " ".join(f"'{a}'" for a in cmd)
    )
    res = subprocess.run(
        ["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, env=env
    )
    if res.returncode == 99:
        pytest.skip("this machine does not allow a read-only bind mount")
    return res


@pytest.mark.slow
def test_read_only_cache_still_serves_the_run(tmp_path, capsys):
    p = toy_pipeline(tmp_path)
    cache = tmp_path / "c"
    assert cli("run", p, "--cache-dir", cache, "--out", tmp_path / "o1", capsys=capsys)[0] == 0
    res = _read_only_run(
        ["run", str(p), "--cache-dir", str(cache), "--out", str(tmp_path / "o2"), "--json"], cache
    )
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert {n["status"] for n in summary["nodes"]} == {"cached"}
    assert "not writable" in res.stderr and "not writable" in summary["notes"][0]
    # a changed parameter computes without storing
    res = _read_only_run(
        [
            "run",
            str(p),
            "--cache-dir",
            str(cache),
            "--out",
            str(tmp_path / "o3"),
            "--set",
            "numbers.n=2",
        ],
        cache,
    )
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    assert (tmp_path / "o3" / "total" / "total.json").exists()


def test_stray_files_in_the_cache(tmp_path, capsys):
    p = toy_pipeline(tmp_path)
    cache = tmp_path / "c"
    assert cli("run", p, "--cache-dir", cache, "--out", tmp_path / "o", capsys=capsys)[0] == 0
    (cache / "objects" / ".DS_Store").write_bytes(b"\0\0")
    sub = next(d for d in (cache / "objects").iterdir() if d.is_dir())
    (sub / ".DS_Store").write_bytes(b"\0\0")
    code, msg = cli("cache", "info", "--cache-dir", cache, capsys=capsys)
    assert code == 0 and "entries" in msg
    code, msg = cli("cache", "prune", "--cache-dir", cache, "--max-gb", "0", capsys=capsys)
    assert code == 0 and "removed" in msg
    code, msg = cli("cache", "clear", "--cache-dir", cache, capsys=capsys)
    assert code == 0


def test_cache_clear_removes_only_what_stereograph_wrote(tmp_path, capsys):
    """`cache clear --cache-dir` pointed at the wrong folder (or a cache that holds someone's files)
    must not delete folders that merely share the cache's names (tmp/, last/, objects/)."""
    p = toy_pipeline(tmp_path)
    cache = tmp_path / "c"
    assert cli("run", p, "--cache-dir", cache, "--out", tmp_path / "o", capsys=capsys)[0] == 0
    mine = [
        cache / "tmp" / "notes.txt",
        cache / "last" / "plan.txt",
        cache / "objects" / "ab" / "abc",
        cache / "reruns" / "keep.md",
        cache / "files.json",
    ]
    (cache / "files.json").write_text("my own list of files\n")  # (not the cache's file index)
    for f in mine:
        f.parent.mkdir(parents=True, exist_ok=True)
        if not f.exists():
            f.write_text("mine")
    code, msg = cli("cache", "clear", "--cache-dir", cache, capsys=capsys)
    assert code == 0 and "removed" in msg and "removed 0 " not in msg
    assert all(f.read_text() for f in mine)
    assert sorted(p.name for p in cache.iterdir()) == [
        "files.json",
        "last",
        "objects",
        "reruns",
        "tmp",
    ]
    assert not list((cache / "objects").glob("*/*/manifest.json"))
    # the cache still works, and a second clear finds nothing of its own
    assert cli("run", p, "--cache-dir", cache, "--out", tmp_path / "o2", capsys=capsys)[0] == 0
    assert cli("cache", "clear", "--cache-dir", cache, capsys=capsys)[0] == 0
    assert all(f.read_text() for f in mine)


def _on_small_tmpfs(folder: Path, kib: int, argv: list[str]) -> subprocess.CompletedProcess:
    """Run the CLI with ``folder`` on a file system of ``kib`` KiB (a real full disk)."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare to mount a small tmpfs")
    folder.mkdir(parents=True, exist_ok=True)
    cmd = " ".join(f"'{a}'" for a in [sys.executable, "-m", "stereograph", *argv])
    # list any .tmp left behind while the (private) mount is still there
    script = (
        f"mount -t tmpfs -o size={kib}k tmpfs {folder} || exit 99; {cmd}; rc=$?; "
        f"echo LEFT:; find {folder} -name '*.tmp'; exit $rc"
    )
    env = {**os.environ, "STEREOGRAPH_ALLOW_PLUGINS": "1"}
    res = subprocess.run(
        ["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, env=env
    )
    if res.returncode == 99:
        pytest.skip("this machine does not allow mounting a tmpfs")
    return res


@pytest.mark.slow
def test_full_disk_for_out_and_for_the_cache(tmp_path):
    p = write(
        tmp_path / "p.yaml",
        f"""\
        plugins: [{TOY}]
        nodes:
          numbers: {{type: toy.numbers, params: {{n: 6, size: 64}}}}
          power: {{type: toy.power, inputs: {{m: numbers.items}}}}
          picture: {{type: toy.picture, inputs: {{m: power.m}}}}
          total: {{type: toy.sum, inputs: {{values: power.norm}}}}
        """,
    )
    disk = tmp_path / "disk"
    res = _on_small_tmpfs(
        disk, 20, ["run", str(p), "--out", str(disk / "o"), "--cache-dir", str(tmp_path / "c")]
    )
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert "could not write output" in res.stderr and "No space left on device" in res.stderr
    assert res.stdout.split("LEFT:")[-1].strip() == ""  # no half-written .tmp files in --out
    res = _on_small_tmpfs(
        disk, 24, ["run", str(p), "--out", str(tmp_path / "o"), "--cache-dir", str(disk / "c")]
    )
    assert res.returncode == 0, res.stderr
    assert (
        "cannot store more entries" in res.stderr
        and (tmp_path / "o" / "total" / "total.json").exists()
    )
    assert res.stdout.split("LEFT:")[-1].strip() == ""


def test_report_of_a_handed_run_folder_shows_only_its_own_files(tmp_path, capsys):
    # a run folder from someone else: its run.json names files elsewhere on this machine (absolute,
    # climbing out, through a symbolic link) and a 'javascript:' link; `stereograph report` must not
    # embed those files into the page (it goes wherever the page goes) nor make a script link
    secret = tmp_path / "secret.png"
    ok, png = cv2.imencode(".png", np.full((16, 16, 3), 7, np.uint8))
    secret.write_bytes(png.tobytes())
    run = tmp_path / "handed"
    (run / "a").mkdir(parents=True)
    (run / "a" / "link.png").symlink_to(secret)
    (run / "a" / "own.png").write_bytes(png.tobytes())
    (run / "a" / "t.json").write_text(json.dumps({"columns": ["k"], "rows": [["mine"]]}))
    (tmp_path / "t.json").write_text(json.dumps({"columns": ["k"], "rows": [["outside"]]}))
    files = [
        str(secret),
        "a/../../secret.png",
        "a/link.png",
        "../t.json",
        "javascript:alert(1)",
        "a/own.png",
        "a/t.json",
    ]
    (run / "run.json").write_text(
        json.dumps(
            {
                "stereograph_run": {"format": 1},
                "run_id": "x",
                "pipeline": "p",
                "ok": True,
                "nodes": [{"node": "a", "type": "t", "status": "ran", "files": files}],
            }
        )
    )
    assert main(["report", str(run)]) == 0
    page = (run / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 1 and "outside" not in page and "mine" in page
    assert 'href="javascript:' not in page and page.count("is not a file of this run folder") == 4


def test_cache_clear_removes_only_what_a_cache_holds(tmp_path, capsys):
    # a cache folder that is a folder of yours: --cache-dir ~ by mistake, or a project's symbolic
    # link .stereograph/cache -> ../.. (a repository can hold one); `cache clear` deleted its tmp/
    # and files.json
    mine = tmp_path / "home"
    (mine / "tmp").mkdir(parents=True)
    (mine / "tmp" / "thesis.tex").write_text("keep")
    (mine / "last").mkdir()
    (mine / "last" / "notes.json").write_text("{}")
    (mine / "files.json").write_text('{"photos": "keep"}')
    proj = tmp_path / "proj"
    (proj / ".stereograph").mkdir(parents=True)
    (proj / ".stereograph" / "cache").symlink_to(mine)
    (proj / ".git").mkdir()
    p = write(
        proj / "p.yaml",
        f"plugins: [{TOY}]\nnodes:\n  numbers: {{type: toy.numbers, params: {{n: 2, size: 4}}}}\n",
    )
    assert cli("--allow-plugins", "run", p, "--out", tmp_path / "o", capsys=capsys)[0] == 0
    assert any((mine / "objects").iterdir())
    code, msg = cli("cache", "clear", p, capsys=capsys)
    assert code == 0 and "removed 3 entries" in msg, msg
    assert (mine / "tmp" / "thesis.tex").read_text() == "keep" and (
        mine / "last" / "notes.json"
    ).exists()
    assert (mine / "files.json").read_text() == '{"photos": "keep"}'
    # the cache's own: gone
    assert not (mine / "objects").exists() and not (mine / "locks").exists()


def test_project_file_cannot_put_the_cache_outside_the_project(tmp_path, capsys):
    mine = tmp_path / "home"
    (mine / "tmp").mkdir(parents=True)
    (mine / "tmp" / "thesis.tex").write_text("keep")
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "pyproject.toml").write_text('[tool.stereograph]\ncache_dir = "../home"\n')
    p = write(proj / "p.yaml", "nodes:\n  rig: {type: source.synthetic, params: {n_scenes: 1}}\n")
    for argv in (["run", p, "--out", tmp_path / "o"], ["cache", "clear", p], ["explain", p]):
        code, msg = cli(*argv, capsys=capsys)
        assert (
            code == 2
            and "cache_dir = '../home' is outside the project" in msg
            and "--cache-dir" in msg
        ), msg
    assert (
        sorted(p.name for p in mine.iterdir()) == ["tmp"] and (mine / "tmp" / "thesis.tex").exists()
    )


def test_a_cache_dir_holding_the_users_own_files_json_keeps_it(tmp_path, capsys):
    """(a --cache-dir folder of the user's with a files.json of theirs: the run overwrote it with
    the cache's index of file digests)"""
    live = Path(__file__).resolve().parents[1] / "pipelines" / "live" / "calibration.yml"
    p = write(
        tmp_path / "p.yaml",
        f"""\
        name: t
        nodes:
          cal: {{type: calibrator.load, params: {{path: '{live}'}}}}
        """,
    )  # (a node that reads a file: the cache keeps its digest in files.json)
    cache = tmp_path / "mine"
    cache.mkdir()
    (cache / "files.json").write_text('{"my": "own notes"}\n')
    assert cli("run", p, "--cache-dir", cache, "--out", tmp_path / "o", capsys=capsys)[0] == 0
    assert (cache / "files.json").read_text() == '{"my": "own notes"}\n'
