"""YAML with ``safe_load`` semantics, within bounds, and the line of every key kept.

:func:`parse_yaml` refuses what a hand-written file never needs and a hostile one uses to hang
the tool: more than :data:`MAX_YAML_VALUES` values once aliases are expanded (an alias "bomb"),
nesting deeper than :data:`MAX_YAML_DEPTH`, a duplicate or non-scalar key. Every error is a
:class:`~stereograph.core.errors.ConfigError` naming the file, line and column.
"""

from __future__ import annotations

from typing import Any

import yaml
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.resolver import Resolver

from stereograph.core.errors import ConfigError, Where

Path_ = tuple  # a key path inside the document, e.g. ("nodes", "segment", "params", "canny_low")

MAX_YAML_VALUES = 20_000  # scalars and collections after expanding aliases
MAX_YAML_DEPTH = 64  # nested mappings / lists


try:  # libyaml's parser gives the same events about six times faster; the composer stays Python's
    from yaml._yaml import CParser as _CParser

    class _SafeBase(Composer, SafeConstructor, Resolver, _CParser):  # safe_load semantics
        def __init__(self, stream: str):
            _CParser.__init__(self, stream)
            SafeConstructor.__init__(self)
            Resolver.__init__(self)
            Composer.__init__(self)

    _LIBYAML = True
except ImportError:  # pragma: no cover - PyYAML built without libyaml
    _SafeBase = yaml.SafeLoader  # type: ignore[assignment,misc]
    _LIBYAML = False


class _BoundedLoader(_SafeBase):
    """A safe loader that refuses documents nested deeper than :data:`MAX_YAML_DEPTH`.

    PyYAML composes recursively; checking the depth as it goes stops before Python's stack does.
    """

    def __init__(self, stream: str, filename: str):
        _SafeBase.__init__(self, stream)
        self._depth = 0
        self._filename = filename

    def compose_node(self, parent, index):  # noqa: ANN001 - PyYAML's signature
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                mark = self.peek_event().start_mark
                raise _too_deep(Where(self._filename, mark.line + 1, mark.column + 1))
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _too_deep(where: Where) -> ConfigError:
    return ConfigError(
        f"the YAML is nested more than {MAX_YAML_DEPTH} levels deep",
        where,
        hint="a pipeline needs a few levels; flatten the data or put it in a file a node reads",
    )


def _expanded_size(root: yaml.Node, filename: str) -> int:
    """Number of values the document holds once aliases are expanded (memoised per YAML node,
    so an alias bomb is measured without being expanded); refuses recursive aliases."""
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node: yaml.Node) -> int:
        k = id(node)
        if k in sizes:
            return sizes[k]
        if k in active:
            raise ConfigError(
                "a YAML alias refers to the collection that contains it",
                Where(filename, node.start_mark.line + 1, node.start_mark.column + 1),
                hint="remove the recursive '*alias'",
            )
        active.add(k)
        n = 1
        if isinstance(node, yaml.MappingNode):
            n += sum(size(kn) + size(vn) for kn, vn in node.value)
        elif isinstance(node, yaml.SequenceNode):
            n += sum(size(v) for v in node.value)
        active.discard(k)
        sizes[k] = n = min(n, 10 * MAX_YAML_VALUES)  # capped: the sum cannot grow without bound
        return n

    return size(root)


