"""Built-in node library: one subpackage per kind. Each node is one file registered in
pyproject.toml."""

# The records' shape checks register with the engine whenever any built-in node is imported (in
# every process: a pool's or a Dask cluster's worker too), not only when a node happens to import a
# contract.
from nodes import contracts as _contracts  # noqa: F401, E402
