"""stereograph: stereo localisation and robot-arm picking as a config-driven processing graph.

Two layers; ``core`` never imports ``app`` (``tests/test_engine_layers.py``). Read the core in
this order (each module's docstring says its invariants and public names):

- :mod:`stereograph.core.errors`    user-facing errors: file, line, node and the fix
- :mod:`stereograph.core.checks`    shape checks of artifact types, registered by node libraries
- :mod:`stereograph.core.api`       the node API (``@node``, ``Params``, ``In``, ``Out``,
  ``NodeError``)
- :mod:`stereograph.core.registry`  node types from the ``stereograph.nodes`` entry-point group
- :mod:`stereograph.core.yaml_lines` YAML within bounds, with the line of every key
- :mod:`stereograph.core.config`    a pipeline file, its includes and ``--set`` -> ``PipelineDoc``
- :mod:`stereograph.core.graph`     the DAG (networkx) and its checks
- :mod:`stereograph.core.project`   where a project's cache and run folders live
- :mod:`stereograph.core.digests`   content digests of bytes, files and values
- :mod:`stereograph.core.codecs`    values to files and back: plain data, arrays, PNG, JPEG
- :mod:`stereograph.core.code_keys` a node's code for its keys: its module and local imports
- :mod:`stereograph.core.outputs`   values into files, in open formats
- :mod:`stereograph.core.run_folder` a run's folder: made ready, its results and ``run.json``
- :mod:`stereograph.core.file_index` file digests reused while a file is unchanged
- :mod:`stereograph.core.cache`     the content-addressed artifact store
- :mod:`stereograph.core.calls`     one call of a node function: ``Task`` in, ``TaskResult`` out
- :mod:`stereograph.core.threads`   one library thread per worker process
- :mod:`stereograph.core.executors` where tasks run: here, a process pool, Dask
- :mod:`stereograph.core.run_result` what a run gives back: ``NodeReport``, ``RunResult``
- :mod:`stereograph.core.run_state` one run's state (``RunState``) and its operations
- :mod:`stereograph.core.node_run`  (``RunState``'s base) running one node: entries, look-up, status
- :mod:`stereograph.core.part_run`  (``RunState``'s base) a streamed chunk as a part of the run
- :mod:`stereograph.core.streaming` the per-item part of a graph, a chunk of items at a time
- :mod:`stereograph.core.ahead`     a region's items made by the pool while the head runs
- :mod:`stereograph.core.runner`    the scheduler: ``run_graph``, ``run_pipeline``
- :mod:`stereograph.core.hooks`     what the core announces (a run written, a cache pruned)

On top, :mod:`stereograph.app`: the ``stereograph`` command (``cli``; ``run_command``,
``run_summary``, ``info_commands``, ``node_index``, ``cache_command``, ``stop_signals``),
``compare`` (``variants``, ``compare_result``, ``compare_table``, ``compare_files``,
``compare_progress``), ``explain``, ``loop`` (``--repeat``), ``rerun`` (replayed unchanged runs),
the pages (``report``, ``report_cycles``, ``compare_report``, ``graph_picture``), ``progress``,
``plaintext`` and the Python facade (``pyapi``: :func:`run`, :func:`check`, :func:`compare`;
docs/python.md).
"""

from typing import Any

__all__ = [
    "REGISTRY",
    "Field",
    "In",
    "NodeError",
    "NodeSpec",
    "Out",
    "Params",
    "RunContext",
    "node",
    "run",
    "check",
    "compare",
    "Result",
]
__version__ = "0.1.0"

_PYAPI = {"run", "check", "compare", "Result", "NodeFailed"}


def __getattr__(name: str) -> Any:
    # imported on first use: `import stereograph` (and `stereograph --help`) stays light
    if name in _PYAPI:
        from stereograph.app import pyapi

        return getattr(pyapi, name)
    if name in __all__:  # the node API (pydantic)
        from stereograph.core import api

        return getattr(api, name)
    raise AttributeError(f"module 'stereograph' has no attribute {name!r}")
