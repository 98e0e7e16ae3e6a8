"""The node API for node libraries and plugins: ``from stereograph.api import node, Params, In,
Out``.

The public name of :mod:`stereograph.core.api`, kept stable whatever the engine's layout; node
code imports this module and ``nodes.contracts`` only (``tests/test_node_contracts.py``).
"""

from stereograph.core.api import *  # noqa: F403  (the public node API is the core's)
from stereograph.core.api import __all__  # noqa: F401
