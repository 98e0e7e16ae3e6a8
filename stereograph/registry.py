"""Node types: the ``stereograph.nodes`` entry-point group, plus plugins a pipeline imports.

Entry points are read without importing anything, so listing names and "did you mean" are
cheap; a node's module is imported the first time the node is used.
"""

from __future__ import annotations

import contextlib
import difflib
import importlib
import importlib.util
import sys
from collections.abc import Iterator
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path

from stereograph.api import REGISTRY, NodeSpec
from stereograph.errors import ConfigError, Where

GROUP = "stereograph.nodes"
COMMANDS_GROUP = "stereograph.commands"


@lru_cache(maxsize=1)
def _entry_points() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def names() -> list[str]:
    """All known node type names, sorted."""
    return sorted(set(_entry_points()) | set(REGISTRY))


def get(name: str, where: Where | None = None, node: str | None = None) -> NodeSpec:
    """The spec of node type ``name``, importing its module on first use.

    Raises
    ------
    ConfigError
        Unknown name (with the closest known names), or a module that fails to import.
    """
    if name in REGISTRY:
        return REGISTRY[name]
    ep = _entry_points().get(name)
    if ep is None:
        close = difflib.get_close_matches(name, names(), n=3, cutoff=0.5)
        hint = f"did you mean {' or '.join(repr(c) for c in close)}?" if close else \
            "run `stereograph nodes` to list the node types"
        raise ConfigError(f"unknown node type '{name}'", where, node, hint)
    try:
        fn = ep.load()
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # a broken node module must not read as "unknown type", nor end the command
        raise ConfigError(f"node type '{name}' is registered as {ep.value} but failed to import: "
                          f"{type(e).__name__}: {e}", where, node,
                          hint="fix that module, or reinstall with `pip install -e .`") from None
    spec = getattr(fn, "spec", None)
    if not isinstance(spec, NodeSpec):
        raise ConfigError(f"entry point {ep.value} is not a @node-decorated function", where, node)
    if spec.name != name:
        raise ConfigError(f"entry point '{name}' points at a node declared as '{spec.name}'", where, node,
                          hint="make the entry-point name and the @node name agree in pyproject.toml")
    return spec


# Whether a pipeline's ``plugins:`` may be imported. Importing a plugin runs its code, so a
# pipeline file from someone else could run anything just by being validated. The command line
# sets this from ``--allow-plugins`` (off by default); a Python program that loads pipelines is
# trusted to have chosen its files and keeps the default (on). See docs/security.md.
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
        raise ConfigError(f"this pipeline imports Python code (plugins: {', '.join(plugins)}), and importing "
                          "runs that code; stereograph does not do that for a pipeline file unless told to", where,
                          hint="if you trust this file and its plugins, add --allow-plugins (or set "
                               "STEREOGRAPH_ALLOW_PLUGINS=1); otherwise remove 'plugins:'")
    for plugin in plugins:
        try:
            if plugin.endswith(".py") or "/" in plugin:
                path = (base_dir / plugin).resolve()
                mod_name = "stereograph_plugin_" + path.stem
                if mod_name in sys.modules:
                    continue
                if not path.is_file():
                    raise FileNotFoundError(f"no such file {path}")
                spec = importlib.util.spec_from_file_location(mod_name, path)
                if spec is None or spec.loader is None:
                    raise ImportError(f"{path} is not a Python module")
                mod = importlib.util.module_from_spec(spec)
                sys.modules[mod_name] = mod
                try:
                    spec.loader.exec_module(mod)
                except BaseException:
                    sys.modules.pop(mod_name, None)  # a half-imported plugin must not count as loaded
                    raise
            else:
                if str(base_dir) not in sys.path:
                    sys.path.insert(0, str(base_dir))
                importlib.import_module(plugin)
        except ConfigError:
            raise
        except KeyboardInterrupt:
            raise
        except BaseException as e:  # SystemExit too: a plugin must not end or hijack the command
            what = f"called sys.exit({e.code!r})" if isinstance(e, SystemExit) else f"{type(e).__name__}: {e}"
            raise ConfigError(f"plugin '{plugin}' failed to import: {what}", where,
                              hint="plugins are module names or .py paths relative to the pipeline file") from None


@lru_cache(maxsize=1)  # reading every installed package's metadata takes tens of ms
def commands() -> dict[str, EntryPoint]:
    """Extra CLI sub-commands contributed by node packages."""
    return {ep.name: ep for ep in entry_points(group=COMMANDS_GROUP)}
