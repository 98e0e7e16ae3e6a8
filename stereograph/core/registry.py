"""Node types: the ``stereograph.nodes`` entry-point group, plus plugins a pipeline imports.

Entry points are read without importing anything, so listing names and "did you mean" are
cheap; a node's module is imported the first time the node is used.
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import importlib
import importlib.util
import json
import os
import sys
import time
from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereograph.core.digests import RACY_NS, digest, file_digest
from stereograph.core.errors import ConfigError, Where
from stereograph.core.outputs import write_whole

if TYPE_CHECKING:
    from stereograph.core.api import NodeSpec

GROUP = "stereograph.nodes"
COMMANDS_GROUP = "stereograph.commands"


class EntryPoint:
    """A named ``module:attr`` reference, imported on :meth:`load` (what ``importlib.metadata``
    gives, without its import and its scan of every installed package)."""

    def __init__(self, name: str, value: str):
        self.name, self.value = name, value

    def load(self):
        module, _, attr = self.value.partition(":")
        obj = importlib.import_module(module.strip())
        for part in filter(None, attr.strip().split(".")):
            obj = getattr(obj, part)
        return obj


def _fingerprint() -> list:
    """What installing or removing a package changes: the folders on ``sys.path`` and their mtimes
    (a new or rewritten ``*.dist-info`` changes its folder's mtime)."""
    out = []
    for p in sys.path:
        try:
            out.append([p, os.stat(p or ".").st_mtime_ns])
        except OSError:
            out.append([p, None])
    return out


def index_file() -> Path:
    """The entry-point index's file: one folder per Python environment (two virtual environments
    must not take turns rewriting it)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    env = hashlib.blake2b(sys.prefix.encode(), digest_size=6).hexdigest()
    return Path(base) / "stereograph" / env / "entry-points.json"


@lru_cache(maxsize=1)
def _all_groups() -> dict[str, dict[str, str]]:
    """Both entry-point groups as {group: {name: value}}, from a small index file while the
    installed packages are unchanged (scanning every package's metadata costs more than the rest of
    ``--help``)."""
    fp = _fingerprint()
    path = index_file()
    known: list = []
    with contextlib.suppress(OSError, ValueError, TypeError, AttributeError):
        known = [e for e in json.loads(path.read_text()) if isinstance(e, dict)]
        for e in known:  # one per sys.path seen (the console script's differs from `python -m`'s)
            if e.get("fingerprint") == fp and isinstance(e.get("groups"), dict):
                return e["groups"]
    from importlib.metadata import entry_points

    groups = {
        g: {ep.name: ep.value for ep in entry_points(group=g)} for g in (GROUP, COMMANDS_GROUP)
    }
    with contextlib.suppress(OSError):  # a read-only home: the index is only a fast path
        write_whole(path, json.dumps([{"fingerprint": fp, "groups": groups}] + known[:7]).encode())
    return groups


def entry_points() -> dict[str, EntryPoint]:
    """The installed node types' entry points, by name (nothing imported)."""
    return {n: EntryPoint(n, v) for n, v in _all_groups().get(GROUP, {}).items()}


def names() -> list[str]:
    """All known node type names, sorted."""
    # (no node can be registered before it is imported)
    api = sys.modules.get("stereograph.core.api")
    return sorted(set(entry_points()) | set(api.REGISTRY if api else ()))


def get(name: str, where: Where | None = None, node: str | None = None) -> NodeSpec:
    """The spec of node type ``name``, importing its module on first use.

    Raises
    ------
    ConfigError
        Unknown name (with the closest known names), or a module that fails to import.
    """
    from stereograph.core.api import REGISTRY, NodeSpec

    if name in REGISTRY:
        return REGISTRY[name]
    ep = entry_points().get(name)
    if ep is None:
        close = difflib.get_close_matches(name, names(), n=3, cutoff=0.5)
        hint = (
            f"did you mean {' or '.join(repr(c) for c in close)}?"
            if close
            else "run `stereograph nodes` to list the node types"
        )
        raise ConfigError(f"unknown node type '{name}'", where, node, hint)
    try:
        fn = ep.load()
    except KeyboardInterrupt:
        raise
    # a broken node module must not read as "unknown type", nor end the command
    except BaseException as e:
        raise ConfigError(
            f"node type '{name}' is registered as {ep.value} but failed to import: "
            f"{type(e).__name__}: {e}",
            where,
            node,
            hint="fix that module, or reinstall with `pip install -e .`",
        ) from None
    spec = getattr(fn, "spec", None)
    if not isinstance(spec, NodeSpec):
        raise ConfigError(f"entry point {ep.value} is not a @node-decorated function", where, node)
    if spec.name != name:
        raise ConfigError(
            f"entry point '{name}' points at a node declared as '{spec.name}'",
            where,
            node,
            hint="make the entry-point name and the @node name agree in pyproject.toml",
        )
    return spec


# Whether a pipeline's ``plugins:`` may be imported. Importing a plugin runs its code, so a
# pipeline file from someone else could run anything just by being validated. The command line
# sets this from ``--allow-plugins`` (off by default); a Python program that loads pipelines is
# trusted to have chosen its files and keeps the default (on). See docs/security.md.
PLUGIN_PATHS: set[str] = set()  # folders put on sys.path for plugins (not installed packages)
# a plugin file's stamp (path, size, times, inode) -> its module, imported from the file as it is
_IMPORTED_FILES: dict[tuple | None, str] = {}
PLUGINS_ALLOWED = True


@contextlib.contextmanager
def plugins_allowed(allowed: bool) -> Iterator[None]:
    """Set :data:`PLUGINS_ALLOWED` for the duration of a block (the CLI wraps each command)."""
    global PLUGINS_ALLOWED
    before, PLUGINS_ALLOWED = PLUGINS_ALLOWED, allowed
    try:
        yield
    finally:
        PLUGINS_ALLOWED = before


def import_plugins(plugins: list[str], base_dir: Path, where: Where | None = None) -> None:
    """Import plugin modules (dotted names, or ``.py`` paths relative to ``base_dir``).

    Raises
    ------
    ConfigError
        Plugins are not allowed (see :data:`PLUGINS_ALLOWED`), or one fails to import, whatever
        it raises on import (``sys.exit()`` included).
    """
    if plugins and not PLUGINS_ALLOWED:
        raise ConfigError(
            f"this pipeline imports Python code (plugins: {', '.join(plugins)}), and importing "
            "runs that code; stereograph does not do that for a pipeline file unless told to",
            where,
            hint="if you trust this file and its plugins, add --allow-plugins (or set "
            "STEREOGRAPH_ALLOW_PLUGINS=1); otherwise remove 'plugins:'",
        )
    from stereograph.core.api import REGISTRY

    for plugin in plugins:
        before = dict(REGISTRY)
        try:
            if plugin.endswith(".py") or "/" in plugin:
                _import_file(base_dir / plugin)
            else:
                _import_module(plugin, base_dir)
        except (ConfigError, KeyboardInterrupt):
            raise
        except BaseException as e:  # SystemExit too: a plugin must not end or hijack the command
            what = (
                f"called sys.exit({e.code!r})"
                if isinstance(e, SystemExit)
                else f"{type(e).__name__}: {e}"
            )
            raise ConfigError(
                f"plugin '{plugin}' failed to import: {what}",
                where,
                hint="plugins are module names or .py paths relative to the pipeline file (a .py "
                "plugin may import modules beside it)",
            ) from None
        _keep_installed(plugin, before, where)


def _import_file(path: Path) -> None:
    """Import a ``.py`` plugin as a module of its own (two plugins named nodes.py in two folders are
    two modules); a file changed since this process imported it is imported again -- the cache key
    follows the file, so the code run must too."""
    try:  # (every task of a run asks again: a stat, not a read, while the file is unchanged)
        st = os.stat(path)
        stamp: tuple | None = (str(path), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
    except OSError:
        stamp = None
    if _IMPORTED_FILES.get(stamp, "") in sys.modules:
        return
    path = path.resolve()
    mod_name = f"stereograph_plugin_{path.stem}_{digest(str(path).encode())[:8]}"
    if not path.is_file():
        raise FileNotFoundError(f"no such file {path}")
    loaded, now = sys.modules.get(mod_name), file_digest(path)
    if loaded is None or getattr(loaded, "__stereograph_digest__", None) != now:
        _exec_plugin(path, mod_name, now, loaded)
    # an edit within the file system's timestamp tick keeps the stamp: only older files are trusted
    if stamp is not None and time.time_ns() - stamp[2] > RACY_NS:
        _IMPORTED_FILES[stamp] = mod_name


def _exec_plugin(path: Path, mod_name: str, now: str, loaded: Any) -> None:
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path} is not a Python module")
    mod = importlib.util.module_from_spec(spec)
    mod.__stereograph_digest__ = now
    sys.modules[mod_name] = mod
    if str(path.parent) not in sys.path:  # its helper modules beside it
        sys.path.append(str(path.parent))
        PLUGIN_PATHS.add(str(path.parent))
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        if loaded is not None:
            sys.modules[mod_name] = loaded
        else:
            sys.modules.pop(mod_name, None)  # a half-imported plugin must not count as loaded
        raise


def _import_module(plugin: str, base_dir: Path) -> None:
    """Import a plugin module by name (from the pipeline's folder first); again if its file
    changed."""
    if str(base_dir) not in sys.path:
        sys.path.insert(0, str(base_dir))
        PLUGIN_PATHS.add(str(base_dir))
    mod = sys.modules.get(plugin)
    file = getattr(mod, "__file__", None)
    if (
        mod is not None
        and file
        and getattr(mod, "__stereograph_digest__", None) not in (None, file_digest(Path(file)))
    ):
        mod = importlib.reload(mod)
    else:
        mod = importlib.import_module(plugin)
    if getattr(mod, "__file__", None):
        mod.__stereograph_digest__ = file_digest(Path(mod.__file__))


def _keep_installed(plugin: str, before: dict, where: Where | None) -> None:
    """An installed node type (an entry point: the built-ins, a package's) is never replaced by a
    plugin; two plugins may still define one name (the last imported is used)."""
    from stereograph.core.api import REGISTRY

    changed = [(name, spec) for name, spec in REGISTRY.items() if spec is not before.get(name)]
    installed = entry_points() if changed else {}  # (a plugin imported already changes nothing)
    for name, spec in changed:
        old = before.get(name)
        if (
            name in installed
            and installed[name].value.partition(":")[0].strip() != spec.fn.__module__
        ):
            if old is not None:
                REGISTRY[name] = old
            else:
                del REGISTRY[name]
            raise ConfigError(
                f"plugin '{plugin}' defines a node type '{name}', the name of an installed node "
                "type: a plugin does not replace one",
                where,
                hint=f"give your node its own name (e.g. '{name}_mine') and use that as the type",
            )


def commands() -> dict[str, EntryPoint]:
    """Extra CLI sub-commands contributed by node packages."""
    return {n: EntryPoint(n, v) for n, v in _all_groups().get(COMMANDS_GROUP, {}).items()}
