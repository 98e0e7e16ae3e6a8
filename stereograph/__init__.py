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

from stereograph.api import REGISTRY, Field, In, NodeError, NodeSpec, Out, Params, RunContext, node

__all__ = ["REGISTRY", "Field", "In", "NodeError", "NodeSpec", "Out", "Params", "RunContext", "node"]
__version__ = "0.1.0"
