"""The Python API: run, check and compare pipelines from a program or a notebook.

``stereograph.run(path, set={...})`` returns a :class:`Result` (``ok``, ``status``, ``res[node]``,
``outputs(node, output)``); ``stereograph.check`` returns the problems; ``stereograph.compare``
tabulates variants. They are what the command does, without its printing: a bad pipeline raises
:class:`~stereograph.core.errors.ConfigError`, a failed node shows in ``res.ok`` / ``res.errors``
(:meth:`Result.raise_for_errors`). docs/python.md has examples.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from stereograph.core.errors import ConfigError, sentence

__all__ = ["NodeFailed", "Result", "check", "compare", "run"]


def _set_texts(set_: Mapping[str, Any] | Iterable[str] | None, name: str = "set") -> list[str]:
    """``{"rig.n_scenes": 20}`` (or ``["rig.n_scenes=20"]``) -> ``--set`` texts."""
    if set_ is None:
        return []
    if isinstance(set_, str):
        return [set_]
    example = (
        '{"rig.n_scenes": 20}'
        if name == "set"
        else '{"segment.type": ["segmenter.color", "segmenter.otsu"]}'
    )
    if isinstance(set_, Mapping):
        texts = []
        for key, value in set_.items():
            try:  # JSON is YAML: the value reads back as the same number, text, list or mapping
                text = json.dumps(_plain(value), allow_nan=False)
            except (TypeError, ValueError) as e:
                raise ConfigError(
                    f"{name}= value of {key!r} is not a plain value ({type(value).__name__}: {e})",
                    hint="give numbers, text, lists or mappings of them, as in the pipeline YAML",
                ) from None
            texts.append(f"{key}={text}")
        return texts
    if not isinstance(set_, Iterable) or isinstance(set_, bytes):
        raise ConfigError(
            f"{name}= must be a mapping or a list of 'NODE.PARAM=VALUE' texts, not "
            f"{type(set_).__name__} ({set_!r})",
            hint=f"for example {name}={example}",
        )
    return [str(s) for s in set_]


def _workers(workers: Any) -> int | None:
    """``workers=`` as ``--workers`` takes it: None or a whole number >= 1."""
    if workers is None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(
            f"workers= must be a whole number of processes, 1 or more (got {workers!r})",
            hint="workers=2 runs per-item nodes in two processes; None or 1 runs them here",
        )
    return workers


def _plain(value: Any) -> Any:
    """NumPy scalars and arrays, tuples and paths as plain JSON values."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, Path):
        return str(value)
    return value


def _progress(progress: Any) -> Any:
    if progress is True:  # plain lines on stderr: readable in a notebook, a log or a terminal
        from stereograph.app.progress import PlainProgress

        return PlainProgress(sys.stderr)
    return progress or None


class NodeFailed(Exception):
    """One or more nodes of a run failed (raised by :meth:`Result.raise_for_errors`)."""


