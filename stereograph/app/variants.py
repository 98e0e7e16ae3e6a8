"""The variants of a comparison: ``--vary node.field=a,b`` and a pipeline's ``variants:`` block,
their Cartesian product, and each one's validated graph.

Public: :class:`Variant`, :func:`parse_vary`, :func:`expand_variants`, :func:`variant_graph`,
:data:`MAX_VARIANTS`.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from stereograph.app.ranking import show
from stereograph.core.config import (
    PipelineDoc,
    apply_override,
    check_node_named,
)
from stereograph.core.errors import ConfigError, UsageError
from stereograph.core.graph import Graph, build_graph
from stereograph.core.yaml_lines import parse_yaml


@dataclass
class Variant:
    """One combination of settings."""

    index: int
    settings: dict[str, Any]  # "node.field" -> value (as given)
    overrides: list[str] = field(default_factory=list)  # what was applied to the document
    # the keys whose value differs between variants (None: all)
    varying: tuple[str, ...] | None = None
    # key -> "--vary" or "variants:" (where it was given)
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={show(v)}" for k, v in self.settings.items())

    @property
    def slug(self) -> str:
        # the folder name: the settings that tell the variants apart (a key with one value says
        # nothing)
        keys = [k for k in self.settings if self.varying is None or k in self.varying] or list(
            self.settings
        )
        text = "_".join(f"{k}-{show(self.settings[k])}" for k in keys)
        return f"v{self.index:02d}_" + re.sub(r"[^A-Za-z0-9._=-]+", "-", text)[:80]


def parse_vary(text: str) -> tuple[str, list[Any]]:
    """Split ``node.field=v1,v2,...`` into the key and the values (each parsed as YAML).

    Values are read as one YAML flow sequence, so ``fit.bin_edges_cm=[30, 40, 60],[30, 60]``
    gives two lists.
    """
    if "=" not in text:
        raise UsageError(
            f"--vary '{text}' is not of the form node.field=v1,v2,...",
            hint="for example --vary fit.type=none,polynomial",
        )
    key, rhs = (s.strip() for s in text.split("=", 1))
    parts = key.split(".")
    if len(parts) < 2 or not all(parts):
        raise UsageError(
            f"--vary '{text}': the left side must be node.field (node.type or node.param)",
            hint="for example --vary fit.degree=1,2,3",
        )
    try:  # the bounds of a pipeline file apply (an alias bomb, deep nesting)
        values = parse_yaml(f"[{rhs}]", f"--vary {key}", record_lines=False)[0]
    except ConfigError as e:
        if not getattr(e, "syntax", False):
            raise
        values = [v.strip() for v in rhs.split(",")]
    if not values or any(v is None for v in values):
        raise UsageError(
            f"--vary '{text}' lists no (or an empty) value", hint="give comma-separated values"
        )
    return key, list(values)


def _override_text(doc: PipelineDoc, key: str, value: Any) -> str | None:
    """The ``--set`` text that applies one setting, or None when it changes nothing."""
    node, _, fieldname = key.partition(".")
    if node not in doc.nodes:
        return f"{key}={json.dumps(value)}"  # apply_override names the bad node
    if fieldname == "type":
        value = str(value)
        current = str(doc.nodes[node]["type"])
        if "." not in value:
            value = current.split(".", 1)[0] + "." + value
        if value == current:
            return None  # same type: keep the params written in the pipeline
    return f"{key}={json.dumps(value)}"


# variants in one compare: each is a run (most of them cached, still a run folder each)
MAX_VARIANTS = 1000


def expand_variants(doc: PipelineDoc, vary: Iterable[str] = ()) -> list[Variant]:
    """The Cartesian product of the pipeline's ``variants:`` block and ``--vary`` options."""
    space: dict[str, list[Any]] = {}
    sources: dict[str, str] = {}
    for k, values in (doc.variants or {}).items():
        if "." not in str(k):
            raise ConfigError(
                f"variants key '{k}' must be node.field",
                doc.where("variants", k),
                hint="for example 'fit.type: [none, polynomial]'",
            )
        # (a key naming no node fails every combination: not one variant's problem for
        # --skip-invalid)
        check_node_named(
            doc, str(k).split(".", 1)[0], f"variants key '{k}'", doc.where("variants", k)
        )
        space[str(k)], sources[str(k)] = list(values), "variants:"
    given: dict[str, str] = {}
    for text in vary:
        k, values = parse_vary(text)
        check_node_named(doc, k.split(".", 1)[0], f"--vary '{text}'")
        if k in given:  # (the second list silently replaced the first)
            raise UsageError(
                f"--vary {k} is given twice ('{given[k]}' and '{text}')",
                hint=f"give every value in one list: --vary {k}=v1,v2,v3",
            )
        given[k] = text
        space[k], sources[k] = values, "--vary"
    if not space:
        raise UsageError(
            f"nothing to compare in {doc.path.name}: no --vary and no 'variants:' block",
            hint="add --vary node.field=v1,v2 (e.g. --vary fit.type=none,polynomial)",
        )
    keys = list(space)
    n = math.prod(len(v) for v in space.values())
    # (60,000 variants were built, then run, silently for minutes before the first line)
    if n > MAX_VARIANTS:
        sizes = " x ".join(f"{len(space[k])} {k}" for k in keys)
        raise UsageError(
            f"{n} variants ({sizes}): more than one compare runs ({MAX_VARIANTS})",
            hint="vary fewer settings or fewer values at once, and compare the best of each",
        )
    varying = tuple(k for k in keys if len(space[k]) > 1)
    return [
        Variant(i + 1, dict(zip(keys, combo)), varying=varying, sources=sources)
        for i, combo in enumerate(itertools.product(*space.values()))
    ]


def variant_graph(doc: PipelineDoc, variant: Variant) -> Graph:
    """Apply a variant's settings to a copy of the document and validate it."""
    vdoc = copy.deepcopy(doc)
    vdoc.variants = {}
    variant.overrides = []
    # A type change resets the node's params, so types go first and params set with them survive.
    ordered = sorted(variant.settings.items(), key=lambda kv: kv[0].split(".", 1)[1] != "type")
    for key, value in ordered:
        text = _override_text(vdoc, key, value)
        if text is not None:
            apply_override(vdoc, text, variant.sources.get(key, "--set"))
            variant.overrides.append(text)
    return build_graph(vdoc)
