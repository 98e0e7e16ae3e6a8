"""Why items were not found, grouped for people: one line per kind of reason, not per number.

Two pairs refused for the same cause say it with their own numbers ("different rows (dv = 6.9 px)",
"(dv = 11.2 px)"): counted as distinct strings, twenty pairs with one shared cause (swapped images,
another rig's calibration) looked like twenty causes of one pair each. Grouped by their wording,
each number becomes the range it took: "different rows (dv = 3.6–11.2 px)", 20 pairs.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

__all__ = ["group_reasons"]

# a number standing alone (not a part of a word or an id such as s001, DICT_4X4_50, 9x6)
_NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?!\w|\.\d)")


def group_reasons(counts: Mapping[str, int]) -> list[tuple[str, int]]:
    """Reasons grouped by their wording, most frequent first.

    Parameters
    ----------
    counts : mapping of str to int
        How many items gave each exact reason (a ``collections.Counter`` of them, say).

    Returns
    -------
    list of (str, int)
        ``(text, count)``: ``text`` is the shared wording with each number replaced by the range
        it took over the group (``"3.6–11.2"``, or the one value when all agree); ties in count
        keep the order in which the kinds were first seen.
    """
    groups: dict[str, list[list[str]]] = {}
    sizes: dict[str, int] = {}
    for r, n in counts.items():
        r = str(r)
        template = _NUMBER.sub("\0", r)
        groups.setdefault(template, []).append(_NUMBER.findall(r))
        sizes[template] = sizes.get(template, 0) + n
    out = []
    for template, values in groups.items():
        parts = template.split("\0")
        text = parts[0]
        for k, part in enumerate(parts[1:]):
            slot = [v[k] for v in values]
            lo, hi = min(slot, key=float), max(slot, key=float)
            text += (lo if float(lo) == float(hi) else f"{lo}–{hi}") + part
        out.append((text, sizes[template]))
    return sorted(out, key=lambda tc: -tc[1])
