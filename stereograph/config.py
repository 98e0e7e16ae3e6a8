"""Pipeline files: YAML (safe_load semantics) with the line of every key kept.

A pipeline file::

    name: locate
    include: [common/rig.yaml]          # optional: files whose nodes/defaults merge in first
    plugins: [my_nodes]                 # optional: modules (or .py paths) defining extra nodes
    defaults:                           # optional: params by node type, below each node's own
      segmenter.edge_morph: {canny_low: 40}
    variants:                           # optional: what `stereograph compare` varies
      compensate.type: [compensator.none, compensator.polynomial]
    nodes:
      rig:   {type: source.synthetic, params: {n_scenes: 120}}
      calib: {type: calibrator.chessboard, inputs: {views: rig.views}}

:func:`load_pipeline` returns a :class:`PipelineDoc`: plain data plus a map from each key's
path to its file and line, so that every later error can point at the YAML that caused it.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from stereograph.errors import ConfigError, UsageError, Where

Path_ = tuple  # a key path inside the document, e.g. ("nodes", "segment", "params", "canny_low")

TOP_KEYS = {"name", "description", "include", "plugins", "defaults", "variants", "nodes"}
NODE_KEYS = {"type", "params", "inputs", "description"}


@dataclass
class PipelineDoc:
    """A pipeline file as data, with where every key came from."""

    path: Path
    name: str
    description: str
    plugins: list[str]
    defaults: dict[str, dict[str, Any]]
    variants: dict[str, list[Any]]
    nodes: dict[str, dict[str, Any]]
    lines: dict[Path_, Where] = field(default_factory=dict)
    overrides: list[str] = field(default_factory=list)

    @property
    def directory(self) -> Path:
        return self.path.parent

    def where(self, *path: Any) -> Where:
        """The closest known place for a key path (falls back to its parents)."""
        p = tuple(path)
        while p:
            if p in self.lines:
                return self.lines[p]
            p = p[:-1]
        return Where(str(self.path))


def _compose(text: str, filename: str) -> tuple[Any, dict[Path_, Where]]:
    """Parse YAML with safe_load semantics and record the line of each key."""
    loader = yaml.SafeLoader(text)
    try:
        root = loader.get_single_node()
        lines: dict[Path_, Where] = {}

        def walk(node: yaml.Node, path: Path_) -> None:
            if isinstance(node, yaml.MappingNode):
                seen: dict[Any, int] = {}
                for k, v in node.value:
                    key = loader.construct_object(k, deep=True)
                    if key in seen:
                        raise ConfigError(f"duplicate key '{key}' (first at line {seen[key]})",
                                          Where(filename, k.start_mark.line + 1, k.start_mark.column + 1),
                                          hint="keep one of them")
                    seen[key] = k.start_mark.line + 1
                    lines[path + (key,)] = Where(filename, k.start_mark.line + 1, k.start_mark.column + 1)
                    walk(v, path + (key,))
            elif isinstance(node, yaml.SequenceNode):
                for i, v in enumerate(node.value):
                    lines[path + (i,)] = Where(filename, v.start_mark.line + 1, v.start_mark.column + 1)
                    walk(v, path + (i,))

        if root is None:
            return None, lines
        walk(root, ())
        data = loader.construct_document(root)
        return data, lines
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        raise ConfigError(f"not valid YAML: {e.problem or e.context}",
                          Where(filename, mark.line + 1 if mark else None, mark.column + 1 if mark else None),
                          hint="check indentation and quoting around that line") from None
    finally:
        loader.dispose()


def _read(path: Path) -> tuple[dict[str, Any], dict[Path_, Where]]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"pipeline file not found: {path}", hint="check the path") from None
    except OSError as e:
        raise ConfigError(f"cannot read pipeline file {path}: {e.strerror}") from None
    data, lines = _compose(text, str(path))
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError("a pipeline file must be a mapping with a 'nodes:' key", Where(str(path), 1))
    return data, lines


def load_pipeline(path: str | Path, overrides: list[str] | None = None, _stack: tuple = ()) -> PipelineDoc:
    """Load a pipeline file, its includes, and ``--set`` overrides.

    Parameters
    ----------
    path : str or Path
        The YAML file.
    overrides : list of str, optional
        ``node.param=value`` (value parsed as YAML), ``node.type=NAME``,
        ``node.inputs.port=src.output``; nested params with more dots.

    Returns
    -------
    PipelineDoc
    """
    path = Path(path).resolve()
    if path in _stack:
        raise ConfigError("include cycle: " + " -> ".join(str(p) for p in _stack + (path,)))
    data, lines = _read(path)
    where = lambda *p: lines.get(tuple(p), Where(str(path), 1))  # noqa: E731

    unknown = set(data) - TOP_KEYS
    for key in sorted(unknown, key=str):
        raise ConfigError(f"unknown top-level key '{key}'", where(key),
                          hint=f"use one of {sorted(TOP_KEYS)}")

    doc = PipelineDoc(path=path, name=str(data.get("name") or path.stem), description=str(data.get("description", "")),
                      plugins=[], defaults={}, variants={}, nodes={}, lines={})

    includes = data.get("include") or []
    if isinstance(includes, str):
        includes = [includes]
    for i, inc in enumerate(includes):
        inc_path = (path.parent / inc)
        if not inc_path.exists():
            raise ConfigError(f"included file not found: {inc}", where("include", i) if ("include", i) in lines
                              else where("include"), hint="paths in include: are relative to this file")
        sub = load_pipeline(inc_path, None, _stack + (path,))
        doc.plugins += sub.plugins
        for t, p in sub.defaults.items():
            doc.defaults.setdefault(t, {}).update(p)
        doc.nodes.update(copy.deepcopy(sub.nodes))
        doc.lines.update(sub.lines)
        doc.variants.update(sub.variants)

    doc.lines.update(lines)
    for key, kind in (("plugins", list), ("defaults", dict), ("variants", dict), ("nodes", dict)):
        if key in data and data[key] is not None and not isinstance(data[key], kind):
            raise ConfigError(f"'{key}' must be a {'list' if kind is list else 'mapping'}", where(key))
    doc.plugins += [str(p) for p in data.get("plugins") or []]
    for t, p in (data.get("defaults") or {}).items():
        if not isinstance(p, dict):
            raise ConfigError(f"defaults for '{t}' must be a mapping of params", where("defaults", t))
        doc.defaults.setdefault(str(t), {}).update(p)
    for k, v in (data.get("variants") or {}).items():
        doc.variants[str(k)] = v if isinstance(v, list) else [v]

    nodes = data.get("nodes")
    if not nodes and not doc.nodes:
        raise ConfigError("the pipeline has no nodes", where("nodes") if "nodes" in data else Where(str(path), 1),
                          hint="add a 'nodes:' mapping of node instances, each with a 'type:'")
    for name, decl in (nodes or {}).items():
        name = str(name)
        if decl is None:
            decl = {}
        if not isinstance(decl, dict):
            raise ConfigError("a node must be a mapping with 'type', 'params', 'inputs'", where("nodes", name),
                              node=name)
        for key in decl:
            if key not in NODE_KEYS:
                raise ConfigError(f"unknown key '{key}' in node", where("nodes", name, key), node=name,
                                  hint=f"a node takes {sorted(NODE_KEYS)}; parameters go under 'params:'")
        if "type" not in decl:
            raise ConfigError("node has no 'type'", where("nodes", name), node=name,
                              hint="add 'type: kind.method' (see `stereograph nodes`)")
        for key in ("params", "inputs"):
            if decl.get(key) is not None and not isinstance(decl[key], dict):
                raise ConfigError(f"'{key}' must be a mapping", where("nodes", name, key), node=name)
        if "." in name or not name:
            raise ConfigError(f"invalid node name '{name}'", where("nodes", name), node=name,
                              hint="node names may not contain '.', which separates node and output in inputs")
        base = doc.nodes.get(name, {})
        # a node redefined over an included one keeps the included params only if the type is the same
        base_params = (base.get("params") or {}) if base.get("type") == decl["type"] else {}
        merged = {"type": decl["type"],
                  "params": {**base_params, **(decl.get("params") or {})},
                  "inputs": {**(base.get("inputs") or {}), **(decl.get("inputs") or {})}}
        doc.nodes[name] = merged

    for ov in overrides or []:
        apply_override(doc, ov)
    return doc


def parse_override(text: str) -> tuple[str, list[str], Any]:
    """Split ``node.field[.sub]=value`` into (node, [field, sub], parsed value)."""
    if "=" not in text:
        raise UsageError(f"--set '{text}' is not of the form node.param=value",
                         hint="for example --set segment.canny_low=40")
    lhs, rhs = text.split("=", 1)
    parts = lhs.strip().split(".")
    if len(parts) < 2 or not all(parts):
        raise UsageError(f"--set '{text}': the left side must be node.param",
                         hint="for example --set segment.canny_low=40")
    try:
        value = yaml.safe_load(rhs) if rhs.strip() else ""
    except yaml.YAMLError:
        value = rhs
    return parts[0], parts[1:], value


def apply_override(doc: PipelineDoc, text: str) -> None:
    """Apply one ``--set`` to the document (validation happens later, with the rest)."""
    node, fields, value = parse_override(text)
    if node not in doc.nodes:
        import difflib

        close = difflib.get_close_matches(node, list(doc.nodes), n=1)
        raise UsageError(f"--set '{text}': no node named '{node}' in {doc.path.name}",
                         hint=f"did you mean '{close[0]}'?" if close else f"nodes are {sorted(doc.nodes)}")
    decl = doc.nodes[node]
    where = Where(f"--set {text}")
    if fields == ["type"]:
        decl["type"] = str(value)
        decl["params"] = {}  # params of another type rarely fit; defaults apply
    elif fields[0] == "inputs" and len(fields) == 2:
        decl["inputs"][fields[1]] = str(value)
    else:
        if fields[0] == "params":
            fields = fields[1:]
        target = decl.setdefault("params", {})
        for f in fields[:-1]:
            nxt = target.get(f)
            if not isinstance(nxt, dict):
                nxt = {}
                target[f] = nxt
            target = nxt
        target[fields[-1]] = value
    doc.lines[("nodes", node, "params", *fields)] = where
    doc.overrides.append(text)