class Result:
    """What :func:`run` gives: each node's status and the outputs of the nodes it kept.

    Attributes
    ----------
    run_id : str
        The run's id (also the name of its output folder by default).
    out_dir : Path
        The run folder: ``run.json``, saved outputs (``<node>/<output>.png|json``).
    status : dict
        Node -> ``ran | cached | failed | partial | skipped | not selected``.
    ran : set
        Nodes that computed anything in this run (the rest came from the cache).
    reports : dict
        Node -> :class:`stereograph.core.run_result.NodeReport` (seconds, items, messages, error,
        hint).
    seconds : float
        Wall time of the run.
    """

    def __init__(self, run_result: Any):
        self._r = run_result
        self.run_id: str = run_result.run_id
        self.out_dir: Path = run_result.out_dir
        self.reports = run_result.reports
        self.seconds: float = run_result.seconds

    @property
    def ok(self) -> bool:
        """No node failed (a node with some failed items counts as failed)."""
        return self._r.ok

    @property
    def status(self) -> dict[str, str]:
        return self._r.status

    @property
    def ran(self) -> set[str]:
        return self._r.ran

    @property
    def nodes(self) -> list[str]:
        """The nodes whose outputs can be read (those that ran or came from the cache)."""
        return [n for n, rep in self.reports.items() if rep.status in ("ran", "cached", "partial")]

    @property
    def errors(self) -> dict[str, str]:
        """Failed node -> its error, with the fix (``"... Fix: ..."``)."""
        out = {}
        for name, rep in self.reports.items():
            if rep.status in ("failed", "partial") and rep.error:
                out[name] = sentence(rep.error) + (
                    " Fix: " + sentence(rep.hint) if rep.hint else ""
                )
        return out

    def outputs(self, node: str, output: str) -> Any:
        """One output of a node: its value, or ``{item: value}`` for a per-item output.

        Terminal and saved outputs are in memory; any other is loaded from the artifact cache
        when asked for (a run with ``use_cache=False`` holds only what ``keep=`` named).

        Raises
        ------
        KeyError
            No such node or output, or the node failed, was skipped or not selected.
        """
        r = self._r
        self._check(node, output)
        if r.holds(node, output):
            return r.outputs(node, output)
        run = r.state
        if run is None or run.store is None:
            raise KeyError(
                f"the result does not hold {node}.{output} (a run without the cache keeps only the "
                f"terminal, saved and keep= outputs): pass keep=['{node}'] to stereograph.run"
            )
        if run.g.is_collection(node, output):
            return {i: run.get((node, output, i)) for i in run.items_of(node, output)}
        return run.get((node, output, None))

    def __getitem__(self, node: str) -> dict[str, Any]:
        """Every output of a node: ``{output name: value or {item: value}}``."""
        self._check(node, None)
        return {o: self.outputs(node, o) for o in self._spec_outputs(node)}

    def _spec_outputs(self, node: str) -> list[str]:
        run = self._r.state
        if run is not None:
            return list(run.g.nodes[node].spec.outputs)
        return sorted(
            {o for (n, o, _) in self._r.values if n == node}
            | {o for (n, o) in self._r.item_ids if n == node}
        )

    def _check(self, node: str, output: str | None) -> None:
        if node not in self.reports:
            raise KeyError(f"no node '{node}' in this pipeline (nodes: {sorted(self.reports)})")
        rep = self.reports[node]
        if rep.status in ("failed", "skipped", "not selected", "pending"):
            what = {"not selected": "was not selected (only=)", "pending": "did not run"}.get(
                rep.status, rep.status
            )
            raise KeyError(
                f"node '{node}' has no outputs: it {what}"
                + (f" ({rep.error})" if rep.error else "")
            )
        if output is not None and output not in self._spec_outputs(node):
            raise KeyError(
                f"node '{node}' has no output '{output}' (its outputs: {self._spec_outputs(node)})"
            )

    def raise_for_errors(self) -> Result:
        """Raise :class:`NodeFailed` naming every failed node and its fix; else return self."""
        if not self.ok:
            raise NodeFailed(" ".join(f"node '{n}': {e}" for n, e in self.errors.items()))
        return self

    def __repr__(self) -> str:
        state = "ok" if self.ok else f"FAILED ({', '.join(self.errors)})"
        counts: dict[str, int] = {}
        for s in self.status.values():
            counts[s] = counts.get(s, 0) + 1
        return (
            f"<stereograph.Result {self.run_id}: {state}; "
            + ", ".join(f"{n} {s}" for s, n in counts.items())
            + f"; {self.seconds:.1f} s; {self.out_dir}>"
        )


def run(
    path: str | Path,
    set: Mapping[str, Any] | Iterable[str] | None = None,  # noqa: A002 - the CLI's --set, by name
    *,
    keep: str | Iterable[str] | None = None,
    out_dir: str | Path | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
    only: str | None = None,
    from_node: str | None = None,
    workers: int | None = None,
    progress: Any = True,
) -> Result:
    """Validate and run a pipeline file, as ``stereograph run`` does.

    Parameters
    ----------
    path : str or Path
        The pipeline YAML.
    set : mapping or list of str, optional
        Overrides, ``{"rig.n_scenes": 20, "segment.type": "segmenter.color"}`` or the command
        line's ``["rig.n_scenes=20"]``.
    keep : "all" or list of str, optional
        Also hold these nodes' outputs in the result (default: the terminal nodes' and every
        saved output). ``"all"`` keeps every node's; memory grows with the images kept.
    out_dir, cache_dir, use_cache, only, from_node :
        As ``--out``, ``--cache-dir``, ``--no-cache`` (False), ``--only``, ``--from``.
    workers : int, optional
        Processes for per-item nodes (``--workers``).
    progress : bool or object
        True: a plain progress line per running node every few seconds on stderr; False: none;
        or an object with the methods of :class:`stereograph.app.progress.PlainProgress`.

    Returns
    -------
    Result

    Raises
    ------
    ConfigError
        The pipeline cannot run as written; a :class:`~stereograph.core.errors.ConfigErrors` when it
        has several problems (``.errors`` lists them).
    """
    from stereograph.core.config import load_pipeline
    from stereograph.core.executors import workers_executor
    from stereograph.core.graph import build_graph
    from stereograph.core.runner import run_graph

    graph = build_graph(load_pipeline(path, _set_texts(set)))
    if keep == "all":
        kept = set_of(graph.nodes)
    elif isinstance(keep, str):
        kept = {keep}
    else:
        kept = set_of(keep or ())
    unknown = sorted(kept - set_of(graph.nodes))
    if unknown:
        raise ConfigError(
            f"keep= names nodes that are not in {graph.doc.path.name}: {unknown}",
            hint=f"nodes are {sorted(graph.nodes)}",
        )
    executor = workers_executor(_workers(workers))
    prog = _progress(progress)
    kw = dict(
        cache_dir=cache_dir,
        out_dir=out_dir,
        use_cache=use_cache,
        only=only,
        from_node=from_node,
        executor=executor,
        progress=prog,
        keep=kept,
    )
    try:
        if hasattr(prog, "__enter__"):  # (the heartbeat thread of the plain lines)
            with prog:
                result = run_graph(graph, **kw)
        else:
            result = run_graph(graph, **kw)
    except BaseException:  # (an interrupted notebook cell: the workers are ended, not waited for)
        executor.close(now=True)
        raise
    executor.close()
    return Result(result)


