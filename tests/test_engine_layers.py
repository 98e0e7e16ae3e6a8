"""The engine's two layers (issue 27): ``stereograph.core`` never imports ``stereograph.app``, and
no module of ``stereograph/`` imports itself back through others. Every import counts, at the top of
a module or inside a function; each check is also run on a planted violation to show it can fail.
"""

from __future__ import annotations

import ast
import inspect
import re
import shutil
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1]


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path, root: Path) -> set[str]:
    """What a file imports anywhere in it: ``import x`` gives x, ``from x import y`` gives x.y (the
    module y of package x, or the name y of module x: :func:`import_graph` tells them apart)."""
    me = module_name(path, root)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found |= {f"{base}.{a.name}" for a in node.names}
    return {m for m in found if m == "stereograph" or m.startswith("stereograph.")}


def import_graph(root: Path) -> nx.DiGraph:
    """Module -> module edges between the files of the package at ``root``."""
    files = {module_name(p, root): p for p in root.rglob("*.py")}
    g = nx.DiGraph()
    g.add_nodes_from(files)
    for name, path in files.items():
        for target in imports_of(path, root):
            while target not in files and "." in target:
                target = target.rpartition(".")[0]
            if target in files and target != name:
                g.add_edge(name, target)
    return g


def layer_violations(root: Path) -> list[str]:
    g = import_graph(root)
    return sorted(
        f"{a} imports {b}"
        for a, b in g.edges
        if a.startswith("stereograph.core") and not b.startswith("stereograph.core")
    )


def circles(root: Path) -> list[list[str]]:
    return [sorted(c) for c in nx.strongly_connected_components(import_graph(root)) if len(c) > 1]


def test_the_core_never_imports_the_app():
    assert layer_violations(ROOT / "stereograph") == []


def test_no_module_imports_itself_back():
    assert circles(ROOT / "stereograph") == []


def test_the_checks_fail_on_a_planted_violation(tmp_path):
    copy = tmp_path / "stereograph"
    shutil.copytree(ROOT / "stereograph", copy, ignore=shutil.ignore_patterns("__pycache__"))
    # inside a function, where a reader would not look
    with open(copy / "core" / "cache.py", "a") as f:
        f.write("\n\ndef _planted():\n    from stereograph.app import rerun\n\n    return rerun\n")
    assert layer_violations(copy) == ["stereograph.core.cache imports stereograph.app.rerun"]
    assert any({"stereograph.app.rerun", "stereograph.core.cache"} <= set(c) for c in circles(copy))


# Imported inside a core function on purpose: slow to import (cv2, NumPy, networkx, pydantic
# through the node API, importlib.metadata behind the registry's index) or optional (Dask,
# filelock).
LAZY_OK = {
    "cv2",
    "numpy",
    "networkx",
    "dask",
    "distributed",
    "filelock",
    "importlib",
    "stereograph",
}


def lazy_imports(root: Path, allowed: set[str] = LAZY_OK) -> list[str]:
    """``file:line module`` of each import inside a function of ``root``'s modules that is not of a
    module slow to import or optional (:data:`LAZY_OK`): those go at the top, where a reader
    looks."""
    found = []
    for path in sorted(root.glob("*.py")):
        for fn in ast.walk(ast.parse(path.read_text())):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and not node.level:
                    names = [node.module or ""]
                else:
                    continue
                found += [
                    f"{path.name}:{node.lineno} {n}"
                    for n in names
                    if n.partition(".")[0] not in allowed
                ]
    return sorted(set(found))


def test_core_modules_import_at_the_top(tmp_path):
    """(issue 27) A core module's imports are at its top, but for the slow and the optional; an
    app module may also put off the libraries that draw (rich, matplotlib) and pydantic, so that
    `stereograph --help` stays fast."""
    assert lazy_imports(ROOT / "stereograph" / "core") == []
    drawing = LAZY_OK | {"rich", "matplotlib", "pydantic"}
    assert lazy_imports(ROOT / "stereograph" / "app", drawing) == []
    (tmp_path / "m.py").write_text("import os\n\n\ndef f():\n    import re\n    import cv2\n")
    assert lazy_imports(tmp_path) == ["m.py:5 re"]


def test_the_reading_map_names_every_core_module_in_order():
    """The package docstring and the README's engine section list every ``core/`` module, in one
    order."""
    core = {p.stem for p in (ROOT / "stereograph" / "core").glob("*.py") if p.stem != "__init__"}
    doc = (ROOT / "stereograph" / "__init__.py").read_text().split('"""')[1]
    in_doc = re.findall(r"stereograph\.core\.([a-z_]+)", doc)
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## The engine in brief") :]
    section = section[: section.index("\n## ", 4)]
    in_readme = re.findall(r"stereograph/core/([a-z_]+)\.py", section)
    assert set(in_doc) == core, sorted(core ^ set(in_doc))
    assert in_readme == in_doc


def long_modules(root: Path, limit: int = 600) -> list[str]:
    """Modules of ``root`` longer than ``limit`` lines."""
    found = []
    for path in sorted(root.glob("*.py")):
        n = len(path.read_text().splitlines())
        if n > limit:
            found.append(f"{path.name} ({n} lines)")
    return found


def test_every_core_module_reads_in_one_sitting(tmp_path):
    """(issue 27) One concept per core module, none over 600 lines: a module that grows past it
    is split by what its parts do."""
    assert long_modules(ROOT / "stereograph" / "core") == []
    (tmp_path / "grown.py").write_text("x = 1\n" * 601)
    (tmp_path / "fits.py").write_text("x = 1\n" * 600)
    assert long_modules(tmp_path) == ["grown.py (601 lines)"]


