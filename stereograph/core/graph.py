"""The pipeline as a validated DAG.

:func:`build_graph` turns a :class:`~stereograph.core.config.PipelineDoc` into a :class:`Graph`:
every node's spec resolved, params validated by the node's pydantic model, inputs wired and
type-checked, cycles refused, and for each node whether it runs once or once per item.
All problems are :class:`~stereograph.core.errors.ConfigError` naming file:line and node.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx
import pydantic

from stereograph.core import registry
from stereograph.core.api import NodeError, NodeSpec, Params, type_name
from stereograph.core.config import (
    PipelineDoc,
    apply_override,
    load_pipeline,
    merge_params,
    types_first,
)
from stereograph.core.errors import (
    ConfigError,
    ConfigErrors,
    did_you_mean,
    in_file_order,
    raise_all,
)


@dataclass
class NodeInstance:
    """One node of a pipeline, resolved."""

    name: str
    spec: NodeSpec
    params: Params
    inputs: dict[str, tuple[str, str]]  # input port -> (upstream node, output port)
    mapped: bool = False  # runs once per collection item

    @property
    def type(self) -> str:
        return self.spec.name


@dataclass
class Graph:
    """A validated pipeline."""

    doc: PipelineDoc
    nodes: dict[str, NodeInstance]
    dag: nx.DiGraph
    order: list[str]
    warnings: list[str] = field(default_factory=list)

    def upstream(self, name: str) -> set[str]:
        return nx.ancestors(self.dag, name)

    def downstream(self, name: str) -> set[str]:
        return nx.descendants(self.dag, name)

    def consumers(self, name: str) -> list[str]:
        return list(self.dag.successors(name))

    def terminal(self) -> list[str]:
        return [n for n in self.order if self.dag.out_degree(n) == 0]

    def is_collection(self, node: str, output: str) -> bool:
        """Whether ``node.output`` is a collection of items."""
        inst = self.nodes[node]
        return inst.spec.outputs[output].collection or inst.mapped


def _format_pydantic(err: pydantic.ValidationError) -> list[tuple[tuple, str]]:
    out = []
    for e in err.errors():
        loc = tuple(e.get("loc", ()))
        msg = e.get("msg", "invalid")
        if e.get("type") == "extra_forbidden":
            msg = "unknown parameter"
        elif e.get("type") == "missing":
            msg = "required parameter is missing"
        elif not loc or e.get("type") == "value_error":  # a validator's own text says it all
            msg = msg.removeprefix("Value error, ")
        elif "input" in e and e.get("type") != "missing":
            msg = f"{msg} (got {e['input']!r})"
        out.append((loc, msg))
    return out


def merge_nested_defaults(model: type[pydantic.BaseModel], raw: dict[str, Any]) -> dict[str, Any]:
    """Fill a partial mapping given for a nested-model field from that field's default.

    ``yaw: {min_deg: -100}`` (or ``--set arm.yaw.min_deg=-100``) changes one field of the
    default joint, as a user expects, instead of replacing the whole joint.
    """
    out = dict(raw)
    for name, f in model.model_fields.items():
        ann = f.annotation
        if name not in out or not isinstance(out[name], dict):
            continue
        if not (isinstance(ann, type) and issubclass(ann, pydantic.BaseModel)) or f.is_required():
            continue
        default = f.get_default(call_default_factory=True)
        if isinstance(default, pydantic.BaseModel):
            merged = {**default.model_dump(), **merge_nested_defaults(ann, out[name])}
            out[name] = merged
    return out


def validate_params(
    spec: NodeSpec,
    raw: dict[str, Any],
    doc: PipelineDoc,
    node: str,
    from_defaults: set[str] | frozenset[str] = frozenset(),
) -> Params:
    """Validate ``raw`` params with the node's model, errors pointing at the YAML (all of them): a
    param in ``from_defaults`` came from the pipeline's ``defaults:`` block, and is located
    there."""
    try:
        # model_validate, not **raw: a YAML key need not be a string (`1: 2` is an unknown
        # parameter)
        return spec.params.model_validate(merge_nested_defaults(spec.params, raw))
    except pydantic.ValidationError as err:
        raise_all(
            [
                _param_error(spec, doc, node, loc, msg, bool(loc) and loc[0] in from_defaults)
                for loc, msg in _format_pydantic(err)
            ]
        )
        raise  # pragma: no cover - pydantic never raises without an error


def _with_sets(doc: PipelineDoc, node: str) -> str:
    """`` (with --set ...)`` naming the overrides of this node, for a problem of its params as a
    whole."""
    sets = [o for o in doc.overrides if o.split("=", 1)[0].split(".")[0] == node]
    return f" (with --set {', '.join(sets)})" if sets else ""


def _model_at(model: Any, path: tuple) -> Any:
    """The pydantic model a params path leads to (list indices and optional types passed through),
    or None."""
    for part in path:
        if isinstance(part, int):
            continue  # an item of a list of models: the same model
        fields = (
            model.model_fields
            if isinstance(model, type) and issubclass(model, pydantic.BaseModel)
            else {}
        )
        if part not in fields:
            return None
        model = _model_in(fields[part].annotation)
    return model if isinstance(model, type) and issubclass(model, pydantic.BaseModel) else None


def _model_in(annotation: Any) -> Any:
    """``SceneSpec`` for ``SceneSpec``, ``list[SceneSpec]`` or ``SceneSpec | None``; the annotation
    otherwise."""
    if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()):
        found = _model_in(arg)
        if isinstance(found, type) and issubclass(found, pydantic.BaseModel):
            return found
    return annotation


def _deepest_field(model: type[pydantic.BaseModel], loc: tuple) -> tuple[str, Any]:
    """The innermost field a pydantic error location names (``object.color_bgr`` for
    ``('object', 'color_bgr', 0)``), with its dotted name: its description is the fix to show."""
    names, f = [], None
    for part in loc:
        fields = (
            model.model_fields
            if isinstance(model, type) and issubclass(model, pydantic.BaseModel)
            else {}
        )
        if part not in fields:
            break
        f = fields[part]
        names.append(str(part))
        model = f.annotation
    return ".".join(names), f


def _param_error(
    spec: NodeSpec, doc: PipelineDoc, node: str, loc: tuple, msg: str, in_defaults: bool = False
) -> ConfigError:
    """One parameter problem as a located error with the fix (at ``defaults:`` for a value given
    there)."""
    if not loc:  # the params as a whole: say which --set contributed, if any
        return ConfigError(
            f"{spec.name} parameters: {msg}{_with_sets(doc, node)}",
            doc.where("nodes", node, "params"),
            node,
            f"see `stereograph nodes {spec.name}`",
        )
    field_name = ".".join(str(p) for p in loc)
    fields = spec.params.model_fields
    hint = None
    if msg == "unknown parameter":
        inner = _model_at(spec.params, loc[:-1])  # the (nested) model the unknown key was given to
        known = list(inner.model_fields) if inner is not None else list(fields)
        close = difflib.get_close_matches(str(loc[-1]), known, n=1)
        where_ = (
            spec.name if len(loc) == 1 or inner is None else f"'{'.'.join(map(str, loc[:-1]))}'"
        )
        hint = (
            f"did you mean '{close[0]}'?"
            if close
            else f"{where_} takes {sorted(known) or 'no parameters'} (see `stereograph nodes "
            f"{spec.name}`)"
        )
    elif loc and loc[0] in fields:
        name, f = _deepest_field(spec.params, loc)
        desc = f.description or ""
        hint = f"'{name}' is {type_name(f.annotation)}" + (f": {desc}" if desc else "")
    where = (
        doc.where("defaults", spec.name, *loc)
        if in_defaults
        else doc.where("nodes", node, "params", *loc)
    )
    via = f" (from defaults: {spec.name})" if in_defaults else ""
    return ConfigError(f"{spec.name} parameter '{field_name}'{via}: {msg}", where, node, hint)


def _wire(
    doc: PipelineDoc,
    nodes: dict[str, NodeInstance],
    unresolved: set[str],
    inst: NodeInstance,
    port: Any,
    ref: Any,
) -> bool:
    """Check one ``port: node.output`` wire and record it; False if it leads to a node already in
    error."""
    name = inst.name
    where = doc.where("nodes", name, "inputs", port)
    if port not in inst.spec.inputs:
        hint = did_you_mean(str(port), inst.spec.inputs, "its inputs are")
        raise ConfigError(f"{inst.type} has no input '{port}'", where, name, hint)
    if not isinstance(ref, str) or ref.count(".") != 1:
        raise ConfigError(
            f"input '{port}: {ref}' must be 'node.output'",
            where,
            name,
            "for example 'pair: rectify.pair'",
        )
    src, out = ref.split(".")
    if src in unresolved:
        return False
    if src not in nodes:
        hint = did_you_mean(src, nodes, "nodes are")
        raise ConfigError(
            f"input '{port}' refers to a node '{src}' that does not exist", where, name, hint
        )
    src_spec = nodes[src].spec
    if out not in src_spec.outputs:
        raise ConfigError(
            f"input '{port}' refers to '{src}.{out}', but {src_spec.name} has no output '{out}'",
            where,
            name,
            did_you_mean(out, src_spec.outputs, "its outputs are", f"{src}."),
        )
    have = src_spec.outputs[out].type
    accepted = inst.spec.inputs[port].types
    if "any" not in accepted and have != "any" and have not in accepted:
        wants = " or ".join(accepted)
        raise ConfigError(
            f"input '{port}' wants {wants} but '{src}.{out}' gives {have}",
            where,
            name,
            f"wire '{port}' to an output of type {wants}",
        )
    inst.inputs[port] = (src, out)
    return True


def build_graph(doc: PipelineDoc) -> Graph:
    """Resolve and check every node and wire of a pipeline before anything runs.

    Every problem is found in one pass: one is raised as a :class:`ConfigError`, several as a
    :class:`~stereograph.core.errors.ConfigErrors` listing them all (in file order).
    """
    registry.import_plugins(doc.plugins, doc.directory, doc.where("plugins"))
    problems = _unknown_default_types(doc)
    typed, nodes, unresolved = _resolve_nodes(doc, problems)
    dag = nx.DiGraph()
    dag.add_nodes_from(nodes)
    for inst in typed.values():
        _wire_node(doc, typed, nodes, unresolved, inst, dag, problems)
    problems += _missing_set_paths(doc, nodes)
    raise_all(problems)
    if not nx.is_directed_acyclic_graph(dag):
        cycle = [e[0] for e in nx.find_cycle(dag)]
        raise ConfigError(
            "the pipeline has a cycle: " + " -> ".join(cycle + [cycle[0]]),
            doc.where("nodes", cycle[0]),
            cycle[0],
            "remove one of these inputs",
        )
    order = list(nx.lexicographical_topological_sort(dag, key=lambda n: list(doc.nodes).index(n)))
    graph = Graph(doc, nodes, dag, order)
    for name in order:
        problems += _decide_mapped(graph, nodes[name])
    raise_all(problems)
    _warn_unused(graph)
    return graph


def _unknown_default_types(doc: PipelineDoc) -> list[ConfigError]:
    """``defaults:`` of a type nobody has: a misspelt type's defaults would silently apply to
    nothing."""
    known = set(registry.names())
    problems = []
    for t in doc.defaults:
        if t not in known:
            close = difflib.get_close_matches(t, sorted(known), n=1, cutoff=0.5)
            problems.append(
                ConfigError(
                    f"defaults are given for an unknown node type '{t}'",
                    doc.where("defaults", t),
                    None,
                    f"did you mean '{close[0]}'?"
                    if close
                    else "run `stereograph nodes` to list the types",
                )
            )
    return problems


def _resolve_nodes(doc: PipelineDoc, problems: list[ConfigError]) -> tuple[dict, dict, set]:
    """``(typed, nodes, unresolved)``: the nodes whose type resolved (their wires are checked),
    those whose params are valid too, and those of no known type (wires to them are not checked
    further)."""
    typed: dict[str, NodeInstance] = {}
    nodes: dict[str, NodeInstance] = {}
    unresolved = set(doc.broken)
    for name, decl in doc.nodes.items():
        try:
            spec = registry.get(str(decl["type"]), doc.where("nodes", name, "type"), name)
        except ConfigError as e:
            problems.append(e)
            unresolved.add(name)
            continue
        typed[name] = NodeInstance(name, spec, None, {})  # type: ignore[arg-type]
        try:
            defaults = doc.defaults.get(spec.name, {})
            raw = merge_params(defaults, decl.get("params") or {})
            typed[name].params = validate_params(
                spec, raw, doc, name, set(defaults) - set(decl.get("params") or {})
            )
            nodes[name] = typed[name]
        except ConfigError as e:
            problems.append(e)
    return typed, nodes, unresolved


def _wire_node(
    doc: PipelineDoc,
    typed: dict,
    nodes: dict,
    unresolved: set,
    inst: NodeInstance,
    dag: nx.DiGraph,
    problems: list[ConfigError],
) -> None:
    """One node's wires checked and drawn, its required inputs wired, its own check of its
    params."""
    name, decl = inst.name, doc.nodes[inst.name]
    wired = decl.get("inputs") or {}
    for port, ref in wired.items():
        try:
            if (
                _wire(doc, typed, unresolved, inst, port, ref)
                and name in nodes
                and inst.inputs[port][0] in nodes
            ):
                dag.add_edge(inst.inputs[port][0], name)
        except ConfigError as e:
            problems.append(e)
    for port, decl_in in inst.spec.inputs.items():
        if port not in wired and not decl_in.optional:
            problems.append(
                ConfigError(
                    f"required input '{port}' ({decl_in.type}) is not wired",
                    doc.where("nodes", name),
                    name,
                    f"add 'inputs: {{{port}: some_node.output}}'",
                )
            )
    if inst.spec.check is not None and name in nodes:
        try:
            inst.spec.check(inst.params, frozenset(wired))
        except NodeError as e:
            problems.append(
                ConfigError(
                    f"{inst.type}: {e.message.rstrip('.')}{_with_sets(doc, name)}",
                    doc.where("nodes", name, "params"),
                    name,
                    e.hint,
                )
            )


def _decide_mapped(graph: Graph, inst: NodeInstance) -> list[ConfigError]:
    """Map or reduce: a node runs per item when a non-gather input carries a collection."""
    doc, name, problems, mapped = graph.doc, inst.name, [], False
    for port, (src, out) in inst.inputs.items():
        coll = graph.is_collection(src, out)
        gather = inst.spec.inputs[port].gather
        if gather and not coll:
            problems.append(
                ConfigError(
                    f"input '{port}' gathers a collection, but '{src}.{out}' is a single artifact",
                    doc.where("nodes", name, "inputs", port),
                    name,
                    "wire it to a per-item output (e.g. of a node that runs once per pair)",
                )
            )
        mapped |= coll and not gather
    inst.mapped = mapped
    if mapped and any(o.collection for o in inst.spec.outputs.values()):
        problems.append(
            ConfigError(
                f"{inst.type} yields a collection but runs per item here",
                doc.where("nodes", name),
                name,
                "nested collections are not supported: feed it single artifacts",
            )
        )
    return problems


def _warn_unused(graph: Graph) -> None:
    """A warning for each output of a non-terminal node that nothing reads, saves or may leave
    unread."""
    used = {(s, o) for inst in graph.nodes.values() for (s, o) in inst.inputs.values()}
    for name in graph.order:
        inst = graph.nodes[name]
        if graph.dag.out_degree(name) == 0:
            continue  # terminal outputs are the run's results
        for out, decl in inst.spec.outputs.items():
            if (name, out) not in used and not decl.save and not decl.optional:
                graph.warnings.append(
                    f"{graph.doc.where('nodes', name)}: node '{name}': output '{out}' is never used"
                )


def check_pipeline(
    path: Any, overrides: list[str] | None = None
) -> tuple[Graph | None, list[ConfigError]]:
    """Every problem of a pipeline file at once: what ``stereograph validate`` prints.

    Parameters
    ----------
    path : str or Path
        The pipeline YAML.
    overrides : list of str, optional
        ``--set`` overrides, as for :func:`~stereograph.core.config.load_pipeline`.

    Returns
    -------
    (graph, problems)
        The validated graph (None when there is any problem) and the problems, each one located
        ``file:line`` with its node and fix. Problems in a node's declaration (an unknown key) do
        not hide those of the rest of the file; a file that is not valid YAML gives its one syntax
        error.
    """
    problems: list[ConfigError] = []
    try:
        doc = load_pipeline(path, overrides)
    except ConfigErrors as e:
        if e.doc is None:
            return None, e.errors
        doc, problems = e.doc, list(e.errors)
        for ov in types_first(overrides or []):  # load_pipeline stopped before the overrides
            try:
                apply_override(doc, ov)
            except ConfigError as oe:
                problems.append(oe)
    except ConfigError as e:
        return None, [e]
    try:
        graph = build_graph(doc)
    except ConfigError as e:
        return None, in_file_order(problems + [e])
    if not problems:
        _warn_missing_reads(graph)
    return (None if problems else graph), problems


def _missing_set_paths(doc: PipelineDoc, nodes: dict[str, NodeInstance]) -> list[ConfigError]:
    """A ``--set`` value of a :func:`~stereograph.core.api.PathField` that names nothing: refused
    now, with the folder it is relative to (a path that exists from the current folder is the usual
    mistake)."""
    problems = []
    for text in doc.overrides:
        lhs, _, _ = text.partition("=")
        node, _, field = lhs.partition(".")
        inst = nodes.get(node)
        info = inst.spec.params.model_fields.get(field) if inst is not None else None
        extra = info.json_schema_extra if info is not None else None
        value = getattr(inst.params, field, None) if inst is not None else None
        if (
            not (isinstance(extra, dict) and extra.get("reads_path"))
            or not isinstance(value, str)
            or not value
        ):
            continue
        given = Path(value).expanduser()
        path = given if given.is_absolute() else doc.directory / given
        if path.exists():
            continue
        here = Path.cwd() / given
        fix = (
            f"--set {lhs}={here} (it exists there, from the current folder)"
            if here.exists() and not given.is_absolute()
            else f"give a path relative to {doc.directory}, or an absolute one"
        )
        problems.append(
            ConfigError(
                f"{path} does not exist (a relative path is taken from "
                f"the pipeline file's folder, {doc.directory})",
                doc.where("nodes", node, "params", field),
                node,
                fix,
            )
        )
    return problems


def _warn_missing_reads(graph: Graph) -> None:
    """A warning per file a node declares it reads (``reads=``) that is not there: it may be written
    by another pipeline before this one runs, so it is not an error here; the run names it if
    not."""
    for name in graph.order:
        inst = graph.nodes[name]
        if inst.spec.reads is None:
            continue
        try:
            paths = inst.spec.reads(inst.params, graph.doc.directory)
        except Exception:  # noqa: BLE001 - the node's own run reports what is wrong with its params
            continue
        for p in paths:
            if not p.exists():
                graph.warnings.append(
                    f"{graph.doc.where('nodes', name)}: node '{name}': it will read "
                    f"{os.path.normpath(p)}, which "
                    "does not exist (yet): the run fails unless it is there by then"
                )
