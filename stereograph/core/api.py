"""The engine's public surface for node authors (public as :mod:`stereograph.api`).

A node is a plain function decorated with :func:`node`: a pydantic params model, typed named
inputs and outputs, a version; it runs as ``fn(params, **inputs) -> {output: value}``. Values
are plain data (NumPy arrays, numbers, strings, lists, dicts). Public: :func:`node`,
:class:`Params`, :class:`In`, :class:`Out`, :class:`NodeError`, :class:`RunContext`, ``Field``.
Example and details: docs/engine.md.
"""

from __future__ import annotations

import inspect
import re
import stat
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator  # noqa: F401  (re-exported)

from stereograph.core.checks import ARTIFACT_CHECKS, artifact_check  # noqa: F401  (re-exported)
from stereograph.core.errors import ConfigError
from stereograph.core.yaml_lines import parse_yaml

__all__ = [
    "Params",
    "Field",
    "PathField",
    "data_file",
    "parse_yaml_data",
    "OrderedRange",
    "PositiveRange",
    "In",
    "Out",
    "NodeSpec",
    "NodeError",
    "RunContext",
    "node",
    "REGISTRY",
    "artifact_check",
]


class Params(BaseModel):
    """Base class of every node's parameter model.

    Unknown keys are refused, values are validated on assignment, and every
    field should carry a ``description`` that names its unit. Every float is
    finite (``inf``, ``nan`` and ``1e309`` are refused when the pipeline is
    validated); a field that means "no limit" by ``inf`` opts out with
    ``Field(..., allow_inf_nan=True)``.
    """

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, frozen=True, allow_inf_nan=False
    )

    @model_validator(mode="before")
    @classmethod
    def _no_control_characters(cls, data: Any) -> Any:
        # A title or a name goes to terminals, pictures and pages: an escape sequence in it (YAML's
        # "\e") would reach a terminal raw through a library's warning. Newlines and tabs are text.
        where = _control_character_at(data)
        if where is not None:
            raise ValueError(
                f"{where or 'a value'} holds a control character (an escape sequence?): "
                "write it as plain text"
            )
        return data


