"""Node kinds share contracts (``nodes/contracts/``), not each other's private modules.

Walks every import statement of every module under ``nodes/`` (top-level and inside functions,
absolute and relative) and fails when a module of one kind imports a ``_``-prefixed module of
another kind.
"""

from __future__ import annotations

import ast
from pathlib import Path

NODES = Path(__file__).resolve().parents[1] / "nodes"
SHARED = {"contracts"}  # public to every kind


def _module_parts(path: Path) -> list[str]:
    rel = path.relative_to(NODES.parent).with_suffix("")
    parts = list(rel.parts)
    return parts[:-1] if parts[-1] == "__init__" else parts


def _imported_modules(path: Path) -> list[tuple[int, list[str]]]:
    """``(line, dotted module parts)`` of every import in a file, relative imports resolved."""
    tree = ast.parse(path.read_text(), filename=str(path))
    here = _module_parts(path)
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            found += [(n.lineno, a.name.split(".")) for a in n.names]
        elif isinstance(n, ast.ImportFrom):
            base = (package[: len(package) - (n.level - 1)] if n.level else [])
            mod = base + (n.module.split(".") if n.module else [])
            found.append((n.lineno, mod))
            # ``from nodes.sources import _render`` imports a module too
            found += [(n.lineno, [*mod, a.name]) for a in n.names]
    return found


def cross_kind_private_imports() -> list[str]:
    bad = []
    for path in sorted(NODES.rglob("*.py")):
        parts = _module_parts(path)
        kind = parts[1] if len(parts) > 1 else None
        for line, mod in _imported_modules(path):
            if len(mod) < 3 or mod[0] != "nodes" or mod[1] == kind or mod[1] in SHARED:
                continue
            private = [i for i, p in enumerate(mod) if i >= 2 and p.startswith("_") and not p.startswith("__")]
            if private:  # name the private module (or a private name of a public module) once
                entry = f"{path.relative_to(NODES.parent).as_posix()}:{line} imports {'.'.join(mod[:private[0] + 1])}"
                if entry not in bad:
                    bad.append(entry)
    return bad


def test_no_kind_imports_another_kinds_private_module():
    bad = cross_kind_private_imports()
    assert not bad, ("move what these share into nodes/contracts/ (see docs/artifacts.md):\n  "
                     + "\n  ".join(bad))


def test_the_walk_sees_private_imports(tmp_path):
    # The check itself can fail: a planted cross-kind private import is reported.
    fake = tmp_path / "nodes"
    (fake / "ik").mkdir(parents=True)
    (fake / "actuators").mkdir()
    (fake / "ik" / "_model.py").write_text("X = 1\n")
    (fake / "actuators" / "a.py").write_text("def f():\n    from nodes.ik._model import X\n    return X\n")
    (fake / "actuators" / "b.py").write_text("from nodes.ik import _model\nfrom ._own import Y\n")
    globals()["NODES"], old = fake, NODES
    try:
        bad = cross_kind_private_imports()
    finally:
        globals()["NODES"] = old
    assert bad == ["nodes/actuators/a.py:2 imports nodes.ik._model", "nodes/actuators/b.py:1 imports nodes.ik._model"]
