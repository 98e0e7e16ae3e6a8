"""How many examples a fuzz test draws: bounded for the suite, scaled up by hand.

``STEREOGRAPH_FUZZ_SCALE=25 python -m pytest -n auto tests/test_fuzz_config.py`` runs the large
version (25 times the examples of the suite's).
"""

from __future__ import annotations

import os

SCALE = float(os.environ.get("STEREOGRAPH_FUZZ_SCALE", "1"))


def examples(n: int) -> int:
    """``n`` examples in the suite, ``n * STEREOGRAPH_FUZZ_SCALE`` by hand (at least 1)."""
    return max(1, round(n * SCALE))