def _control_character_at(value: Any, path: str = "") -> str | None:
    """The key path of the first string (in nested dicts and lists) holding a control character,
    else None."""
    if isinstance(value, str):
        return (
            path
            if any(ord(c) < 32 and c not in "\n\t\r" or 0x7F <= ord(c) < 0xA0 for c in value)
            else None
        )
    if isinstance(value, dict):
        items = ((f"{path}.{k}" if path else str(k), v) for k, v in value.items())
    elif isinstance(value, (list, tuple)):
        items = ((f"{path}[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for where, v in items:
        found = _control_character_at(v, where)
        if found is not None:
            return found
    return None


def PathField(default: Any = ..., **kwargs: Any) -> Any:  # noqa: N802  (a Field, named like one)
    """A :func:`Field` naming a file or folder the node reads, relative to the pipeline file. A
    ``--set`` that names one that does not exist is refused before anything runs, saying where it
    was looked for (the pipeline's folder, not the current one)."""
    return Field(default, json_schema_extra={"reads_path": True}, **kwargs)


# a calibration, truth or target file is KB to a few MB: beyond this, not one
MAX_DATA_FILE_MB = 64.0
# brackets / tags nested deeper than this: no data file of ours, a parser's stack bomb
MAX_DATA_NESTING = 64


def data_file(path: str | Path, what: str, label: str, max_mb: float = MAX_DATA_FILE_MB) -> Path:
    """``path``, checked before a node reads it as ``what`` (a data file may come from anyone): it
    exists, it is a regular file -- a device, FIFO or socket is refused before it is opened
    (``/dev/zero`` never ends, a FIFO never answers) --, it holds at most ``max_mb`` MB, and it does
    not nest brackets or XML tags deeper than :data:`MAX_DATA_NESTING` (a parser's stack).
    :class:`NodeError` naming it, else."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        raise NodeError(
            f"{label}: {p} does not exist.",
            hint="relative paths start at the pipeline file's folder",
        ) from None
    if not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a device, FIFO or socket"
        raise NodeError(
            f"{label}: {p} is {kind}, not a file: it is not read as {what}.",
            hint=f"give the path of {what} (a regular file)",
        )
    if st.st_size > max_mb * 2**20:
        raise NodeError(
            f"{label}: {p} holds {st.st_size / 2**20:.0f} MB, more than {what} can "
            f"({max_mb:g} MB).",
            hint=f"give {what}; a file this large is another kind of file",
        )
    depth = _nesting(p.read_bytes())
    if depth > MAX_DATA_NESTING:
        raise NodeError(
            f"{label}: {p} nests its values {depth} levels deep; {what} needs a few.",
            hint=f"give {what}; this one was not written by a calibration or measuring tool",
        )
    return p


def _nesting(data: bytes) -> int:
    """How deep ``[``/``{`` brackets (JSON, YAML flow) or XML elements nest (a rough count: strings
    aside)."""
    deepest = level = 0
    for m in re.finditer(rb"[\[{]|[\]}]|<[A-Za-z_][^>]*?(?<!/)>|</", data):
        tok = m.group(0)
        level += 1 if tok[:1] in (b"[", b"{") or (tok[:1] == b"<" and tok[1:2] != b"/") else -1
        deepest = max(deepest, level)
    return deepest


def parse_yaml_data(text: str, source: str, label: str) -> Any:
    """YAML from a data file, with the bounds a pipeline file has (safe_load semantics, depth,
    values after alias expansion: a few hundred bytes of aliases cannot ask for gigabytes)."""

    try:
        return parse_yaml(text, source, record_lines=False)[0]
    except ConfigError as e:
        raise NodeError(
            f"{label}: {e}", hint="give a YAML file written by the tool it comes from"
        ) from None


def _ordered(value: tuple[float, float]) -> tuple[float, float]:
    lo, hi = value
    if not lo < hi:
        raise ValueError(f"the first value must be below the second (got [{lo:g}, {hi:g}])")
    return value


OrderedRange = Annotated[tuple[float, float], AfterValidator(_ordered)]
"""A ``[low, high]`` range with ``low < high`` (both finite); use as a params field type."""


def _positive_ordered(value: tuple[float, float]) -> tuple[float, float]:
    if not value[0] > 0:
        raise ValueError(f"the range must start above 0 (got [{value[0]:g}, {value[1]:g}])")
    return _ordered(value)


PositiveRange = Annotated[tuple[float, float], AfterValidator(_positive_ordered)]
"""A ``[low, high]`` range with ``0 < low < high`` (a distance or size range)."""


class NodeError(Exception):
    """A failure the user can act on (bad input, no object found, ...).

    Parameters
    ----------
    message : str
        What went wrong, in one sentence; name the file or value involved.
    hint : str, optional
        How to fix it. The engine prints it after the message.
    lasting : bool
        No later call should be tried until a person has seen to something: the failure would come
        back every time (a serial port that cannot be opened, a missing file), or trying again is
        unsafe (an actuator stopped half-way through a motion). A ``--repeat`` loop stops here
        instead of going on with the next cycle.
    """

    def __init__(self, message: str, hint: str | None = None, lasting: bool = False):
        super().__init__(message)
        self.message = message
        self.hint = hint
        self.lasting = lasting

    def __str__(self) -> str:  # pragma: no cover - trivial
        return self.message if not self.hint else f"{self.message} Fix: {self.hint}"


@dataclass(frozen=True)
class In:
    """A named input of a node.

    Parameters
    ----------
    type : str
        Artifact type name (see ``docs/artifacts.md``); ``"any"`` accepts all. Alternatives
        are separated by ``|`` (``"RectifiedPair | StereoPair"``); the node learns which one
        is wired from ``ctx.input_types``.
    gather : bool
        If true and the wired output is a collection, the node receives the
        whole collection at once as ``{item_id: value}`` (a *reduce*). If false
        (default) and the wired output is a collection, the node runs once per
        item (a *map*).
    optional : bool
        The input may be left unwired; the function then receives ``None``.
    description : str
        One line for ``stereograph nodes``.
    """

    type: str = "any"
    gather: bool = False
    optional: bool = False
    description: str = ""

    @property
    def types(self) -> tuple[str, ...]:
        """The accepted artifact type names (the ``|``-separated alternatives of ``type``)."""
        return tuple(t.strip() for t in self.type.split("|") if t.strip())


@dataclass(frozen=True)
class Out:
    """A named output of a node.

    Parameters
    ----------
    type : str
        Artifact type name; ``"any"`` matches every input.
    collection : bool
        The node returns an ordered ``{item_id: value}`` mapping whose items are
        cached one by one and fan out to map nodes downstream.
    save : bool
        Also write this output into the run's output folder on every run
        (images as PNG, everything else as JSON), cached or not.
    optional : bool
        A by-product a pipeline may leave unwired without a warning (a synthetic
        source's ground truth, say). Unwired outputs are otherwise warned about.
    description : str
        One line for ``stereograph nodes``.
    lossy : bool
        A picture for people (an overlay), not data for other nodes: an 8-bit image
        output kept in the cache and saved as JPEG (quality 90, about 6x smaller than
        PNG). Every reader, a downstream node included, gets what that JPEG decodes
        to, on a fresh run as on a cached one.
    headline : bool
        The run's answer, or part of it (a saved output): shown first on the run's
        page, above the node details (an accuracy table, the arm at the grasp).
    """

    type: str = "any"
    collection: bool = False
    save: bool = False
    optional: bool = False
    description: str = ""
    lossy: bool = False
    headline: bool = False


STOP_LOOP = "stereograph:stop-loop"
"""The key of :meth:`RunContext.stop_loop`'s request among the run's resources: (node, reason)."""


@dataclass
class RunContext:
    """What a node may learn about the run it is part of.

    A node asks for it by having a keyword parameter named ``ctx``.

    Attributes
    ----------
    node_name : str
        The instance name in the pipeline (``segment``), not the type.
    item : str or None
        The item id when the node runs once per collection item.
    out_dir : Path
        The run's output folder for this node (created on demand). Files written
        here are not cached; prefer ``Out(save=True)`` for results. They are the
        run's files (``run.json`` lists them): a later run into the same folder
        removes them with the rest.
    pipeline_dir : Path
        Folder of the pipeline file: resolve relative paths in params from it.
    input_types : dict
        Input port -> the artifact type of the output wired to it (unwired ports absent).
        A node whose input accepts alternatives (``In("A | B")``) reads which one it got here.
    resources : dict or None
        Objects kept open for the whole run (every cycle of ``--repeat``); see :meth:`resource`.
    producing_items : bool
        True when the engine produces this node's collection outputs item by item (the node
        declared ``items=``, see :func:`node`): a call with ``item`` None then returns only the
        other outputs, a call with ``item`` set that item's value of each collection output.
    lost : dict
        For each gathering input port (``In(..., gather=True)``): ``{item: why}`` of the items that
        failed upstream of the gathered collection and so never reached it (``why`` names the node
        and its reason). A node that counts items (a report) says how many it could not count.
    """

    node_name: str
    item: str | None
    out_dir: Path
    pipeline_dir: Path
    messages: list[str] = field(default_factory=list)
    input_types: dict[str, str] = field(default_factory=dict)
    resources: dict[str, Any] | None = None
    on_progress: Callable[[float, float, str], None] | None = field(
        default=None, repr=False, compare=False
    )
    producing_items: bool = False
    lost: dict[str, dict[str, str]] = field(default_factory=dict)

    def resource(self, key: str, open_fn: Callable[[], Any]) -> Any:
        """An object (a device, a connection) opened once and kept for the whole run.

        The first call with ``key`` calls ``open_fn()``; later calls in the same run, such as the
        next cycle of ``stereograph run --repeat``, get the same object. The engine calls its
        ``close()`` (or ``release()``) when the run ends, interrupted or not. Returns None when
        the run cannot keep objects (the node runs in another process): the node then opens and
        closes the object itself.
        """
        if self.resources is None:
            return None
        key = f"{self.node_name}:{key}"
        if key not in self.resources:
            self.resources[key] = open_fn()
        return self.resources[key]

    def stop_loop(self, reason: str) -> None:
        """Ask a ``--repeat`` loop (or a pipeline's ``repeat:``) to end after this cycle, in words
        (``"the table is clear"``): the cycle itself finishes normally. No effect outside a loop."""
        if self.resources is not None:
            self.resources[STOP_LOOP] = (self.node_name, str(reason))

    def progress(self, done: float, total: float, unit: str = "items") -> None:
        """Report progress inside this call: ``ctx.progress(37, 120, "scenes")``.

        For a node that does much in one call (a source rendering or reading a whole
        collection); the run shows ``rig 37/120 scenes`` with an ETA. Cheap to call often; a
        no-op where nobody listens (a worker process, a plain function call).
        """
        if self.on_progress is not None:
            try:
                self.on_progress(done, total, unit)
            except Exception:  # noqa: BLE001 - a display problem must never fail the node
                pass

    def warn(self, message: str) -> None:
        """Record a warning that the run summary shows next to the node."""
        self.messages.append(message)

    def path(self, value: str | Path) -> Path:
        """Resolve a path given in YAML relative to the pipeline's folder."""
        p = Path(value).expanduser()
        return p if p.is_absolute() else (self.pipeline_dir / p)


@dataclass(frozen=True)
class NodeSpec:
    """Everything the engine knows about a node type."""

    name: str
    fn: Callable[..., Any]
    params: type[Params]
    inputs: dict[str, In]
    outputs: dict[str, Out]
    version: str
    cacheable: bool
    reads: Callable[[Params, Path], list[Path]] | None
    description: str
    items: Callable[[Params, RunContext], list[str]] | None = None
    prepare: Callable[[], Any] | None = None
    check: Callable[[Params, frozenset[str]], None] | None = None

    @property
    def kind(self) -> str:
        """The part of the name before the first dot (``segmenter``)."""
        return self.name.split(".", 1)[0]

    @cached_property
    def wants_ctx(self) -> bool:
        return "ctx" in inspect.signature(self.fn).parameters


class _Registry(dict):
    """Node types that have been defined (imported) so far, by name."""


REGISTRY: _Registry = _Registry()


class _UndeclaredParam(NodeError, AttributeError):
    """A node declared without ``params=`` read a param. An AttributeError too, so that ``hasattr``
    and ``getattr(params, name, default)`` still work; a NodeError, so the run says it plainly."""


class _NoParams(Params):
    """The params of a node declared without ``params=``: none."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # (pydantic's own private attributes)
            return super().__getattr__(name)
        raise _UndeclaredParam(
            f"the node reads params.{name}, but its @node(...) declares no params model",
            hint=f"declare one: class MyParams(Params): {name}: float = Field(..., "
            "description='... (unit)'), "
            "then @node(..., params=MyParams); the pipeline's params: then set it",
        )


def type_name(ann: Any) -> str:
    """A parameter's type as a person reads it: ``'train' | 'all'``, ``float | None``,
    ``tuple[float, float]`` (constraints such as ``PositiveRange``'s validator are left out: the
    description states them)."""
    origin = typing.get_origin(ann)
    if origin is typing.Annotated:
        return type_name(typing.get_args(ann)[0])
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in typing.get_args(ann))
    if origin is not None:
        args = [type_name(a) for a in typing.get_args(ann)]
        name = getattr(origin, "__name__", str(origin).replace("typing.", ""))
        return " | ".join(args) if name in ("Union", "UnionType") else f"{name}[{', '.join(args)}]"
    return (
        "None" if ann is type(None) else getattr(ann, "__name__", str(ann).replace("typing.", ""))
    )


def node(
    name: str,
    *,
    inputs: dict[str, In] | None = None,
    outputs: dict[str, Out] | None = None,
    params: type[Params] | None = None,
    version: str = "1",
    cacheable: bool = True,
    reads: Callable[[Params, Path], list[Path]] | None = None,
    items: Callable[[Params, RunContext], list[str]] | None = None,
    prepare: Callable[[], Any] | None = None,
    check: Callable[[Params, frozenset[str]], None] | None = None,
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Declare a function as a stereograph node type.

    Parameters
    ----------
    name : str
        Registered type name, ``kind.method`` (``segmenter.edge_morph``).
    inputs, outputs : dict
        Named ports (:class:`In`, :class:`Out`).
    params : type[Params]
        The pydantic model of the node's parameters (types, defaults, ranges, units).
    version : str
        Bump when behaviour changes in a way the source hash would not show.
    cacheable : bool
        False for side effects or live input (actuators, cameras).
    reads, items, prepare, check : callable, optional
        ``reads(params, pipeline_dir)``: the files read (the cache key follows them);
        ``items(params, ctx)``: the item ids, found cheaply (run item by item); ``prepare()``:
        what every call shares, loaded ahead; ``check(params, wired)``: params refused by which
        inputs are wired, at validation. In full: docs/engine.md.

    Returns
    -------
    The undecorated function, with the spec attached as ``fn.spec``.
    """

    declared = dict(
        params=params or _NoParams,
        inputs=dict(inputs or {}),
        outputs=dict(outputs or {}),
        version=str(version),
        cacheable=cacheable,
        reads=reads,
        items=items,
        prepare=prepare,
        check=check,
    )
    return lambda fn: _register(name, fn, declared)


def _register(name: str, fn: Callable[..., Any], declared: dict[str, Any]) -> Callable[..., Any]:
    """Attach the spec to ``fn`` and register it (what :func:`node` returns for a function)."""
    doc = inspect.getdoc(fn) or ""
    spec = NodeSpec(
        name=name, fn=fn, description=doc.split("\n\n", 1)[0].replace("\n", " "), **declared
    )
    missing = [i for i in spec.inputs if i not in inspect.signature(fn).parameters]
    if missing:
        raise TypeError(
            f"node {name!r}: function {fn.__name__} lacks parameters for inputs {missing}"
        )
    REGISTRY[name] = spec
    fn.spec = spec  # type: ignore[attr-defined]
    return fn
