"""What a comparison gave: :class:`VariantResult` per variant, :class:`CompareResult` for all, and
how a metric reads in a cell (:func:`metric_cell`, :func:`metric_header`).

Shared by the terminal table, the files, the progress lines and ``compare.html``, so that a
number reads the same in each. Knows nothing of what the metrics mean.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stereograph.app.ranking import PER_PAIR, show
from stereograph.app.variants import Variant


def metric_cell(name: str, v: Any, missing: str = "–") -> str:
    """A metric as a cell: the engine's per-pair time in ms, integers as they are, seconds (a name
    ending ``_s``) with 4 decimals, other numbers with 3; ``missing`` for none."""
    if v is None:
        return missing
    if name == PER_PAIR:
        return f"{1000 * v:.1f}"
    if isinstance(v, int):
        return str(v)
    return f"{v:.4f}" if name.endswith("_s") else f"{v:.3f}"


def metric_header(name: str) -> str:
    return "pair ms" if name == PER_PAIR else name


@dataclass
class VariantResult:
    """What one variant's run gave."""

    variant: Variant
    ok: bool
    error: str | None
    status: dict[str, str]
    ran: set[str]
    out_dir: Path | None
    seconds: float
    per_pair_s: float | None
    metrics: dict[str, float | int | None]  # the declared metrics, merged (see collect_metrics)

    @property
    def computed(self) -> str:
        """What the variant computed, for its progress line: a node that failed was computed too
        (it is not 'all cached')."""
        parts = [n for n in self.status if n in self.ran] + [
            f"{n} (failed)" for n, st in self.status.items() if st == "failed" and n not in self.ran
        ]
        return ", ".join(parts) or ("nothing (all cached)" if self.ok else "nothing")


@dataclass
class CompareResult:
    """All variants, the table rows, and the files written."""

    pipeline: str
    keys: list[str]
    split: str | None
    out_dir: Path
    variants: list[VariantResult]
    rows: list[dict[str, Any]]
    files: dict[str, Path]
    #: ``(label, why)`` of each combination ``skip_invalid`` left out (its config did not validate)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    #: the metric the pipeline's ``compare: {metric: ...}`` names (``--best`` overrides it)
    ranked_by: str | None = None

    def shown_metrics(self, first: str | None = None) -> tuple[list[str], list[str]]:
        """``(shown, constant)``: the metric ``first`` names (``NAME[:how]``), then the metrics
        whose value differs between variants, in their order, the per-pair time last; and those the
        same in every one."""
        lead = (first or self.ranked_by or "").partition(":")[0]
        varies = [
            n
            for n in self.metric_names
            if n == PER_PAIR
            or len({metric_cell(n, r.get(n)) for r in self.rows}) > 1
            or len(self.rows) < 2
        ]
        shown = ([lead] if lead in self.metric_names else []) + [n for n in varies if n != lead]
        return shown, [n for n in self.metric_names if n not in shown]

    def same_in_every(self, names: list[str]) -> str:
        """``name value, ...`` of metrics every variant has the same value of (the first row's)."""
        return ", ".join(f"{n} {metric_cell(n, self.rows[0].get(n))}" for n in names)

    def varying_keys(self) -> list[str]:
        """The keys whose value differs between variants (all keys when none does)."""
        return [
            k for k in self.keys if len({show(x.variant.settings[k]) for x in self.variants}) > 1
        ] or self.keys

    def fixed_settings(self) -> list[str]:
        """``key=value`` of the keys every variant has the same value of."""
        first, varying = self.variants[0].variant.settings, self.varying_keys()
        return [f"{k}={show(first[k])}" for k in self.keys if k not in varying]

    def short_label(self, v: Variant) -> str:
        """Only the settings that differ between variants (plots and pages have little room)."""
        return ", ".join(show(v.settings[k]) for k in self.varying_keys())

    @property
    def ok(self) -> bool:
        return all(v.ok for v in self.variants)

    @property
    def metric_names(self) -> list[str]:
        """Every metric column, in the order the variants first report them (per-pair time last)."""
        names: dict[str, None] = {}
        for vr in self.variants:
            names.update(dict.fromkeys(vr.metrics))
        return [*names, PER_PAIR]

    def row(self, **settings: Any) -> dict[str, Any]:
        """The first row whose settings include these (``row(**{"fit.type": "none"})``)."""
        for r in self.rows:
            if all(r["settings"].get(k) == v for k, v in settings.items()):
                return r
        raise KeyError(settings)
