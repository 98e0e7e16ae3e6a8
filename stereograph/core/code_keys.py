"""What a node's code is, for its entries' keys: its module and every project-local module it
imports, transitively, with their digests (:func:`code_hash`).

The engine, the standard library and installed packages are not project code. A file's import
statements depend on its bytes only, so a store's file index keeps them (``index``: a
:class:`~stereograph.core.file_index.FileIndex`). Public: :func:`code_hash`,
:func:`code_files`, :func:`import_statements`.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import sys
import sysconfig
from functools import lru_cache
from pathlib import Path
from typing import Any

from stereograph.core.digests import digest, hash_json

_SYSTEM_DIRS = tuple(
    str(Path(p).resolve())
    for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
)
_ENGINE_DIR = str(Path(__file__).resolve().parent)


def _is_local(path: str) -> bool:
    """Project-local source (not stdlib, not site-packages, not the engine itself)."""
    p = str(Path(path).resolve())
    return p.endswith(".py") and not p.startswith(_SYSTEM_DIRS) and not p.startswith(_ENGINE_DIR)


@lru_cache(maxsize=1024)
def _top_is_local(top: str) -> bool:
    """Whether a top-level package could hold project-local modules. Asking about ``pkg.sub``
    imports ``pkg``: for a site-packages or stdlib package (matplotlib, say) that costs a second
    and cannot find anything local, so such names are not looked up at all."""
    try:
        spec = importlib.util.find_spec(top)  # a top-level name imports nothing
    except (ImportError, ValueError, AttributeError):
        return False
    if spec is None:
        return False
    if spec.origin and spec.origin not in ("namespace", "built-in", "frozen"):
        return _is_local(spec.origin)
    return any(
        _is_local(str(Path(p) / "__init__.py")) for p in (spec.submodule_search_locations or [])
    )


def _find_origin(name: str) -> str | None:
    if "." in name and not _top_is_local(name.partition(".")[0]):
        return None
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError, AttributeError):
        return None
    return spec.origin if spec and spec.origin and spec.origin.endswith(".py") else None


def import_statements(path: str) -> tuple:
    """The import statements of a source file, ``(module, level, names)`` each (``import a.b``:
    ``("a.b", 0, ())``); what a file imports depends on its bytes only (:class:`FileIndex` keeps
    it, so that a run parses only the files changed since)."""
    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return ()
    out: list[tuple] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, 0, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.module or "", node.level, tuple(a.name for a in node.names)))
    return tuple(out)


@lru_cache(maxsize=512)
def _statements_at(path: str, mtime_ns: int) -> tuple:
    return import_statements(path)  # (without a store: once per file and process)


@lru_cache(maxsize=512)
def _imports_of(statements: tuple, package: str) -> tuple[str, ...]:
    """Local modules a file's import statements import (resolved to file paths)."""
    names: list[str] = []
    for module, level, members in statements:
        if not members:  # import a.b
            names.append(module)
            continue
        base = module
        if level:
            parts = package.split(".") if package else []
            parts = parts[: len(parts) - (level - 1)] if level > 1 else parts
            base = ".".join(parts + ([module] if module else []))
        names.append(base)
        names += [f"{base}.{a}" for a in members if base]
    found = []
    for n in names:
        if not n:
            continue
        origin = _find_origin(n)
        if origin and _is_local(origin):
            found.append(str(Path(origin).resolve()))
    return tuple(sorted(set(found)))


@lru_cache(maxsize=8192)
def _resolved(file: str) -> str:
    return str(Path(file).resolve())


# resolved module file -> module name, for the sys.modules it was built from
_NAMES: dict[str, str] = {}
_NAMES_SEEN = [0]


def _module_name_for(path: str) -> str:
    # resolving every loaded module's path on every call was most of a cached rerun's time
    if len(sys.modules) != _NAMES_SEEN[0] or path not in _NAMES:
        _NAMES.clear()
        for name, mod in list(sys.modules.items()):
            f = getattr(mod, "__file__", None)
            if isinstance(f, str):
                _NAMES.setdefault(_resolved(f), name)
        _NAMES_SEEN[0] = len(sys.modules)
    return _NAMES.get(path, "")


def code_files(module_file: str, index: Any = None) -> list[str]:
    """A node module and every project-local module it imports, transitively (each file's import
    statements from ``index`` where it has them)."""
    seen: set[str] = set()
    todo = [str(Path(module_file).resolve())]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        modname = _module_name_for(path)
        package = modname if path.endswith("__init__.py") else modname.rpartition(".")[0]
        try:
            mtime = os.stat(path).st_mtime_ns
        except OSError:
            continue
        statements = index.statements(path) if index else _statements_at(path, mtime)
        todo += [p for p in _imports_of(statements, package) if p not in seen]
    return sorted(seen)


def code_hash(fn: Any, index: Any = None) -> tuple[str, dict[str, str]]:
    """Digest of a node function's source and its local imports, and the per-file digests
    (through a store's ``index`` when given: files unchanged since are neither read nor parsed)."""
    mod = sys.modules.get(fn.__module__)
    module_file = getattr(mod, "__file__", None)
    if not module_file:
        return digest(fn.__qualname__.encode()), {}
    files = {}
    for f in code_files(module_file, index):
        if index is not None:
            files[f] = index.digest(Path(f))
            continue
        try:
            files[f] = digest(Path(f).read_bytes())
        except OSError:
            files[f] = "missing"
    return hash_json(files), files
