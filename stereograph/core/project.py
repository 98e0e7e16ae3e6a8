"""Where a pipeline's cache and run folders live: one of each per project.

The project root is the nearest folder up with a ``pyproject.toml`` or ``.git``; its
``.stereograph/cache`` and ``runs/`` serve every pipeline in it. Overrides and the cache's size
budget: docs/engine.md. This module imports nothing heavy (the CLI asks it first).
"""

from __future__ import annotations

import os
import tomllib
import uuid
from datetime import datetime
from functools import lru_cache
from pathlib import Path
from typing import Any

from stereograph.core.errors import ConfigError

DEFAULT_BUDGET_GB = 4.0  # a few GB: every everyday pipeline's artifacts fit many times over
MARKERS = ("pyproject.toml", ".git")


def project_root(start: str | Path) -> Path:
    """The nearest folder at or above ``start`` (a file's folder, or a folder) with a project
    marker; ``start`` (its folder) itself when there is none."""
    here = Path(start).resolve()
    if not here.is_dir():
        here = here.parent
    for d in (here, *here.parents):
        if any((d / m).exists() for m in MARKERS):
            return d
    return here


@lru_cache(maxsize=32)
def _tool_config(root: Path) -> dict[str, Any]:
    """``[tool.stereograph]`` of ``root/pyproject.toml`` ({} when absent or unreadable)."""
    path = root / "pyproject.toml"
    if not path.is_file():
        return {}
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    conf = data.get("tool", {}).get("stereograph", {})
    return conf if isinstance(conf, dict) else {}


def cache_dir(pipeline_dir: str | Path) -> Path:
    """The default artifact cache for a pipeline in ``pipeline_dir`` (see the module docstring)."""
    env = os.environ.get("STEREOGRAPH_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    root = project_root(pipeline_dir)
    conf = _tool_config(root).get("cache_dir")
    if isinstance(conf, str) and conf:
        path = (root / Path(conf).expanduser()).resolve()
        if path != root and root not in path.parents:
            # a project's files come with the project (a repository cloned, a folder handed over):
            # they must not point the cache -- written to by every run, emptied by `cache clear` --
            # at your files

            raise ConfigError(
                f"{root / 'pyproject.toml'}: [tool.stereograph] cache_dir = {conf!r} is "
                "outside the "
                f"project ({root})",
                hint="give a folder inside the project; for a cache elsewhere, choose it yourself "
                "with --cache-dir or STEREOGRAPH_CACHE_DIR",
            )
        return path
    return root / ".stereograph" / "cache"


def runs_dir(pipeline_dir: str | Path) -> Path:
    """The folder that holds run folders (``<root>/runs``) for a pipeline in ``pipeline_dir``."""
    return project_root(pipeline_dir) / "runs"


def budget_bytes(pipeline_dir: str | Path | None = None) -> int:
    """The cache's size budget in bytes (0: unlimited).

    Raises
    ------
    ConfigError
        ``STEREOGRAPH_CACHE_BUDGET_GB`` or the project setting is not a non-negative number.
    """
    env = os.environ.get("STEREOGRAPH_CACHE_BUDGET_GB")
    if env is not None and env.strip():
        value, source = env, "STEREOGRAPH_CACHE_BUDGET_GB"
    else:
        conf = _tool_config(project_root(pipeline_dir)) if pipeline_dir is not None else {}
        value, source = (
            conf.get("cache_budget_gb", DEFAULT_BUDGET_GB),
            "[tool.stereograph] cache_budget_gb",
        )
    try:
        gb = float(value)
    except (TypeError, ValueError):
        raise _bad_budget(source, value, "is not a number of GB") from None
    if not gb >= 0:
        raise _bad_budget(source, value, "must be 0 (no limit) or more")
    return int(gb * 1e9)


def _bad_budget(source: str, value: Any, why: str) -> ConfigError:
    return ConfigError(
        f"cache budget: {source} = {value!r} {why}",
        hint="set it in GB, for example STEREOGRAPH_CACHE_BUDGET_GB=4 (0: no limit)",
    )


def new_run_id() -> str:
    """A run folder's name: when it started, and 4 hex digits apart from another one that second."""
    return datetime.now().strftime("%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:4]
