"""stereograph: stereo localisation and robot-arm picking as a config-driven processing graph.

The engine is a handful of modules, read in this order:

- :mod:`stereograph.api`      the node API (``@node``, ``Params``, ``In``, ``Out``, ``NodeError``)
- :mod:`stereograph.registry` node types from the ``stereograph.nodes`` entry-point group
- :mod:`stereograph.config`   pipeline YAML -> validated :class:`~stereograph.config.Pipeline`
- :mod:`stereograph.graph`    the DAG (networkx) and its checks
- :mod:`stereograph.cache`    content-addressed artifact store
- :mod:`stereograph.runner`   the scheduler
- :mod:`stereograph.cli`      the ``stereograph`` command
- :mod:`stereograph.pyapi`    the Python API: :func:`run`, :func:`check`, :func:`compare` (docs/python.md)
"""

from typing import Any

__all__ = ["REGISTRY", "Field", "In", "NodeError", "NodeSpec", "Out", "Params", "RunContext", "node",
           "run", "check", "compare", "Result"]
__version__ = "0.1.0"

_PYAPI = {"run", "check", "compare", "Result", "NodeFailed"}


def __getattr__(name: str) -> Any:
    # imported on first use: `import stereograph` (and `stereograph --help`) stays light
    if name == "compare":  # the module, callable as the API's compare (see stereograph/compare.py)
        import importlib

        return importlib.import_module("stereograph.compare")
    if name in _PYAPI:
        from stereograph import pyapi

        return getattr(pyapi, name)
    if name in __all__:  # the node API (pydantic)
        from stereograph import api

        return getattr(api, name)
    raise AttributeError(f"module 'stereograph' has no attribute {name!r}")