def set_of(items: Iterable[str]) -> set[str]:
    return {str(i) for i in items}


def check(
    path: str | Path, set: Mapping[str, Any] | Iterable[str] | None = None
) -> list[ConfigError]:  # noqa: A002
    """Every problem of a pipeline file at once (``stereograph validate``); ``[]`` when it is valid.

    Each problem's ``str()`` is one paragraph: ``file:line: node 'x': what. Fix: how.``; its
    ``where``, ``node``, ``message`` and ``hint`` are there separately.
    """
    from stereograph.core.graph import check_pipeline

    return check_pipeline(path, _set_texts(set))[1]


def compare(
    path: str | Path,
    vary: Mapping[str, Iterable[Any]] | Iterable[str] | None = None,
    *,
    set: Mapping[str, Any] | Iterable[str] | None = None,  # noqa: A002
    out_dir: str | Path | None = None,
    cache_dir: str | Path | None = None,
    split: str | None = None,
    skip_invalid: bool = False,
    plots: bool = True,
    progress: Any = True,
) -> Any:
    """Run every combination of some settings on one shared cache (``stereograph compare``).

    Parameters
    ----------
    path : str or Path
        The pipeline YAML (its ``variants:`` block applies; ``vary`` adds to it).
    vary : mapping or list of str, optional
        ``{"segment.type": ["segmenter.color", "segmenter.otsu"]}`` or
        ``["segment.type=color,otsu"]``.
    set : mapping or list of str, optional
        Overrides applied to every variant, as for :func:`run`.
    out_dir, cache_dir, split, skip_invalid, plots :
        As for :func:`stereograph.app.compare.compare`.
    progress : bool or object
        True: a line per variant and per running node on stderr.

    Returns
    -------
    stereograph.app.compare_result.CompareResult
        ``.rows`` (one dict per variant: its settings and the metrics its nodes declare,
        times), ``.row(**settings)``, ``.variants`` (each with ``.status``, ``.ran``, ``.out_dir``),
        ``.files`` (``compare.csv``, ``compare.json``, plots).
    """
    from stereograph.app import compare as compare_mod
    from stereograph.app.compare_progress import CompareLines

    if isinstance(vary, Mapping):
        vary_texts = []
        for key, values in vary.items():
            if isinstance(values, (str, bytes)) or not isinstance(values, Iterable):
                raise ConfigError(
                    f"vary= values of {key!r} must be a list of the values to try (got {values!r})",
                    hint=f'for example vary={{"{key}": [1, 2]}}',
                )
            vary_texts.append(
                f"{key}="
                + ", ".join(_set_texts({key: v}, "vary")[0].split("=", 1)[1] for v in values)
            )
    else:
        vary_texts = _set_texts(vary, "vary")
    # True: a line per variant, and the per-node lines of run(), on stderr
    prog = CompareLines(sys.stderr) if progress is True else (progress or None)
    kw = dict(
        overrides=_set_texts(set),
        cache_dir=cache_dir,
        split=split,
        skip_invalid=skip_invalid,
        plots=plots,
    )
    if hasattr(prog, "__enter__"):  # compare does not enter it: start (and stop) the heartbeat here
        with prog:
            return compare_mod.compare(path, vary_texts, out_dir, progress=prog, **kw)
    return compare_mod.compare(path, vary_texts, out_dir, progress=prog, **kw)