def _yaml_error(e: yaml.YAMLError, filename: str, text: str) -> ConfigError:
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    line = col = None
    if mark is not None:
        line, col = mark.line + 1, mark.column + 1
    elif isinstance(e, yaml.reader.ReaderError):  # a character YAML does not allow (NUL, control)
        before = (
            text.encode("utf-8", "surrogatepass")[: e.position].decode("utf-8", "replace")
            if _LIBYAML
            else text[: e.position]
        )  # libyaml counts bytes, PyYAML characters
        line = before.count("\n") + 1
        col = len(before) - (before.rfind("\n") + 1) + 1
        ch = e.character if isinstance(e.character, int) else ord(str(e.character)[:1] or "?")
        err = ConfigError(
            f"character U+{ch:04X} is not allowed in YAML",
            Where(filename, line, col),
            hint="remove it (control characters and NUL cannot appear in a pipeline file)",
        )
        err.syntax = True  # type: ignore[attr-defined]
        return err
    what = getattr(e, "problem", None) or getattr(e, "context", None) or str(e)
    # libyaml >= 0.2.6 stops at its own limit (1000) while scanning ahead
    if "nesting depth" in what:
        # (a bound, not a syntax error: never taken as text)
        return _too_deep(Where(filename, line, col))
    err = ConfigError(
        f"not valid YAML: {what}",
        Where(filename, line, col),
        hint="check indentation and quoting around that line",
    )
    err.syntax = True  # type: ignore[attr-defined]  # (a --set value that is not YAML is taken as text)
    return err


def _record_keys(
    loader: Any,
    node: yaml.Node,
    filename: str,
    lines: dict[Path_, Where] | None,
    path: Path_ = (),
    walked: set[int] | None = None,
) -> None:
    """Check every key (a plain name, not twice in a mapping) and, into ``lines``, the line of each
    key and list item, in document order; a node reached again through an alias has its lines
    already."""
    walked = set() if walked is None else walked
    if id(node) in walked:
        return
    walked.add(id(node))
    if isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            if lines is not None:
                lines[path + (i,)] = Where(filename, v.start_mark.line + 1, v.start_mark.column + 1)
            _record_keys(loader, v, filename, lines, path + (i,), walked)
    if not isinstance(node, yaml.MappingNode):
        return
    seen: dict[Any, int] = {}
    for k, v in node.value:
        at = Where(filename, k.start_mark.line + 1, k.start_mark.column + 1)
        if not isinstance(k, yaml.ScalarNode):
            raise ConfigError(
                "a key must be a plain name, not a list or mapping",
                at,
                hint="write 'name: value' (a '? [a, b]' complex key is not a name)",
            )
        key = loader.construct_object(k, deep=True)
        if key in seen:
            raise ConfigError(
                f"duplicate key '{key}' (first at line {seen[key]})", at, hint="keep one of them"
            )
        seen[key] = k.start_mark.line + 1
        if lines is not None:
            lines[path + (key,)] = at
        _record_keys(loader, v, filename, lines, path + (key,), walked)


def parse_yaml(
    text: str, filename: str, record_lines: bool = True
) -> tuple[Any, dict[Path_, Where]]:
    """Parse YAML with safe_load semantics, within the bounds above, and record the line of each
    key.

    Parameters
    ----------
    text : str
        The document.
    filename : str
        Named in errors (a path, or ``--set ...``).
    record_lines : bool
        Keep the line of every key and list item.

    Returns
    -------
    (data, lines)

    Raises
    ------
    ConfigError
        Invalid YAML, a non-scalar key, a duplicate key, or a document beyond the bounds.
    """
    loader = None
    try:
        loader = _BoundedLoader(text, filename)  # (checks every character first)
        root = loader.get_single_node()
        lines: dict[Path_, Where] = {}
        if root is None:
            return None, lines
        n = _expanded_size(root, filename)
        if n > MAX_YAML_VALUES:
            raise ConfigError(
                f"the YAML holds more than {MAX_YAML_VALUES} values once its aliases are expanded",
                Where(filename, 1),
                hint="a pipeline file sets parameters; put large data in a file that a node reads",
            )
        _record_keys(loader, root, filename, lines if record_lines else None)
        data = loader.construct_document(root)
        return data, lines
    except yaml.YAMLError as e:
        raise _yaml_error(e, filename, text) from None
    except RecursionError:  # belt and braces: the depth bound should stop it first
        raise ConfigError(
            "the YAML is nested too deeply",
            Where(filename),
            hint=f"keep it within {MAX_YAML_DEPTH} levels",
        ) from None
    finally:
        if loader is not None:
            loader.dispose()
