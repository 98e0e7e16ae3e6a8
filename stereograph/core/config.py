"""Pipeline files: a file, its includes and ``--set`` overrides read into a :class:`PipelineDoc`.

:func:`load_pipeline` keeps the file and line of every key (parsed by
:mod:`stereograph.core.yaml_lines`), so that every later error points at the YAML that caused
it; names that become file names are checked here (:func:`check_name`). The file's shape:
docs/engine.md.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from stereograph.core.errors import ConfigError, UsageError, Where, did_you_mean, raise_all
from stereograph.core.yaml_lines import Path_, parse_yaml

TOP_KEYS = {
    "name",
    "description",
    "include",
    "plugins",
    "defaults",
    "variants",
    "compare",
    "repeat",
    "nodes",
}
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
    # `compare: {metric: NAME[:max|:abs]}`: what `stereograph compare` ranks by
    compare_metric: str | None = None
    # `repeat: N`: cycles of the live part a plain `run` runs (0 = until stopped)
    repeat: int | None = None
    # nodes left out for a problem of their own (already reported)
    broken: set[str] = field(default_factory=set)

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


# Bounds on what one pipeline may read (its YAML's own: stereograph.core.yaml_lines). Pipeline
# files are written by hand and are a few KB; data belongs in files that nodes read.
MAX_FILE_BYTES = 256 * 1024
MAX_INCLUDED_FILES = 64  # files read for one pipeline, includes of includes counted

# letters, digits, '_' and '-' (no dot, separator or space)
_SAFE_NAME = re.compile(r"^[^\W][\w-]*$")
_SAFE_PIPELINE_NAME = re.compile(r"^[^\W][\w.-]*$")
MAX_NAME_CHARS = 100


def check_name(
    name: str, what: str, where: Where, node: str | None = None, dots: bool = False
) -> None:
    """Refuse a node or pipeline name that is not a safe file-name component.

    Names become folder and file names (``<out>/<node>/<output>.json``, ``runs/<pipeline>/``), so
    a name with a path separator, a leading dot or a control character could write elsewhere.
    """
    pattern = _SAFE_PIPELINE_NAME if dots else _SAFE_NAME
    if not pattern.match(name) or len(name) > MAX_NAME_CHARS or ".." in name:
        allowed = "letters, digits, '_', '-'" + (" and '.'" if dots else "")
        raise ConfigError(
            f"invalid {what} {name!r}",
            where,
            node,
            hint=f"a {what} is used as a file name: use {allowed} only, starting with a letter, "
            f"digit or '_', at most {MAX_NAME_CHARS} characters"
            + ("" if dots else " ('.' separates node and output in inputs)"),
        )


def merge_params(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` on top of ``base``, nested mappings merged field by field (neither is changed).

    A node's ``object: {radius_cm: 5}`` (or ``--set segment.object.radius_cm=5``) changes the
    radius of the ``object`` that ``defaults:`` or an included file gave, and keeps its colour,
    as ``merge_nested_defaults`` does for a parameter model's own defaults.
    """
    out = dict(base)
    for k, v in over.items():
        out[k] = (
            merge_params(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
        )
    return out


def _read(path: Path) -> tuple[dict[str, Any], dict[Path_, Where]]:
    try:
        if not path.exists():
            raise ConfigError(f"pipeline file not found: {path}", hint=_nearby_files(path))
        if not path.is_file():
            raise ConfigError(
                f"{path} is not a regular file", hint="give the path of a pipeline .yaml file"
            )
        with path.open("rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except ConfigError:
        raise
    except (OSError, ValueError) as e:
        raise ConfigError(
            f"cannot read pipeline file {path}: {getattr(e, 'strerror', None) or e}"
        ) from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(
            f"pipeline file {path} is larger than {MAX_FILE_BYTES // 1024} KiB",
            hint="a pipeline file sets parameters; put large data in a file that a node reads",
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise ConfigError(
            f"byte 0x{raw[e.start]:02x} is not UTF-8 text",
            Where(str(path), line),
            hint="save the file as UTF-8",
        ) from None
    data, lines = parse_yaml(text, str(path))
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(
            "a pipeline file must be a mapping with a 'nodes:' key", Where(str(path), 1)
        )
    return data, lines


def _nearby_files(path: Path) -> str:
    """A Fix for a pipeline path that does not exist: the closest pipeline file in its folder."""
    try:
        there = [p.name for p in path.parent.glob("*.y*ml") if p.is_file()]
    except OSError:
        there = []
    hint = did_you_mean(path.name, there, f"pipeline files in {path.parent} are")
    return hint if there and (len(there) <= 20 or hint.startswith("did")) else "check the path"


def load_pipeline(
    path: str | Path,
    overrides: list[str] | None = None,
    _stack: tuple = (),
    _budget: list[int] | None = None,
) -> PipelineDoc:
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
    path, budget = _open(path, _stack, _budget)
    data, lines = _read(path)
    where = lambda *p: lines.get(tuple(p), Where(str(path), 1))  # noqa: E731

    # Problems that leave the rest of the file readable are collected, so that one `validate`
    # reports them all; the file is read on without the part in error.
    problems = [
        ConfigError(
            f"unknown top-level key '{key}'", where(key), hint=f"use one of {sorted(TOP_KEYS)}"
        )
        for key in sorted(set(data) - TOP_KEYS, key=str)
    ]
    doc = PipelineDoc(
        path=path,
        name=_pipeline_name(data, path, where),
        description=str(data.get("description", "")),
        plugins=[],
        defaults={},
        variants={},
        nodes={},
        lines={},
    )
    _include(doc, data, lines, where, _stack + (path,), budget)
    doc.lines.update(lines)
    _top_level(doc, data, where)
    problems += _node_decls(doc, data, where)
    raise_all(problems, doc)
    for ov in types_first(overrides or []):
        apply_override(doc, ov)
    return doc


def _node_decls(doc: PipelineDoc, data: dict, where: Callable[..., Where]) -> list[ConfigError]:
    """Read the file's ``nodes:`` into ``doc`` (over what its includes declared); the problems of
    a node leave it out, and are returned so that one ``validate`` reports them all."""
    nodes = data.get("nodes")
    if not nodes and not doc.nodes:
        raise ConfigError(
            "the pipeline has no nodes",
            where("nodes") if "nodes" in data else Where(str(doc.path), 1),
            hint="add a 'nodes:' mapping of node instances, each with a 'type:'",
        )
    problems = []
    for name, decl in (nodes or {}).items():
        name = str(name)
        try:
            doc.nodes[name] = _node_decl(doc.nodes.get(name, {}), name, decl, where)
        except ConfigError as e:
            problems.append(e)
            doc.broken.add(name)
            doc.nodes.pop(name, None)
    return problems


def _open(path: str | Path, stack: tuple, budget: list[int] | None) -> tuple[Path, list[int]]:
    """The pipeline file's resolved path and what is left of the include budget (ConfigError for a
    path that cannot be one, an include cycle, or too many files)."""
    try:
        path = Path(path).resolve()
    except (OSError, ValueError) as e:  # a NUL in the name, a loop of symlinks
        raise ConfigError(
            f"cannot use pipeline path {str(path)!r}: {e}", hint="check the path"
        ) from None
    if path in stack:
        raise ConfigError("include cycle: " + " -> ".join(str(p) for p in stack + (path,)))
    budget = budget if budget is not None else [MAX_INCLUDED_FILES]
    budget[0] -= 1
    if budget[0] < 0:
        raise ConfigError(
            f"more than {MAX_INCLUDED_FILES} files are read through include:",
            Where(str(path)),
            hint="include each shared file once",
        )
    return path, budget


def _pipeline_name(data: dict, path: Path, where: Callable[..., Where]) -> str:
    """``name:``, checked; else the file's name made safe for a folder name."""
    name = data.get("name")
    if name is None or name == "":
        return re.sub(r"[^\w.-]", "_", path.stem).lstrip(".")[:MAX_NAME_CHARS] or "pipeline"
    if not isinstance(name, (str, int)) or isinstance(name, bool):
        raise ConfigError("'name' must be a text", where("name"), hint="for example 'name: locate'")
    check_name(str(name), "pipeline name", where("name"), dots=True)
    return str(name)


def _include(
    doc: PipelineDoc,
    data: dict,
    lines: dict,
    where: Callable[..., Where],
    stack: tuple,
    budget: list[int],
) -> None:
    """Read the ``include:`` files into ``doc``, in order (a later one's nodes over an earlier
    one's)."""
    includes = data.get("include") or []
    if isinstance(includes, str):
        includes = [includes]
    if not isinstance(includes, list):
        raise ConfigError(
            "'include' must be a file name or a list of file names",
            where("include"),
            hint="for example 'include: [common.yaml]' (relative to this file)",
        )
    for i, inc in enumerate(includes):
        at = where("include", i) if ("include", i) in lines else where("include")
        if not isinstance(inc, str) or not inc.strip():
            raise ConfigError(
                f"include: {inc!r} is not a file name",
                at,
                hint="list YAML files relative to this file, e.g. [common.yaml]",
            )
        inc_path = stack[-1].parent / inc
        try:
            ok, there = inc_path.is_file(), inc_path.exists()
        except (OSError, ValueError):
            ok = there = False
        if not ok:
            raise ConfigError(
                f"included {inc} is not a regular file (a folder or a device)"
                if there
                else f"included file not found: {inc}",
                at,
                hint="paths in include: are relative to this file and name a YAML file",
            )
        try:
            sub = load_pipeline(inc_path, None, stack, budget)
        except ConfigError as e:
            # (the included file's own line alone does not say which pipeline read it; an error
            # with no line of its own is placed at the include: line)
            for err in [e, *getattr(e, "errors", [])]:
                err.where = _read_through(err.where, at) if err.where else at
            partial = getattr(e, "doc", None)  # (what validate goes on checking)
            if isinstance(partial, PipelineDoc):
                partial.lines = {key: _read_through(w, at) for key, w in partial.lines.items()}
            raise
        doc.plugins += sub.plugins
        for t, p in sub.defaults.items():
            doc.defaults[t] = merge_params(doc.defaults.get(t, {}), p)
        doc.nodes.update(copy.deepcopy(sub.nodes))
        doc.lines.update({key: _read_through(w, at) for key, w in sub.lines.items()})
        doc.variants.update(sub.variants)
        doc.compare_metric = sub.compare_metric or doc.compare_metric
        doc.repeat = sub.repeat if sub.repeat is not None else doc.repeat


def _read_through(where: Where, include_line: Where) -> Where:
    """``where``, in a file read through ``include_line``."""
    return replace(where, included_at=(*where.included_at, include_line))


def _top_level(doc: PipelineDoc, data: dict, where: Callable[..., Where]) -> None:
    """``plugins``, ``defaults``, ``variants`` and ``compare`` into ``doc``, checked."""
    for key, kind in (("plugins", list), ("defaults", dict), ("variants", dict), ("nodes", dict)):
        if key in data and data[key] is not None and not isinstance(data[key], kind):
            raise ConfigError(
                f"'{key}' must be a {'list' if kind is list else 'mapping'}", where(key)
            )
    for i, p in enumerate(data.get("plugins") or []):
        if not isinstance(p, str) or not p.strip():
            raise ConfigError(
                f"plugin {p!r} is not a module name or .py path",
                where("plugins", i),
                hint="for example 'plugins: [my_nodes.py]' (relative to this file)",
            )
        doc.plugins.append(p)
    for t, p in (data.get("defaults") or {}).items():
        if not isinstance(p, dict):
            raise ConfigError(
                f"defaults for '{t}' must be a mapping of params", where("defaults", t)
            )
        doc.defaults[str(t)] = merge_params(doc.defaults.get(str(t), {}), p)
    for k, v in (data.get("variants") or {}).items():
        doc.variants[str(k)] = v if isinstance(v, list) else [v]
    if data.get("compare") is not None:
        block = data["compare"]
        if (
            not isinstance(block, dict)
            or set(block) - {"metric"}
            or not isinstance(block.get("metric"), str)
        ):
            raise ConfigError(
                "'compare' must be a mapping with one key, 'metric'",
                where("compare"),
                hint="for example 'compare: {metric: NAME}', NAME a metric the nodes declare "
                "(lowest "
                "is best; NAME:max for highest, NAME:abs for closest to zero)",
            )
        doc.compare_metric = block["metric"]
    doc.repeat = _repeat(data, where) if data.get("repeat") is not None else doc.repeat


def _repeat(data: dict, where: Callable[..., Where]) -> int:
    """``repeat: N``, checked."""
    n = data["repeat"]
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ConfigError(
            f"'repeat' must be a whole number >= 0, got {n!r}",
            where("repeat"),
            hint="for example 'repeat: 30' (cycles of the live part; 0 = until a node or Ctrl-C "
            "stops the loop); `run --repeat N` overrides it",
        )
    return n


def _node_decl(base: dict, name: str, decl: Any, where: Callable[..., Where]) -> dict:
    """One node's declaration, checked and merged over an included one of the same name (whose
    type it keeps when it names none, and whose params it keeps only if the type is the same)."""
    decl = {} if decl is None else decl
    if not isinstance(decl, dict):
        raise ConfigError(
            "a node must be a mapping with 'type', 'params', 'inputs'",
            where("nodes", name),
            node=name,
        )
    for key in decl:
        if key not in NODE_KEYS:
            raise ConfigError(
                f"unknown key '{key}' in node",
                where("nodes", name, key),
                node=name,
                hint=f"a node takes {sorted(NODE_KEYS)}; parameters go under 'params:'",
            )
    if "type" not in decl and isinstance(base.get("type"), str):
        decl = {**decl, "type": base["type"]}  # a change to an included node keeps its type
    if "type" not in decl:
        raise ConfigError(
            "node has no 'type'",
            where("nodes", name),
            node=name,
            hint="add 'type: kind.method' (see `stereograph nodes`)",
        )
    for key in ("params", "inputs"):
        if decl.get(key) is not None and not isinstance(decl[key], dict):
            raise ConfigError(f"'{key}' must be a mapping", where("nodes", name, key), node=name)
    check_name(name, "node name", where("nodes", name), node=name)
    if not isinstance(decl["type"], str):
        raise ConfigError(
            f"'type' must be a node type name, not {decl['type']!r}",
            where("nodes", name, "type"),
            node=name,
            hint="add 'type: kind.method' (see `stereograph nodes`)",
        )
    base_params = (base.get("params") or {}) if base.get("type") == decl["type"] else {}
    return {
        "type": decl["type"],
        "params": merge_params(base_params, decl.get("params") or {}),
        "inputs": {**(base.get("inputs") or {}), **(decl.get("inputs") or {})},
    }


def types_first(overrides: list[str]) -> list[str]:
    """``--set`` texts with the type swaps (``NODE.type=NAME``) first, the rest in their order: a
    swap resets the node's params, so a param set before it on the line was silently dropped."""

    def is_type(text: str) -> bool:
        return text.split("=", 1)[0].strip().split(".")[1:] == ["type"]

    return [t for t in overrides if is_type(t)] + [t for t in overrides if not is_type(t)]


def parse_override(text: str) -> tuple[str, list[str], Any]:
    """Split ``node.field[.sub]=value`` into (node, [field, sub], parsed value)."""
    if "=" not in text:
        raise UsageError(
            f"--set '{text}' is not of the form node.param=value",
            hint="for example --set segment.canny_low=40",
        )
    lhs, rhs = text.split("=", 1)
    parts = lhs.strip().split(".")
    if len(parts) < 2 or not all(parts) or parts[1:] == ["params"]:
        raise UsageError(
            f"--set '{text}': the left side must be node.param",
            hint="for example --set segment.canny_low=40",
        )
    if len(text) > MAX_FILE_BYTES:
        raise UsageError(
            f"--set {lhs}=...: the value is longer than {MAX_FILE_BYTES // 1024} KiB",
            hint="put large data in a file that a node reads",
        )
    try:
        value = parse_yaml(rhs, f"--set {lhs}", record_lines=False)[0] if rhs.strip() else ""
    except ConfigError as e:
        if not getattr(e, "syntax", False):
            raise  # beyond the bounds (alias bomb, nesting): refuse, never fall back
        value = rhs  # not YAML: the text as written
    return parts[0], parts[1:], value


def check_node_named(doc: PipelineDoc, node: str, what: str, where: Where | None = None) -> None:
    """Refuse a ``node`` the pipeline does not have, as ``what`` (a ``--set``, a ``variants:`` key)
    named it: UsageError for a command-line option, ConfigError at ``where`` for a file's line."""
    if node in doc.nodes:
        return
    hint = did_you_mean(node, doc.nodes, "nodes are")
    if where is None:
        raise UsageError(f"{what}: no node named '{node}' in {doc.path.name}", hint=hint)
    raise ConfigError(f"{what}: no node named '{node}' in {doc.path.name}", where, hint=hint)


def _index(container: Any, field: str) -> int | None:
    """``field`` as an index into ``container`` when it is a list and the field a whole number
    inside it."""
    if isinstance(container, list) and field.isdigit() and int(field) < len(container):
        return int(field)
    return None


def _set_param(target: dict, fields: list[str], value: Any) -> list[int]:
    """Set ``value`` at the path ``fields`` in nested params (a number indexes a list the file gave:
    ``objects.0.color_bgr``); returns the depths at which a missing or scalar value was replaced by
    a mapping."""
    replaced = []
    for k, f in enumerate(fields[:-1]):
        i = _index(target, f)
        nxt = target[i] if i is not None else target.get(f) if isinstance(target, dict) else None
        if not isinstance(nxt, (dict, list)) or (
            isinstance(nxt, list) and _index(nxt, fields[k + 1]) is None
        ):
            nxt = {}
            if i is not None:
                target[i] = nxt
            else:
                target[f] = nxt
            replaced.append(k)
        target = nxt
    i = _index(target, fields[-1])
    if i is not None:
        target[i] = value
    else:
        target[fields[-1]] = value
    return replaced


def apply_override(doc: PipelineDoc, text: str, source: str = "--set") -> None:
    """Apply one ``--set`` to the document (validation happens later, with the rest).

    ``source`` is what a problem with it is said to come from (``--vary`` for a compared variant's
    setting).
    """
    node, fields, value = parse_override(text)
    check_node_named(doc, node, f"{source} '{text}'")
    decl = doc.nodes[node]
    where = Where(f"{source} {text}")
    if fields == ["type"]:
        decl["type"] = str(value)
        decl["params"] = {}  # params of another type rarely fit; defaults apply
        # (a problem with it is the --set's, not the file's line)
        doc.lines[("nodes", node, "type")] = where
    elif fields[0] == "inputs" and len(fields) == 2:
        decl["inputs"][fields[1]] = str(value)
        doc.lines[("nodes", node, "inputs", fields[1])] = where
    else:
        if fields[0] == "params":
            fields = fields[1:]
        replaced = _set_param(decl.setdefault("params", {}), fields, value)
        for k in replaced:  # (the value it replaced was the file's)
            doc.lines[("nodes", node, "params", *fields[: k + 1])] = where
    key = ("nodes", node, "params", *fields)
    for stale in [k for k in doc.lines if k[: len(key)] == key]:  # lines of the value it replaces
        del doc.lines[stale]
    doc.lines[key] = where
    doc.overrides.append(text)