def long_functions(root: Path, limit: int = 60, docstrings: bool = True) -> list[str]:
    """Functions of ``root`` longer than ``limit`` lines, docstring included (or not)."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for n in ast.walk(ast.parse(path.read_text())):
            if not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            lines = n.end_lineno - n.lineno + 1
            doc = n.body[0]
            if not docstrings and ast.get_docstring(n) is not None:
                lines -= doc.end_lineno - doc.lineno + 1
            if lines > limit:
                found.append(f"{path.name}:{n.lineno} {n.name} ({lines} lines)")
    return found


def test_every_core_function_fits_on_a_screen(tmp_path):
    """(issue 27) No function in core/ over 60 lines; none in app/, the node library or the servo
    emulator over 60 lines of code; none in any of them over complexity 15 (ruff's C901, set in
    pyproject.toml); each check shown failing on a planted function."""
    import subprocess
    import sys

    assert long_functions(ROOT / "stereograph" / "core") == []
    # the commands and pages, the node library and the servo emulator too; a public function's
    # NumPy docstring does not count there
    for part in (ROOT / "stereograph" / "app", ROOT / "nodes", ROOT / "simbench"):
        assert long_functions(part, docstrings=False) == [], part
    planted = tmp_path / "core"
    planted.mkdir()
    body = "".join(f"    if x == {i}:\n        return {i}\n" for i in range(40))
    (planted / "big.py").write_text(f"def big(x):\n{body}    return -1\n")
    assert long_functions(planted) == ["big.py:1 big (82 lines)"]
    app = tmp_path / "app"
    app.mkdir()
    doc = '    """Long.\n' + "    x\n" * 30 + '    """\n'
    body = "".join(f"    if x == {i}:\n        return {i}\n" for i in range(29))
    (app / "big.py").write_text(f"def big(x):\n{doc}{body}    return -1\n")
    assert long_functions(app, docstrings=False) == []
    (app / "big.py").write_text(f"def big(x):\n{doc}{body}    x += 1\n    return -1\n")
    assert long_functions(app, docstrings=False) == ["big.py:1 big (61 lines)"]
    import tomllib

    limit = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["ruff"]["lint"]["mccabe"][
        "max-complexity"
    ]
    assert limit == 15
    ruff = [sys.executable, "-m", "ruff", "check", "--quiet", "--select", "C901"]
    # project config
    done = subprocess.run(
        [*ruff, "stereograph", "nodes", "simbench"], cwd=ROOT, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout
    done = subprocess.run(
        [*ruff, "--isolated", "--config", f"lint.mccabe.max-complexity={limit}", str(planted)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1 and "too complex (41 > 15)" in done.stdout, done.stdout


def long_docstrings(root: Path, limit: int = 10) -> list[str]:
    """Modules of ``root`` whose docstring is longer than ``limit`` lines (the package's reading map
    aside)."""
    found = []
    for path in sorted(root.rglob("*.py")):
        if path == root / "__init__.py":
            continue
        doc = ast.get_docstring(ast.parse(path.read_text()), clean=False) or ""
        if len(doc.strip().splitlines()) > limit:
            found.append(f"{path.relative_to(root)} ({len(doc.strip().splitlines())} lines)")
    return found


def test_every_engine_module_docstring_scans(tmp_path):
    """Purpose, invariants, public names in at most ten lines; the long stories live in
    docs/engine.md."""
    assert long_docstrings(ROOT / "stereograph") == []
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "told.py").write_text('"""' + "a line\n" * 11 + '"""\n')
    assert long_docstrings(tmp_path) == ["pkg/told.py (11 lines)"]


def run_state_reaches(root: Path, private: set[str], own: set[str]) -> list[str]:
    """Where a module of ``root`` other than RunState's own (``own``: file names) touches one of
    ``private``."""
    found = []
    for path in sorted(root.rglob("*.py")):
        if path.name in own:
            continue
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, ast.Attribute) and n.attr in private:
                found.append(f"{path.name}:{n.lineno} .{n.attr}")
    return found


def test_only_run_state_touches_its_tables(tmp_path):
    """(issue 27, part 2) RunState's tables (keys, values, items, failures, ...) are its own:
    streaming, outputs, the runner and the app go through its methods."""
    tree = ast.parse((ROOT / "stereograph" / "core" / "run_state.py").read_text())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "RunState")
    init = next(n for n in cls.body if isinstance(n, ast.FunctionDef) and n.name == "__init__")
    private = {
        t.attr
        for n in ast.walk(init)
        for t in (n.targets if isinstance(n, ast.Assign) else [getattr(n, "target", None)])
        if isinstance(t, ast.Attribute) and t.attr.startswith("_")
    }
    assert {"_mem", "_ref_keys", "_items", "_failed_items", "_keys"} <= private
    # its own modules: run_state.py and those of its bases (node_run.py, part_run.py)
    from stereograph.core.run_state import RunState

    own = {
        Path(inspect.getfile(c)).name
        for c in RunState.__mro__
        if c.__module__.startswith("stereograph.core.")
    }
    assert own == {"run_state.py", "node_run.py", "part_run.py"}
    assert run_state_reaches(ROOT / "stereograph", private, own) == []
    (tmp_path / "streaming.py").write_text("def f(run):\n    return run._mem[('a', 'b', None)]\n")
    assert run_state_reaches(tmp_path, private, own) == ["streaming.py:2 ._mem"]
