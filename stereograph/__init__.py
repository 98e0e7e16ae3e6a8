"""stereograph: stereo localisation and robot-arm picking as a config-driven processing graph.

The engine is a handful of modules, read in this order:

- :mod:`stereograph.api`      the node API (``@node``, ``Params``, ``In``, ``Out``, ``NodeError``)
- :mod:`stereograph.registry` node types from the ``stereograph.nodes`` entry-point group
- :mod:`stereograph.config`   pipeline YAML -> validated :class:`~stereograph.config.Pipeline`
- :mod:`stereograph.graph`    the DAG (networkx) and its checks
- :mod:`stereograph.cache`    content-addressed artifact store
- :mod:`stereograph.runner`   the scheduler
- :mod:`stereograph.cli`      the ``stereograph`` command
"""

from typing import Any

__all__ = ["REGISTRY", "Field", "In", "NodeError", "NodeSpec", "Out", "Params", "RunContext", "node"]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    # the node API (pydantic) is imported when first used, not by `stereograph --help`
    if name in __all__:
        from stereograph import api

        return getattr(api, name)
    raise AttributeError(f"module 'stereograph' has no attribute {name!r}")
